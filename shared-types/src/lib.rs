//! `shared-types`: the small types every crate of the 4C4D pipeline shares, and nothing heavier.
//! `rig` and `calib` depend on this crate instead of the engine, so building them does
//! not build the rasteriser, ONNX runtime or k-d trees.
//!
//! - [`camera`]: cameras (OpenCV/COLMAP convention), lens models, `cameras.json` sets;
//! - [`progress`]: the [`Progress`] sink every long task reports through;
//! - [`atomic`]: the one way to write a file that a reader never sees half-written;
//! - [`ply`]: the one binary PLY codec (a table of named scalar columns);
//! - [`points`]: point clouds with colour and optional time (`points.ply`);
//! - `fuzz` (feature `fuzz`, for tests): damaged files and an allocation meter for the
//!   readers' fuzz tests.

pub mod atomic;
pub mod camera;
#[cfg(any(test, feature = "fuzz"))]
pub mod fuzz;
pub mod ply;
pub mod points;
pub mod progress;

pub use camera::{Camera, CameraSet, Distortion, Intrinsics, WorldToCamera};
pub use points::PointCloud;
pub use progress::{NoProgress, Progress};
