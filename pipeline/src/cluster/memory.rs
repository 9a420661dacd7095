//! Memory requests sized to the capture. `train` and `eval` hold every frame they read in
//! memory (RGB, a byte a channel) beside the model, so a job's `--mem` follows from the
//! number of views and their working size; when `[cluster]` sets no `mem` for such a
//! stage, its job asks for that. The frames are counted from what exists at submit time:
//! the frames stage's index when it has run, else the recordings as ingest probes them
//! (`work/ingest/streams.json`, or the raw folders, read without decoding a frame) at
//! `[frames]`' working size, rate and frame limit.

use std::path::Path;

use rig::frames::{FramesConfig, FramesIndex, working_size};
use rig::ingest::{IngestOptions, Streams};

use crate::config::CaptureConfig;
use crate::layout::Capture;

/// Memory a stage process needs besides its frames and model (the engine, buffers, LPIPS
/// weights), MiB.
const BASE_MIB: u64 = 512;
/// Bytes a Gaussian takes while training: parameters, their gradients, Adam's two moments
/// and the densification statistics, at full colour.
const TRAINING_BYTES_PER_GAUSSIAN: u64 = 1200;
/// Headroom over the estimate.
const MARGIN: f64 = 1.5;

/// The frames a capture's engine stages hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Footprint {
    pub views: u64,
    /// RGB bytes of all those views.
    pub bytes: u64,
}

impl Footprint {
    /// The part of these frames that `frames` of `of` aligned frames take (one time chunk's
    /// window, which is all a chunk's job holds).
    pub fn share(self, frames: usize, of: usize) -> Self {
        let of = of.max(1) as u64;
        let frames = (frames as u64).min(of);
        Self {
            views: self.views * frames / of,
            bytes: self.bytes * frames / of,
        }
    }
}

/// The capture's frames as counted at submit time, or `None` when its recordings cannot
/// be read yet (the ingest job will say why).
pub fn footprint(work: &Path, capture: &Capture, config: &CaptureConfig) -> Option<Footprint> {
    if let Ok(index) = FramesIndex::read_json(&work.join("frames").join("frames.json")) {
        return Some(from_index(&index));
    }
    let streams = match Streams::read_json(&work.join("ingest").join("streams.json")) {
        Ok(s) => s,
        Err(_) => probe_recordings(capture, config)?,
    };
    Some(from_streams(&streams, &config.frames))
}

/// The capture's recordings as ingest probes them (nothing decoded); `None` when they
/// cannot be read, or in a build without FFmpeg, which cannot probe videos.
#[cfg(feature = "ffmpeg")]
fn probe_recordings(capture: &Capture, config: &CaptureConfig) -> Option<Streams> {
    let cameras: Vec<(String, std::path::PathBuf)> = capture
        .all_cameras()
        .map(|c| (c.name.clone(), c.dir.clone()))
        .collect();
    let options = IngestOptions {
        image_fps: config.ingest.image_fps,
    };
    rig::ingest::ingest(&cameras, &options, &shared_types::progress::NoProgress).ok()
}

#[cfg(not(feature = "ffmpeg"))]
fn probe_recordings(_: &Capture, _: &CaptureConfig) -> Option<Streams> {
    None
}

fn from_index(index: &FramesIndex) -> Footprint {
    let per_frame: u64 = index
        .cameras
        .iter()
        .map(|c| 3 * c.width as u64 * c.height as u64)
        .sum();
    let frames = index.frames.len() as u64;
    Footprint {
        views: frames * index.cameras.len() as u64,
        bytes: frames * per_frame,
    }
}

/// The frames the frames stage would write: every camera over the shortest recording (an
/// upper bound on the cameras' common span) at the output rate, capped by `max_frames`.
fn from_streams(streams: &Streams, frames: &FramesConfig) -> Footprint {
    let videos = streams.cameras.iter().map(|c| &c.video);
    let shortest = videos
        .clone()
        .map(|v| v.duration_s)
        .fold(f64::INFINITY, f64::min);
    let fps = frames
        .fps
        .unwrap_or_else(|| videos.clone().map(|v| v.fps).fold(f64::INFINITY, f64::min));
    let mut count = if shortest.is_finite() && fps.is_finite() {
        ((shortest - frames.start_s).max(0.0) * fps).floor() as u64
    } else {
        0
    };
    if let Some(max) = frames.max_frames {
        count = count.min(max as u64);
    }
    let per_frame: u64 = videos
        .map(|v| {
            let (w, h) = working_size((v.width, v.height), frames.long_side, frames.allow_upscale);
            3 * w as u64 * h as u64
        })
        .sum();
    Footprint {
        views: count * streams.cameras.len() as u64,
        bytes: count * per_frame,
    }
}

