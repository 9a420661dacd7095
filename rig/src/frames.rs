//! Frames: re-align the cameras on a common output timeline and write the images.
//!
//! The timeline runs from the latest camera start to the earliest camera end at a fixed
//! rate. For each output frame every camera contributes its nearest frame; the exact
//! timestamp of that frame (common timeline) and its residual to the output time are kept
//! in `frames.json`, so the trainer never assumes genlocked cameras. Images are resized to
//! the working resolution and written as PNGs in parallel. This module decodes and writes
//! images; it does not estimate offsets (that is `sync`).

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

#[cfg(feature = "ffmpeg")]
use crate::ingest::{IngestError, Streams};
#[cfg(feature = "ffmpeg")]
use crate::source::{CameraSource, PixelLayout, SourceError};
#[cfg(feature = "ffmpeg")]
use crate::sync::SyncResult;
#[cfg(feature = "ffmpeg")]
use shared_types::progress::Progress;

/// The `[frames]` section of `capture.toml`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct FramesConfig {
    /// Long side of the written images, pixels.
    pub long_side: u32,
    /// Enlarge images smaller than `long_side` (off: they keep their size).
    pub allow_upscale: bool,
    /// Output frame rate; the reference camera's rate when absent.
    pub fps: Option<f64>,
    /// Skip this many seconds at the start of the common timeline.
    pub start_s: f64,
    /// Keep at most this many output frames.
    pub max_frames: Option<usize>,
}

impl Default for FramesConfig {
    fn default() -> Self {
        FramesConfig {
            long_side: 960,
            allow_upscale: false,
            fps: None,
            start_s: 0.0,
            max_frames: None,
        }
    }
}

/// `frames.json`: the aligned frames.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FramesIndex {
    /// Output frame rate.
    pub fps: f64,
    /// Common-timeline time of output frame 0, seconds.
    pub start_s: f64,
    /// Cameras, with the size their images were written at.
    pub cameras: Vec<CameraImages>,
    /// Output frames in order.
    pub frames: Vec<AlignedFrame>,
    /// What the user should know about the timeline: cameras that film together for only
    /// part of their recordings, frames far from their nominal time.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// A camera's written images.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraImages {
    /// Camera name (also its image folder).
    pub name: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

/// One output frame.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AlignedFrame {
    /// Output frame index (also the image file's number).
    pub index: usize,
    /// Nominal time of the output frame, common timeline, seconds.
    pub time_s: f64,
    /// One view per camera, in `cameras` order.
    pub views: Vec<View>,
}

/// One camera's frame used for an output frame.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct View {
    /// Index of the frame in the camera's stream.
    pub source_frame: usize,
    /// Exact time of that frame on the common timeline, seconds (use this for training).
    pub timestamp_s: f64,
    /// `timestamp_s − time_s`: how far the frame is from the nominal output time.
    pub residual_s: f64,
    /// Image path relative to the frames folder (`cam0/000000.png`).
    pub file: String,
}

/// Errors from frame extraction.
#[derive(Debug, thiserror::Error)]
pub enum FramesError {
    /// The cameras' recordings do not overlap on the common timeline.
    #[error(
        "the cameras never film at the same time: {last_start} starts at {start:.3} s (common timeline), after {first_end} has stopped at {end:.3} s; check the offsets in work/sync/sync.json (a wrong audio match, or [sync] manual_offsets), or [frames] start_s"
    )]
    NoOverlap {
        /// The camera that starts last.
        last_start: String,
        /// Latest start (with `start_s`).
        start: f64,
        /// The camera that ends first.
        first_end: String,
        /// Earliest end.
        end: f64,
    },
    /// The timeline's times or rate are not finite, or would make an absurd number of
    /// frames (a damaged or hand-edited streams.json / sync.json).
    #[error(
        "the common timeline cannot be planned: {0}; rerun ingest and sync (`pipeline run CAPTURE --from ingest --force`), or set [frames] fps"
    )]
    Timeline(String),
    /// streams.json and sync.json disagree.
    #[error("sync.json does not match streams.json ({0}); rerun sync")]
    Mismatch(String),
    /// Decoding failed.
    #[cfg(feature = "ffmpeg")]
    #[error(transparent)]
    Ingest(#[from] IngestError),
    /// Writing failed.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A `frames.json` could not be parsed.
    #[error("{path}: not a valid frames index ({source}); rerun the frames stage")]
    Json {
        /// The path.
        path: PathBuf,
        /// The error.
        source: serde_json::Error,
    },
    /// PNG encoding failed.
    #[error("{path}: {source}")]
    Image {
        /// The path.
        path: PathBuf,
        /// The error.
        source: image::ImageError,
    },
}

