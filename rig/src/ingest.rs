//! Ingest: find each camera's video files, read their exact per-frame timestamps, and
//! describe what was found ([`Streams`], written as `work/ingest/streams.json`).
//!
//! GoPro chapters (`GX01xxxx.MP4`, `GX02xxxx.MP4`, …) are joined in order; any other
//! FFmpeg-readable files in a camera folder are joined in name order. A folder with no
//! video but numbered images (`.jpg`, `.png`, …) is an image sequence: image `k` (in
//! natural name order) is at `k / image_fps` seconds ([`IngestOptions`]). Timestamps come from
//! the demuxer (no decoding), so ingest is fast; audio is decoded on demand by
//! [`decode_audio`]. This module does not synchronise cameras (that is `sync`).

use std::path::{Path, PathBuf};

#[cfg(feature = "ffmpeg")]
use ffmpeg::media::Type;
#[cfg(feature = "ffmpeg")]
use ffmpeg_next as ffmpeg;
use serde::{Deserialize, Serialize};

use crate::media;
use crate::rotation::Rotation;
#[cfg(feature = "ffmpeg")]
use crate::source::{FileSource, PixelLayout, SourceError, decode_err, init_ffmpeg};
use shared_types::progress::Progress;

/// Errors from ingesting camera folders.
#[derive(Debug, thiserror::Error)]
pub enum IngestError {
    /// No cameras were given.
    #[error("no camera folders given: put each camera's videos in raw/cam0, raw/cam1, …")]
    NoCameras,
    /// A camera path does not exist.
    #[error("camera {camera}: {path} does not exist")]
    Missing {
        /// Camera name.
        camera: String,
        /// The path.
        path: PathBuf,
    },
    /// A camera folder has no video file.
    #[error(
        "camera {camera}: no video file in {path} (looked for .mp4/.mov/.mkv/.avi/.m4v/.webm/.mts/.ts videos, \
         or numbered .jpg/.jpeg/.png/.bmp/.tif/.tiff images)"
    )]
    NoVideo {
        /// Camera name.
        camera: String,
        /// The folder.
        path: PathBuf,
    },
    /// A folder holds chapters of more than one GoPro recording.
    #[error(
        "camera {camera}: {path} holds several GoPro recordings ({recordings}); keep one recording per camera folder"
    )]
    SeveralRecordings {
        /// Camera name.
        camera: String,
        /// The folder.
        path: PathBuf,
        /// Their file numbers.
        recordings: String,
    },
    /// The images of an image-sequence camera differ in size.
    #[error(
        "camera {camera}: {path} is {}×{} but the camera's first image is {}×{}; \
         every image of a camera must have the same size (re-export or remove it)",
        .size.0, .size.1, .expected.0, .expected.1
    )]
    ImageSize {
        /// Camera name.
        camera: String,
        /// The odd image.
        path: PathBuf,
        /// Its size and the first image's (width, height).
        size: (u32, u32),
        expected: (u32, u32),
    },
    /// `image_fps` is not a positive frame rate.
    #[error("[ingest] image_fps = {0} must be a positive number of images per second")]
    ImageFps(f64),
    /// A video file has no frames.
    #[error("camera {camera}: {path} has no video frames; re-export or remove it")]
    NoFrames {
        /// Camera name.
        camera: String,
        /// The file.
        path: PathBuf,
    },
    /// Decoding failed.
    #[cfg(feature = "ffmpeg")]
    #[error("camera {camera}: {source}")]
    Source {
        /// Camera name.
        camera: String,
        /// The decoding error.
        source: SourceError,
    },
    /// Reading a folder or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A JSON file could not be parsed.
    #[error("{path}: not a valid streams file ({source}); rerun the ingest stage")]
    Json {
        /// The path.
        path: PathBuf,
        /// The error.
        source: serde_json::Error,
    },
}

/// What ingest found for all cameras.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Streams {
    /// One entry per camera, in the order given.
    pub cameras: Vec<CameraStream>,
    /// Mismatches between cameras (fps, resolution, missing audio) worth a look.
    pub warnings: Vec<String>,
}

