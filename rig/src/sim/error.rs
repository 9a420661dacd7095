//! Errors of the simulator: every variant names the file (scene or output) it concerns and
//! says what to do about it.

use std::path::PathBuf;

/// What can go wrong while reading a scene file or writing a simulated capture.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("cannot read scene file {path}: {source}")]
    ReadScene {
        path: PathBuf,
        source: std::io::Error,
    },

    #[error(
        "scene file {origin} is not valid TOML for a scene: {message}\n(see docs/simulator.md for every key)"
    )]
    Parse { origin: String, message: String },

    #[error("scene file {origin}: {message}")]
    Invalid { origin: String, message: String },

    #[error(
        "capture directory {path} already holds a capture (found {found}); remove it or choose an empty directory"
    )]
    CaptureExists { path: PathBuf, found: String },

    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },

    #[cfg(feature = "ffmpeg")]
    #[error("cannot encode {path}: {what}: {source}")]
    Encode {
        path: PathBuf,
        what: String,
        source: ffmpeg_next::Error,
    },

    #[error(
        "FFmpeg lacks {what} needed to write {path}; install an FFmpeg build with it (Debian: libavcodec59)"
    )]
    MissingCodec { path: PathBuf, what: String },

    #[error("cannot write image {path}: {source}")]
    Image {
        path: PathBuf,
        source: image::ImageError,
    },
}

impl SimError {
    pub(crate) fn invalid(origin: &str, message: impl Into<String>) -> Self {
        SimError::Invalid {
            origin: origin.to_string(),
            message: message.into(),
        }
    }

    pub(crate) fn write(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SimError::Write {
            path: path.into(),
            source,
        }
    }
}
