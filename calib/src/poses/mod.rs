//! The `poses` stage: from the first aligned frame of each video camera plus the stills,
//! solve the rig with COLMAP (or take an imported calibration), normalise the scene, and
//! write `work/poses/cameras.json` + `work/poses/points3d.ply`.
//!
//! Normalisation: `x_norm = scale · (x_world − centre)` with `centre` the mean of the video
//! camera centres and `scale` chosen so the video cameras sit at mean distance
//! [`PosesConfig::radius`] (default 1) from it. Poses and points in the outputs are in the
//! normalised frame; `normalisation` in `cameras.json` maps back to COLMAP's (or the
//! imported calibration's) frame.
//!
//! Cameras in `cameras.json` keep the lens distortion that was solved; turning frames and
//! cameras into pinhole ones happens once, through [`crate::undistort`].
//!
//! One file per concern: `config` (settings and inputs), `file` (the `cameras.json`
//! schema), `error`, `solve` (the COLMAP run and picking its model), `capture_cameras`
//! (an imported calibration's camera for each camera folder, `[poses] names`), `sizes`
//! (a calibration's image size against the video's: same, codec padding, resize),
//! `normalise` and `write` (normalising and writing the outputs, for solved and imported
//! cameras alike).

mod capture_cameras;
mod config;
mod error;
mod file;
mod normalise;
mod sizes;
mod solve;
mod write;

pub use capture_cameras::{CaptureCamera, select_cameras};
pub use config::{PosesConfig, PosesInputs};
pub use error::PosesError;
pub use file::{PoseSource, PosesFile};
pub use normalise::{Normalisation, normalisation_for};
pub use sizes::{SizeRelation, fit_intrinsics, size_relation};
pub use solve::{BLANK_STD_DEV, cameras_from_model, pick_model, solve};
pub use write::{PosesOutput, SparsePoint, scale_intrinsics, write_imported};
