//! The init stage's one error type.

use std::path::PathBuf;

use shared_types::points::PlyError;

use crate::npy::NpyError;
use crate::onnx::OnnxError;

/// Errors of the init stage (a rejected pair is not an error: see
/// [`PairReport`](crate::PairReport)).
#[derive(Debug, thiserror::Error)]
pub enum InitError {
    #[error("invalid [init] settings: {0}")]
    Config(String),
    #[error("cannot read frame {path}: {source}; rerun the frames stage")]
    Image {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(
        "frame {path} is {got:?} but camera {camera} is calibrated for {want:?}; rerun the frames stage at the working size"
    )]
    ImageSize {
        path: PathBuf,
        camera: String,
        got: (u32, u32),
        want: (u32, u32),
    },
    #[error(transparent)]
    Onnx(#[from] OnnxError),
    #[error(transparent)]
    Npy(#[from] NpyError),
    #[error(transparent)]
    Ply(#[from] PlyError),
    #[error("cannot create {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}
