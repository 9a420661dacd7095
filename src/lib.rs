//! `splat4d`: the 4D Gaussian engine of the 4C4D pipeline.
//!
//! Laid out by what things are:
//! - [`math`]: the per-Gaussian math every render backend follows (4D rotations, slicing
//!   at time t, spherical + spherindrical colour, EWA projection, numerics);
//! - [`render`]: the [`RenderBackend`] trait and its backends (`render::cpu`, with the
//!   `f64` oracle `render::reference`, and `render::gpu`);
//! - [`gpu`]: the device and the kernel toolkit every WGSL owner builds with;
//! - [`model`]: the Gaussians, their file format and their initialisation from points;
//! - [`train`]: loss, optimiser, densification and the training loop; [`decay`]: the 4C4D
//!   Neural Decaying Function that plugs into it;
//! - [`metrics`], [`eval`]: image metrics and evaluation of a model on views;
//! - [`export`]: 3DGS PLY frames, the 4D PLY, `.splatv` and the browser viewer;
//! - [`trajectories`]: camera paths (orbit, spiral, interpolation) for rendering.
//!
//! The small types shared with the capture side (cameras, progress, atomic writes, point
//! clouds) live in the `shared-types` crate and are re-exported here.

// `!(x > y)` is deliberate throughout the numerics: it is true for NaN, which must be
// culled. Index loops mirror the matrix formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

pub use shared_types::{atomic, camera, progress};

pub mod decay;
pub mod eval;
pub mod export;
pub mod gpu;
pub mod math;
pub mod metrics;
pub mod model;
pub mod render;
pub mod train;
pub mod trajectories;

pub use camera::{Camera, CameraSet, Distortion, Intrinsics, WorldToCamera};
pub use model::file::{ModelFileError, load_model, save_model};
pub use model::{ColourDegrees, Gaussians, TimeMapping};
pub use progress::{NoProgress, Progress};
pub use render::{
    CpuBackend, Gradients, ImageGradients, RenderBackend, RenderError, RenderOptions, Rendered,
    ViewRequest,
};