/// Where a camera's frames come from.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SourceKind {
    /// Video files decoded with FFmpeg.
    File,
    /// A live V4L2 recording (written as files, timestamps from the kernel).
    V4l2,
    /// A simulated camera.
    Simulated,
    /// Numbered still images, decoded with FFmpeg, timed by [`IngestOptions::image_fps`].
    Images,
}

/// How ingest reads camera folders.
#[derive(Clone, Debug, PartialEq)]
pub struct IngestOptions {
    /// Frame rate given to image-sequence cameras, whose files carry no timestamps: image
    /// `k` of every such camera is at `k / image_fps` seconds on its clock.
    pub image_fps: f64,
}

impl Default for IngestOptions {
    fn default() -> Self {
        Self { image_fps: 30.0 }
    }
}

/// One camera's stream.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraStream {
    /// Camera name (`cam0`, …).
    pub name: String,
    /// Where the frames come from.
    pub kind: SourceKind,
    /// The files, in playback order, each with the time (seconds, camera clock) at which
    /// its own timestamp 0 sits.
    pub chapters: Vec<Chapter>,
    /// Video stream description.
    pub video: VideoInfo,
    /// Audio stream description, if the camera recorded sound.
    pub audio: Option<AudioInfo>,
    /// Presentation time of every frame, seconds on the camera's own clock, increasing.
    pub timestamps: Vec<f64>,
}

/// One file of a camera's recording.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Chapter {
    /// The file.
    pub path: PathBuf,
    /// Seconds added to the file's own timestamps to put them on the camera's clock.
    pub offset_s: f64,
}

/// The video stream of a camera.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct VideoInfo {
    /// Codec name.
    pub codec: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Degrees clockwise a player turns the stored frames by (a phone's display matrix);
    /// `width` and `height` are the displayed size, and frames are decoded turned.
    #[serde(default)]
    pub rotation: Rotation,
    /// Frames per second from the median frame interval.
    pub fps: f64,
    /// True when frame intervals vary by more than 5 % (besides isolated gaps).
    pub variable_frame_rate: bool,
    /// Number of frames.
    pub frame_count: usize,
    /// Intervals longer than 1.75 local median intervals: likely dropped frames.
    pub gaps: usize,
    /// Seconds from the first frame to the end of the last one.
    pub duration_s: f64,
}

/// The audio stream of a camera.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AudioInfo {
    /// Codec name.
    pub codec: String,
    /// Native sample rate in Hz.
    pub sample_rate: u32,
    /// Channels in the file (decoded audio is mixed to mono).
    pub channels: u16,
}

/// A decoded audio track: mono `f32` at the native rate.
#[derive(Clone, Debug, PartialEq)]
pub struct AudioTrack {
    /// Samples per second.
    pub sample_rate: u32,
    /// Camera-clock time (seconds) of `samples[0]`.
    pub start_s: f64,
    /// Mono samples.
    pub samples: Vec<f32>,
}

impl Streams {
    /// Looks a camera up by name.
    pub fn camera(&self, name: &str) -> Option<&CameraStream> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// Writes `streams.json` atomically (temporary name, then rename).
    pub fn write_json(&self, path: &Path) -> Result<(), IngestError> {
        shared_types::atomic::write_json(path, self).map_err(|source| IngestError::Io {
            path: path.into(),
            source,
        })
    }