/// Whether `stage` holds the frames, so its job's `--mem` is sized to them ([`request`]).
pub fn sized(stage: &str) -> bool {
    matches!(stage, "train" | "eval")
}

/// `--mem` for `stage`'s job (`"1536M"`), for the stages that hold the frames; `None` for
/// the others (the cluster's default applies).
pub fn request(stage: &str, frames: Footprint, max_gaussians: usize) -> Option<String> {
    let model = match stage {
        "train" => max_gaussians as u64 * TRAINING_BYTES_PER_GAUSSIAN,
        "eval" => max_gaussians as u64 * TRAINING_BYTES_PER_GAUSSIAN / 4,
        _ => return None,
    };
    let mib = BASE_MIB as f64 + (frames.bytes + model) as f64 / (1 << 20) as f64;
    Some(format!("{}M", (MARGIN * mib).ceil() as u64))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rig::frames::{AlignedFrame, CameraImages};
    use rig::ingest::{CameraStream, SourceKind, VideoInfo};

    fn stream(name: &str, width: u32, height: u32, fps: f64, duration_s: f64) -> CameraStream {
        CameraStream {
            name: name.into(),
            kind: SourceKind::File,
            chapters: Vec::new(),
            video: VideoInfo {
                codec: "h264".into(),
                width,
                height,
                rotation: Default::default(),
                fps,
                variable_frame_rate: false,
                frame_count: (fps * duration_s) as usize,
                gaps: 0,
                duration_s,
            },
            audio: None,
            timestamps: Vec::new(),
        }
    }

    #[test]
    fn frames_counted_from_the_recordings_follow_the_frames_settings() {
        let streams = Streams {
            cameras: vec![
                stream("cam0", 1920, 1080, 30.0, 10.0),
                stream("cam1", 1920, 1080, 30.0, 8.0),
            ],
            warnings: Vec::new(),
        };
        let mut frames = FramesConfig {
            long_side: 960,
            fps: Some(15.0),
            ..Default::default()
        };
        // 8 s (the shortest) at 15 fps: 120 frames of two 960×540 cameras.
        let f = from_streams(&streams, &frames);
        assert_eq!(f.views, 240);
        assert_eq!(f.bytes, 120 * 2 * 3 * 960 * 540);
        frames.max_frames = Some(50);
        assert_eq!(from_streams(&streams, &frames).views, 100);
        // The cameras' own rate when `[frames] fps` is unset.
        frames.max_frames = None;
        frames.fps = None;
        assert_eq!(from_streams(&streams, &frames).views, 2 * 240);
    }

    #[test]
    fn an_index_counts_what_was_written() {
        let index = FramesIndex {
            fps: 25.0,
            start_s: 0.0,
            cameras: vec![
                CameraImages {
                    name: "cam0".into(),
                    width: 640,
                    height: 360,
                },
                CameraImages {
                    name: "cam1".into(),
                    width: 320,
                    height: 180,
                },
            ],
            frames: (0..75)
                .map(|index| AlignedFrame {
                    index,
                    time_s: index as f64 / 25.0,
                    views: Vec::new(),
                })
                .collect(),
            warnings: Vec::new(),
        };
        let f = from_index(&index);
        assert_eq!(f.views, 150);
        assert_eq!(f.bytes, 75 * 3 * (640 * 360 + 320 * 180));
    }

    #[test]
    fn train_and_eval_ask_for_their_frames_and_model_the_rest_for_nothing() {
        // The basketball capture: 300 training views at 640×360 (207 MB) and at most 80 000
        // Gaussians; its train stage peaked at 616 MB.
        let frames = Footprint {
            views: 300,
            bytes: 300 * 3 * 640 * 360,
        };
        let train = request("train", frames, 80_000).unwrap();
        let mib: u64 = train.trim_end_matches('M').parse().unwrap();
        assert!((616..=2 * 1024).contains(&mib), "{train}");
        assert!(crate::cluster::config::is_slurm_memory(&train));
        let eval: u64 = request("eval", frames, 80_000)
            .unwrap()
            .trim_end_matches('M')
            .parse()
            .unwrap();
        assert!(eval < mib && eval >= 616, "{eval}");
        for stage in [
            "ingest", "sync", "frames", "poses", "init", "render", "export",
        ] {
            assert_eq!(request(stage, frames, 80_000), None, "{stage}");
        }
    }
}