impl FramesIndex {
    /// Reads a `frames.json`.
    pub fn read_json(path: &Path) -> Result<Self, FramesError> {
        let text = std::fs::read_to_string(path).map_err(|source| FramesError::Io {
            path: path.into(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|source| FramesError::Json {
            path: path.into(),
            source,
        })
    }

    /// Writes `frames.json` atomically.
    pub fn write_json(&self, path: &Path) -> Result<(), FramesError> {
        shared_types::atomic::write_json(path, self).map_err(|source| FramesError::Io {
            path: path.into(),
            source,
        })
    }
}

/// Size of an image of `size` with its long side brought to `long_side`.
pub fn working_size(size: (u32, u32), long_side: u32, allow_upscale: bool) -> (u32, u32) {
    let (w, h) = size;
    let long = w.max(h).max(1);
    if long_side == 0 || (long <= long_side && !allow_upscale) {
        return (w, h);
    }
    let s = f64::from(long_side) / f64::from(long);
    (
        ((f64::from(w) * s).round() as u32).max(1),
        ((f64::from(h) * s).round() as u32).max(1),
    )
}

#[cfg(feature = "ffmpeg")]
/// Index of the value in increasing `times` nearest to `t`.
fn nearest(times: &[f64], t: f64) -> usize {
    let i = times.partition_point(|&x| x < t);
    if i == 0 {
        0
    } else if i == times.len() || t - times[i - 1] <= times[i] - t {
        i - 1
    } else {
        i
    }
}

/// Most output frames a timeline may have (nine hours at 60 fps): more means a damaged
/// time or rate, not a capture.
pub const MAX_FRAMES: usize = 2_000_000;

#[cfg(feature = "ffmpeg")]
/// Plans the output timeline (no decoding): which frame of each camera goes where.
pub fn plan(
    streams: &Streams,
    sync: &SyncResult,
    config: &FramesConfig,
) -> Result<FramesIndex, FramesError> {
    if streams.cameras.len() != sync.cameras.len() {
        return Err(FramesError::Mismatch(format!(
            "{} cameras in streams, {} in sync",
            streams.cameras.len(),
            sync.cameras.len()
        )));
    }
    for (s, c) in streams.cameras.iter().zip(&sync.cameras) {
        if s.name != c.name || s.timestamps.len() != c.timestamps.len() || c.timestamps.is_empty() {
            return Err(FramesError::Mismatch(format!(
                "camera {} differs or has no frames",
                s.name
            )));
        }
    }
    let fps = config
        .fps
        .or_else(|| streams.camera(&sync.reference).map(|c| c.video.fps))
        .filter(|f| f.is_finite() && *f > 0.0)
        .unwrap_or(30.0);
    let first = |c: &crate::sync::CameraSync| c.timestamps[0];
    let last = |c: &crate::sync::CameraSync| c.timestamps[c.timestamps.len() - 1];
    let starter = sync
        .cameras
        .iter()
        .max_by(|a, b| first(a).total_cmp(&first(b)));
    let ender = sync
        .cameras
        .iter()
        .min_by(|a, b| last(a).total_cmp(&last(b)));
    let (Some(starter), Some(ender)) = (starter, ender) else {
        return Err(FramesError::Mismatch("no cameras".into()));
    };
    let start = first(starter) + config.start_s.max(0.0);
    let end = last(ender);
    if !(start.is_finite() && end.is_finite()) {
        return Err(FramesError::Timeline(format!(
            "the cameras' times run from {start} to {end} s"
        )));
    }
    let frames_f = (end - start) * fps;
    if frames_f > MAX_FRAMES as f64 {
        return Err(FramesError::Timeline(format!(
            "{:.3} s at {fps} fps would be {frames_f:.3e} frames, over {MAX_FRAMES}",
            end - start
        )));
    }
    if end < start {
        return Err(FramesError::NoOverlap {
            last_start: starter.name.clone(),
            start,
            first_end: ender.name.clone(),
            end,
        });
    }
    let mut count = ((end - start) * fps + 1e-9).floor() as usize + 1;
    if let Some(m) = config.max_frames {
        count = count.min(m);
    }
    let cameras = streams
        .cameras
        .iter()
        .map(|c| {
            let (width, height) = working_size(
                (c.video.width, c.video.height),
                config.long_side,
                config.allow_upscale,
            );
            CameraImages {
                name: c.name.clone(),
                width,
                height,
            }
        })
        .collect();
    let frames: Vec<AlignedFrame> = (0..count)
        .map(|index| {
            let time_s = start + index as f64 / fps;
            let views = sync
                .cameras
                .iter()
                .map(|c| {
                    let k = nearest(&c.timestamps, time_s);
                    View {
                        source_frame: k,
                        timestamp_s: c.timestamps[k],
                        residual_s: c.timestamps[k] - time_s,
                        file: format!("{}/{index:06}.png", c.name),
                    }
                })
                .collect();
            AlignedFrame {
                index,
                time_s,
                views,
            }
        })
        .collect();
    let mut warnings = overlap_warnings(sync, (start, end), (&starter.name, &ender.name));
    warnings.extend(residual_warnings(sync, &frames, fps));
    Ok(FramesIndex {
        fps,
        start_s: start,
        cameras,
        frames,
        warnings,
    })
}

#[cfg(feature = "ffmpeg")]
/// A camera whose recording the common span `(start, end)` cuts by more than a quarter
/// (and a second): cameras started or stopped far apart.
fn overlap_warnings(
    sync: &SyncResult,
    (start, end): (f64, f64),
    (starter, ender): (&str, &str),
) -> Vec<String> {
    let span = end - start;
    sync.cameras
        .iter()
        .filter_map(|c| {
            let own = c.timestamps[c.timestamps.len() - 1] - c.timestamps[0];
            (own - span > (0.25 * own).max(1.0)).then(|| {
                format!(
                    "{} films for {own:.1} s, but all cameras film together for only {span:.1} s ({starter} starts last, {ender} stops first): the rest of {} is left out; start and stop the cameras closer together, or check the offsets in sync.json",
                    c.name, c.name
                )
            })
        })
        .collect()
}

#[cfg(feature = "ffmpeg")]
/// A camera whose nearest frame is more than half an output frame from the output time
/// for over a tenth of the frames (a variable frame rate well below the output rate, or
/// dropped frames).
fn residual_warnings(sync: &SyncResult, frames: &[AlignedFrame], fps: f64) -> Vec<String> {
    let half = 0.5 / fps + 1e-6;
    sync.cameras
        .iter()
        .enumerate()
        .filter_map(|(c, cam)| {
            let far = frames.iter().filter(|f| f.views[c].residual_s.abs() > half).count();
            (far * 10 > frames.len()).then(|| {
                format!(
                    "{}: {far} of {} output frames use a frame more than half a frame from their time (a variable frame rate below {fps:.2} fps, or dropped frames); training uses each frame's own timestamp, but motion there is sampled coarser — set [frames] fps lower to match",
                    cam.name,
                    frames.len()
                )
            })
        })
        .collect()
}

#[cfg(feature = "ffmpeg")]
/// Plans the timeline, decodes every camera and writes `out_dir/<camera>/NNNNNN.png` and
/// `out_dir/frames.json` (cameras in parallel, PNG encoding in parallel).
pub fn extract(
    streams: &Streams,
    sync: &SyncResult,
    config: &FramesConfig,
    out_dir: &Path,
    progress: &dyn Progress,
) -> Result<FramesIndex, FramesError> {
    let index = plan(streams, sync, config)?;
    let total = (index.frames.len() * index.cameras.len()) as u64;
    progress.start(total, "images");
    (0..streams.cameras.len())
        .into_par_iter()
        .try_for_each(|ci| write_camera(streams, &index, ci, out_dir, progress))?;
    progress.finish();
    index.write_json(&out_dir.join("frames.json"))?;
    Ok(index)
}

#[cfg(feature = "ffmpeg")]
fn write_camera(
    streams: &Streams,
    index: &FramesIndex,
    ci: usize,
    out_dir: &Path,
    progress: &dyn Progress,
) -> Result<(), FramesError> {
    let stream = &streams.cameras[ci];
    let size = (index.cameras[ci].width, index.cameras[ci].height);
    let dir = out_dir.join(&stream.name);
    std::fs::create_dir_all(&dir).map_err(|source| FramesError::Io {
        path: dir.clone(),
        source,
    })?;
    // Output frames wanting each source frame, in source order.
    let mut wanted: Vec<(usize, usize)> = index
        .frames
        .iter()
        .map(|f| (f.views[ci].source_frame, f.index))
        .collect();
    wanted.sort_unstable();
    let Some(&(last_needed, _)) = wanted.last() else {
        return Ok(());
    };
    let src = |source: SourceError| IngestError::Source {
        camera: stream.name.clone(),
        source,
    };
    let mut source = stream.open(PixelLayout::Rgb8, Some(size)).map_err(src)?;
    let mut next = 0;
    let mut batch: Vec<(std::sync::Arc<Vec<u8>>, PathBuf)> = Vec::new();
    let flush = |batch: &mut Vec<(std::sync::Arc<Vec<u8>>, PathBuf)>| -> Result<(), FramesError> {
        batch
            .par_iter()
            .try_for_each(|(data, path)| write_png(path, data, size))?;
        progress.advance(batch.len() as u64);
        batch.clear();
        Ok(())
    };
    let mut last: Option<std::sync::Arc<Vec<u8>>> = None;
    while next < wanted.len() {
        let Some(frame) = source.next_frame().map_err(src)? else {
            break;
        };
        // Identify the frame by its timestamp (robust to frames the decoder skipped).
        let k = nearest(&stream.timestamps, frame.timestamp);
        let data = std::sync::Arc::new(frame.data);
        last = Some(data.clone());
        while next < wanted.len() && wanted[next].0 <= k {
            let (s, out) = wanted[next];
            if s <= k {
                // s < k: the decoder skipped frame s; the nearest later frame stands in.
                batch.push((data.clone(), dir.join(format!("{out:06}.png"))));
            }
            next += 1;
        }
        if batch.len() >= 16 {
            flush(&mut batch)?;
        }
        if k >= last_needed {
            break;
        }
    }
    if next < wanted.len() {
        // The decoder ended early (a truncated file): the last decoded frame stands in.
        tracing::warn!(
            "{}: {} frames could not be decoded; using the last decoded frame",
            stream.name,
            wanted.len() - next
        );
        let Some(data) = last else {
            return Err(FramesError::Mismatch(format!(
                "{} decoded no frames",
                stream.name
            )));
        };
        for &(_, out) in &wanted[next..] {
            batch.push((data.clone(), dir.join(format!("{out:06}.png"))));
        }
    }
    flush(&mut batch)?;
    Ok(())
}

#[cfg(feature = "ffmpeg")]
/// Writes an RGB8 PNG atomically.
fn write_png(path: &Path, data: &[u8], (w, h): (u32, u32)) -> Result<(), FramesError> {
    shared_types::atomic::write_with(path, |tmp| {
        image::save_buffer_with_format(
            tmp,
            data,
            w,
            h,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
    })
    .map_err(|source| FramesError::Image {
        path: path.into(),
        source,
    })
}