    /// Reads a `streams.json`.
    pub fn read_json(path: &Path) -> Result<Self, IngestError> {
        let text = std::fs::read_to_string(path).map_err(|source| IngestError::Io {
            path: path.into(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|source| IngestError::Json {
            path: path.into(),
            source,
        })
    }
}

impl CameraStream {
    /// Chapters as (path, offset) pairs for [`FileSource::open`].
    pub fn chapter_list(&self) -> Vec<(PathBuf, f64)> {
        self.chapters
            .iter()
            .map(|c| (c.path.clone(), c.offset_s))
            .collect()
    }

    #[cfg(feature = "ffmpeg")]
    /// Opens the camera's frames for decoding.
    pub fn open(
        &self,
        layout: PixelLayout,
        out_size: Option<(u32, u32)>,
    ) -> Result<FileSource, SourceError> {
        FileSource::open(&self.name, &self.chapter_list(), layout, out_size)
    }
}

/// The video files of one camera in playback order, or its images in natural name order
/// when the folder holds images and no video ([`media`] tells which).
pub fn camera_files(camera: &str, path: &Path) -> Result<Vec<PathBuf>, IngestError> {
    if !path.exists() {
        return Err(IngestError::Missing {
            camera: camera.into(),
            path: path.into(),
        });
    }
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let io = |source| IngestError::Io {
        path: path.into(),
        source,
    };
    let mut files = Vec::new();
    let mut images = Vec::new();
    for entry in std::fs::read_dir(path).map_err(io)? {
        let p = entry.map_err(io)?.path();
        // Hidden files are never recordings: an interrupted atomic write leaves its
        // temporary sibling (`.NAME.tmp-PID.MP4`, see `shared_types::atomic::temp_sibling`).
        let hidden = p
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with('.'));
        if !p.is_file() || hidden {
            continue;
        }
        if media::is_image(&p) {
            images.push(p);
        } else if !media::is_sidecar(&p) && is_video(&p).map_err(io)? {
            files.push(p);
        }
    }
    if files.is_empty() && !images.is_empty() {
        // An image sequence (images next to videos are thumbnails and ignored).
        media::sort_images(&mut images);
        return Ok(images);
    }
    if files.is_empty() {
        return Err(IngestError::NoVideo {
            camera: camera.into(),
            path: path.into(),
        });
    }
    let recordings: std::collections::BTreeSet<u32> = files
        .iter()
        .filter_map(|p| media::gopro_chapter(p.file_name()?.to_str()?).map(|(r, _)| r))
        .collect();
    if recordings.len() > 1 {
        let list = recordings
            .iter()
            .map(|r| format!("{r:04}"))
            .collect::<Vec<_>>()
            .join(", ");
        return Err(IngestError::SeveralRecordings {
            camera: camera.into(),
            path: path.into(),
            recordings: list,
        });
    }
    media::sort_recordings(&mut files);
    Ok(files)
}

/// Whether `path` is a video: by its name, or by its content when the name says nothing.
fn is_video(path: &Path) -> std::io::Result<bool> {
    Ok(media::has_video_name(path) || media::sniff_file(path)?.is_some())
}

/// Timestamps and stream facts of one file, from the demuxer.
struct FileProbe {
    codec: String,
    /// Displayed size (stored size turned by `rotation`).
    width: u32,
    height: u32,
    rotation: Rotation,
    /// Presentation times (seconds, the file's own clock), sorted.
    times: Vec<f64>,
    /// End of the last frame (seconds, file clock).
    end: f64,
    audio: Option<AudioInfo>,
    /// Where the file's own clock starts, when that start is the muxer's arbitrary choice
    /// ([`arbitrary_start`]): its first video or audio timestamp. 0 otherwise.
    start: f64,
}

#[cfg(feature = "ffmpeg")]
/// Whether a container's timestamps start at an arbitrary value rather than on a clock
/// the cameras could share: MPEG transport and program streams (AVCHD `.MTS`, `.m2ts`,
/// `.ts`, `.MPG`, `.VOB`) start at the muxer's delay (1.4 s from FFmpeg, anything from a
/// camcorder) on a 33-bit 90 kHz clock that wraps every 26.5 hours (FFmpeg unwraps it
/// within a file). MP4/MOV (which the recorder writes on a shared clock), Matroska and MXF
/// (timecode is metadata, timestamps start at 0) keep theirs.
fn arbitrary_start(input: &ffmpeg::format::context::Input) -> bool {
    let format = input.format();
    format
        .name()
        .split(',')
        .any(|n| n == "mpegts" || n == "mpeg")
}

#[cfg(feature = "ffmpeg")]
fn probe_file(path: &Path) -> Result<FileProbe, SourceError> {
    init_ffmpeg();
    let mut input = ffmpeg::format::input(&path).map_err(decode_err(path))?;
    let (index, time_base, codec, (width, height), rotation, rate) = {
        let stream = input
            .streams()
            .best(Type::Video)
            .ok_or_else(|| SourceError::NoStream {
                path: path.into(),
                kind: "video",
                hint: "",
            })?;
        let params = stream.parameters();
        let ctx =
            ffmpeg::codec::context::Context::from_parameters(params).map_err(decode_err(path))?;
        let codec = ctx.id().name().to_string();
        let video = ctx.decoder().video().map_err(decode_err(path))?;
        let rotation = Rotation::of_stream(&stream);
        (
            stream.index(),
            f64::from(stream.time_base()),
            codec,
            rotation.turn_size((video.width(), video.height())),
            rotation,
            stream.avg_frame_rate(),
        )
    };
    let audio_index = input.streams().best(Type::Audio).map(|s| s.index());
    let start = if arbitrary_start(&input) {
        std::iter::once(index)
            .chain(audio_index)
            .map(|i| stream_start(&input, i))
            .fold(f64::INFINITY, f64::min)
    } else {
        0.0
    };
    let audio = match input.streams().best(Type::Audio) {
        Some(stream) => {
            let ctx = ffmpeg::codec::context::Context::from_parameters(stream.parameters())
                .map_err(decode_err(path))?;
            let codec = ctx.id().name().to_string();
            let dec = ctx.decoder().audio().map_err(decode_err(path))?;
            Some(AudioInfo {
                codec,
                sample_rate: dec.rate(),
                channels: dec.channels(),
            })
        }
        None => None,
    };
    let mut times = Vec::new();
    let mut last_duration = 0.0;
    for (stream, packet) in input.packets() {
        if stream.index() != index {
            continue;
        }
        let Some(ts) = packet.pts().or(packet.dts()) else {
            continue;
        };
        // AV_PKT_FLAG_DISCARD: decoded but not shown (edit lists), so not a frame.
        if packet.flags().bits() & ffmpeg::ffi::AV_PKT_FLAG_DISCARD != 0 {
            continue;
        }
        times.push(ts as f64 * time_base);
        last_duration = packet.duration() as f64 * time_base;
    }
    times.sort_by(f64::total_cmp);
    times.dedup();
    let fallback = if rate.numerator() > 0 {
        f64::from(rate.invert())
    } else {
        0.0
    };
    let step = if last_duration > 0.0 {
        last_duration
    } else {
        fallback
    };
    let end = times.last().map_or(0.0, |t| t + step);
    Ok(FileProbe {
        codec,
        width,
        height,
        rotation,
        times,
        end,
        audio,
        start,
    })
}

/// Median of the positive intervals of increasing `times`.
pub(crate) fn median_interval(times: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = times
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// Counts gaps (intervals over 1.75× the local median interval: dropped frames) and tells
/// whether the frame rate varies (local median intervals differ by over 5 %, or over 5 % of
/// the intervals stray from their local median by over 5 %).
pub(crate) fn frame_rate_regularity(times: &[f64]) -> (usize, bool) {
    let d: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return (0, false);
    }
    let half = 15;
    let local: Vec<f64> = (0..d.len())
        .map(|i| {
            let mut w = d[i.saturating_sub(half)..(i + half + 1).min(d.len())].to_vec();
            w.sort_by(f64::total_cmp);
            w[w.len() / 2]
        })
        .collect();
    let gaps = d
        .iter()
        .zip(&local)
        .filter(|(d, m)| **d > 1.75 * **m)
        .count();
    let irregular = d
        .iter()
        .zip(&local)
        .filter(|(d, m)| (**d - **m).abs() > 0.05 * **m && **d <= 1.75 * **m)
        .count();
    let (lo, hi) = local
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &m| (lo.min(m), hi.max(m)));
    (gaps, hi > 1.05 * lo || irregular > d.len() / 20 + 1)
}

