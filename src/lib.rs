//! `splat4d`: the 4D Gaussian engine of the 4C4D pipeline.
//!
//! Holds the model, slicing at time t, colour, the differentiable rasteriser, training,
//! metrics and model files, plus the small shared types (cameras, progress) that the
//! `rig`, `calib` and `pipeline` crates use. See `ARCHITECTURE.md` for the map.

// `!(x > y)` is deliberate throughout the numerics: it is true for NaN, which must be
// culled. Index loops mirror the matrix formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

pub use shared_types::{atomic, camera, progress};

pub mod blend;
pub mod model;
pub mod model_file;
pub mod numerics;
pub mod project;
pub mod reference;
pub mod render;
pub mod rotation4d;
pub mod sh;
pub mod slice;
pub mod tiles;

pub use camera::{Camera, CameraSet, Distortion, Intrinsics, WorldToCamera};
pub use model::{ColourDegrees, Gaussians, TimeMapping};
pub use model_file::{ModelFileError, load_model, save_model};
pub use progress::{NoProgress, Progress};
pub use render::{
    Gradients, ImageGradients, RenderError, RenderOptions, Rendered, render, render_with,
};

pub mod decay;
pub mod densify;
pub mod export;
pub mod init;
pub mod loss;
pub mod optim;
pub mod ssim;
pub mod train;

pub mod eval;
pub mod lpips;
pub mod metrics;
pub mod paths;
