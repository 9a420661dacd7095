//! The simulator's view of [`crate::video`]: the same MP4 writer (libx264 + optional AAC),
//! with errors reported as [`SimError`] and the call shape the camera loop uses.

use std::path::{Path, PathBuf};

use super::error::SimError;
use crate::video::{self, VideoError, VideoOptions};

pub use crate::video::{fps_rational, init};

impl From<VideoError> for SimError {
    fn from(e: VideoError) -> Self {
        match e {
            VideoError::Encode { path, what, source } => SimError::Encode { path, what, source },
            VideoError::MissingCodec { path, what } => SimError::MissingCodec { path, what },
            VideoError::Write { path, source } => SimError::Write { path, source },
            VideoError::Invalid { path, message } => SimError::Invalid {
                origin: path.display().to_string(),
                message,
            },
        }
    }
}

/// An MP4 being written by a simulated camera.
pub struct Mp4Writer(video::Mp4Writer);

impl Mp4Writer {
    /// Open `path` for `width × height` video at `fps`, with mono audio at `audio_rate` Hz
    /// when given. `crf` and `preset` are libx264's.
    pub fn create(
        path: &Path,
        width: u32,
        height: u32,
        fps: f64,
        crf: u32,
        preset: &str,
        audio_rate: Option<u32>,
    ) -> Result<Self, SimError> {
        let options = VideoOptions {
            fps,
            crf,
            preset: preset.to_string(),
            audio_rate,
        };
        Ok(Self(video::Mp4Writer::create(
            path, width, height, &options,
        )?))
    }

    /// Add video frame number `index` (its pts is `index / fps`); `rgb` is tightly packed.
    pub fn push_video(&mut self, index: i64, rgb: &[u8]) -> Result<(), SimError> {
        Ok(self.0.push_video(index, rgb)?)
    }

    /// Add audio samples (mono, [-1, 1]) following those already added. The writer keeps
    /// partial encoder frames itself, so `pending` is only drained into it.
    pub fn push_audio(&mut self, samples: &[f32], pending: &mut Vec<f32>) -> Result<(), SimError> {
        pending.extend_from_slice(samples);
        self.0.push_audio(pending)?;
        pending.clear();
        Ok(())
    }

    /// Flush, write the trailer and move the file to its final name.
    pub fn finish(mut self, pending_audio: Vec<f32>) -> Result<PathBuf, SimError> {
        self.0.push_audio(&pending_audio)?;
        Ok(self.0.finish()?)
    }
}