#[cfg(feature = "ffmpeg")]
/// Probes one camera: its files, per-frame timestamps and stream facts.
pub fn probe_camera(
    camera: &str,
    path: &Path,
    options: &IngestOptions,
) -> Result<CameraStream, IngestError> {
    let files = camera_files(camera, path)?;
    if files.first().is_some_and(|f| media::is_image(f)) {
        return probe_images(camera, path, files, options.image_fps);
    }
    let src = |source| IngestError::Source {
        camera: camera.into(),
        source,
    };
    let mut chapters = Vec::new();
    let mut timestamps = Vec::new();
    let mut first: Option<FileProbe> = None;
    let mut offset = 0.0;
    for file in &files {
        let probe = probe_file(file).map_err(src)?;
        if probe.times.is_empty() {
            return Err(IngestError::NoFrames {
                camera: camera.into(),
                path: file.clone(),
            });
        }
        // The camera's clock is its first file's (from 0 where that file's start is
        // arbitrary); a chapter continues where the previous one ended.
        let chapter_offset = if chapters.is_empty() {
            -probe.start
        } else {
            offset - probe.times[0]
        };
        timestamps.extend(probe.times.iter().map(|t| t + chapter_offset));
        offset = chapter_offset + probe.end;
        chapters.push(Chapter {
            path: file.clone(),
            offset_s: chapter_offset,
        });
        if first.is_none() {
            first = Some(probe);
        }
    }
    let Some(first) = first else {
        return Err(IngestError::NoVideo {
            camera: camera.into(),
            path: path.into(),
        });
    };
    let interval = median_interval(&timestamps).unwrap_or(1.0 / 30.0);
    let (gaps, variable_frame_rate) = frame_rate_regularity(&timestamps);
    let duration_s = offset - timestamps.first().copied().unwrap_or(0.0);
    Ok(CameraStream {
        name: camera.to_string(),
        kind: SourceKind::File,
        chapters,
        video: VideoInfo {
            codec: first.codec,
            width: first.width,
            height: first.height,
            rotation: first.rotation,
            fps: 1.0 / interval,
            variable_frame_rate,
            frame_count: timestamps.len(),
            gaps,
            duration_s,
        },
        audio: first.audio,
        timestamps,
    })
}

