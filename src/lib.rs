//! `splat4d`: the 4D Gaussian engine of the 4C4D pipeline.
//!
//! Holds the model, slicing at time t, colour, the differentiable rasteriser, training,
//! metrics and model files, plus the small shared types (cameras, progress) that the
//! `rig`, `calib` and `pipeline` crates use. See `ARCHITECTURE.md` for the map.

pub mod camera;
pub mod progress;

pub use camera::{Camera, CameraSet, Distortion, Intrinsics, WorldToCamera};
pub use progress::{NoProgress, Progress};