#[cfg(feature = "ffmpeg")]
/// An image-sequence camera: every image probed for its size, image `k` at `k / fps`.
fn probe_images(
    camera: &str,
    folder: &Path,
    files: Vec<PathBuf>,
    fps: f64,
) -> Result<CameraStream, IngestError> {
    if !(fps > 0.0 && fps.is_finite()) {
        return Err(IngestError::ImageFps(fps));
    }
    let src = |source| IngestError::Source {
        camera: camera.into(),
        source,
    };
    let mut first: Option<FileProbe> = None;
    for file in &files {
        let probe = probe_file(file).map_err(src)?;
        match &first {
            None => first = Some(probe),
            Some(f) if (f.width, f.height) != (probe.width, probe.height) => {
                return Err(IngestError::ImageSize {
                    camera: camera.into(),
                    path: file.clone(),
                    size: (probe.width, probe.height),
                    expected: (f.width, f.height),
                });
            }
            Some(_) => {}
        }
    }
    let Some(first) = first else {
        return Err(IngestError::NoVideo {
            camera: camera.into(),
            path: folder.into(),
        });
    };
    let timestamps: Vec<f64> = (0..files.len()).map(|k| k as f64 / fps).collect();
    let chapters = files
        .into_iter()
        .zip(&timestamps)
        .map(|(path, &offset_s)| Chapter { path, offset_s })
        .collect();
    Ok(CameraStream {
        name: camera.to_string(),
        kind: SourceKind::Images,
        chapters,
        video: VideoInfo {
            codec: first.codec,
            width: first.width,
            height: first.height,
            rotation: Rotation::None,
            fps,
            variable_frame_rate: false,
            frame_count: timestamps.len(),
            gaps: 0,
            duration_s: timestamps.len() as f64 / fps,
        },
        audio: None,
        timestamps,
    })
}

#[cfg(feature = "ffmpeg")]
/// Probes every camera folder (`(name, path)`; a path may also be a single video file)
/// and reports mismatches between cameras in [`Streams::warnings`].
pub fn ingest(
    camera_dirs: &[(String, PathBuf)],
    options: &IngestOptions,
    progress: &dyn Progress,
) -> Result<Streams, IngestError> {
    if camera_dirs.is_empty() {
        return Err(IngestError::NoCameras);
    }
    progress.start(camera_dirs.len() as u64, "cameras");
    let mut cameras = Vec::new();
    for (name, path) in camera_dirs {
        progress.message(name);
        cameras.push(probe_camera(name, path, options)?);
        progress.advance(1);
    }
    progress.finish();
    let warnings = mismatch_warnings(&cameras);
    for w in &warnings {
        tracing::warn!("{w}");
    }
    Ok(Streams { cameras, warnings })
}

/// Warnings about fps, resolution and audio differences between cameras.
pub fn mismatch_warnings(cameras: &[CameraStream]) -> Vec<String> {
    let mut warnings = Vec::new();
    let Some(first) = cameras.first() else {
        return warnings;
    };
    for c in &cameras[1..] {
        if (c.video.fps - first.video.fps).abs() > 0.01 * first.video.fps {
            warnings.push(format!(
                "{} runs at {:.3} fps but {} at {:.3} fps: frames will be matched by timestamp, with larger residuals",
                c.name, c.video.fps, first.name, first.video.fps
            ));
        }
        if (c.video.width, c.video.height) != (first.video.width, first.video.height) {
            warnings.push(format!(
                "{} is {}x{} but {} is {}x{}: each camera keeps its own intrinsics",
                c.name,
                c.video.width,
                c.video.height,
                first.name,
                first.video.width,
                first.video.height
            ));
        }
    }
    for c in cameras {
        if c.audio.is_none() && c.kind != SourceKind::Images {
            warnings.push(format!(
                "{} has no audio track: audio sync cannot use it",
                c.name
            ));
        }
        if c.video.variable_frame_rate {
            warnings.push(format!(
                "{} has a variable frame rate: per-frame timestamps are used as they are",
                c.name
            ));
        }
        if c.video.gaps > 0 {
            warnings.push(format!(
                "{}: {} gaps longer than 1.75 frame intervals (dropped frames?)",
                c.name, c.video.gaps
            ));
        }
    }
    warnings
}

#[cfg(feature = "ffmpeg")]
/// Decodes a camera's audio (all chapters) to mono `f32` at its native rate.
///
/// Returns `Ok(None)` when the camera has no audio stream. Each chapter's samples are
/// placed at their timestamps and cut at the chapter's end (AAC pads its last frame).
pub fn decode_audio(stream: &CameraStream) -> Result<Option<AudioTrack>, IngestError> {
    let Some(info) = &stream.audio else {
        return Ok(None);
    };
    let rate = info.sample_rate;
    let src = |source| IngestError::Source {
        camera: stream.name.clone(),
        source,
    };
    let mut track: Option<AudioTrack> = None;
    let n = stream.chapters.len();
    for (i, chapter) in stream.chapters.iter().enumerate() {
        let end = if i + 1 < n {
            Some(stream.chapters[i + 1].offset_s)
        } else {
            None
        };
        let Some((start, samples)) = decode_audio_file(&chapter.path).map_err(src)? else {
            continue;
        };
        let start = start + chapter.offset_s;
        let track = track.get_or_insert_with(|| AudioTrack {
            sample_rate: rate,
            start_s: start,
            samples: vec![],
        });
        let at = ((start - track.start_s) * f64::from(rate)).round().max(0.0) as usize;
        let stop = end.map_or(usize::MAX, |e| {
            ((e - track.start_s) * f64::from(rate)).round().max(0.0) as usize
        });
        track.samples.resize(at, 0.0);
        let take = stop.saturating_sub(at).min(samples.len());
        track.samples.extend_from_slice(&samples[..take]);
    }
    Ok(track)
}

#[cfg(feature = "ffmpeg")]
/// Decodes the best audio stream of one file: (start time in the file's clock, mono samples).
fn decode_audio_file(path: &Path) -> Result<Option<(f64, Vec<f32>)>, SourceError> {
    init_ffmpeg();
    let mut input = ffmpeg::format::input(&path).map_err(decode_err(path))?;
    let Some(stream) = input.streams().best(Type::Audio) else {
        return Ok(None);
    };
    let index = stream.index();
    let time_base = f64::from(stream.time_base());
    let duration = if stream.duration() > 0 {
        Some(stream.duration() as f64 * time_base)
    } else {
        None
    };
    let ctx = ffmpeg::codec::context::Context::from_parameters(stream.parameters())
        .map_err(decode_err(path))?;
    let mut decoder = ctx.decoder().audio().map_err(decode_err(path))?;
    let mut samples = Vec::new();
    let mut start: Option<f64> = None;
    let mut frame = ffmpeg::frame::Audio::empty();
    let mut drain =
        |decoder: &mut ffmpeg::decoder::Audio, samples: &mut Vec<f32>, start: &mut Option<f64>| {
            while decoder.receive_frame(&mut frame).is_ok() {
                if start.is_none() {
                    *start = frame
                        .timestamp()
                        .or(frame.pts())
                        .map(|p| p as f64 * time_base);
                }
                mix_to_mono(&frame, samples);
            }
        };
    for (s, packet) in input.packets() {
        if s.index() == index && decoder.send_packet(&packet).is_ok() {
            drain(&mut decoder, &mut samples, &mut start);
        }
    }
    let _ = decoder.send_eof();
    drain(&mut decoder, &mut samples, &mut start);
    let start = start.unwrap_or(0.0);
    if let Some(d) = duration {
        let keep =
            ((d - (start - (stream_start(&input, index)))) * f64::from(decoder.rate())).round();
        if keep > 0.0 && (keep as usize) < samples.len() {
            samples.truncate(keep as usize);
        }
    }
    Ok(Some((start, samples)))
}

#[cfg(feature = "ffmpeg")]
fn stream_start(input: &ffmpeg::format::context::Input, index: usize) -> f64 {
    input
        .stream(index)
        .map(|s| {
            let st = s.start_time();
            if st == ffmpeg::ffi::AV_NOPTS_VALUE {
                0.0
            } else {
                st as f64 * f64::from(s.time_base())
            }
        })
        .unwrap_or(0.0)
}

#[cfg(feature = "ffmpeg")]
/// Appends the mono mix (channel mean) of a decoded audio frame.
fn mix_to_mono(frame: &ffmpeg::frame::Audio, out: &mut Vec<f32>) {
    use ffmpeg::format::Sample;
    use ffmpeg::format::sample::Type as Layout;
    let n = frame.samples();
    let ch = usize::from(frame.channels().max(1));
    let base = out.len();
    out.resize(base + n, 0.0);
    let dst = &mut out[base..];
    let scale = 1.0 / ch as f32;
    let mut add = |i: usize, v: f32| dst[i] += v * scale;
    macro_rules! mix {
        ($t:ty, $conv:expr, $planar:expr) => {{
            if $planar {
                for c in 0..ch {
                    let plane: &[$t] = frame.plane(c);
                    for i in 0..n {
                        add(i, $conv(plane[i]));
                    }
                }
            } else {
                let data = frame.data(0);
                let size = std::mem::size_of::<$t>();
                for i in 0..n {
                    for c in 0..ch {
                        let at = (i * ch + c) * size;
                        let bytes: [u8; std::mem::size_of::<$t>()] = data[at..at + size]
                            .try_into()
                            .unwrap_or([0; std::mem::size_of::<$t>()]);
                        add(i, $conv(<$t>::from_ne_bytes(bytes)));
                    }
                }
            }
        }};
    }
    match frame.format() {
        Sample::F32(l) => mix!(f32, |v: f32| v, l == Layout::Planar),
        Sample::F64(l) => mix!(f64, |v: f64| v as f32, l == Layout::Planar),
        Sample::I16(l) => mix!(i16, |v: i16| f32::from(v) / 32768.0, l == Layout::Planar),
        Sample::I32(l) => mix!(
            i32,
            |v: i32| v as f32 / 2_147_483_648.0,
            l == Layout::Planar
        ),
        Sample::U8(l) => mix!(
            u8,
            |v: u8| (f32::from(v) - 128.0) / 128.0,
            l == Layout::Planar
        ),
        _ => tracing::warn!(
            "unsupported audio sample format {:?}; treated as silence",
            frame.format()
        ),
    }
}
