//! `calib`: geometry of the rig. COLMAP driving and model IO, camera models and
//! undistortion, calibration import.
//!
//! The poses stage calls [`poses::solve`] (COLMAP) or [`import::import_calibration`] then
//! [`poses::write_imported`]; frames are made pinhole with [`undistort::UndistortMap`].
//! Depends on `shared-types` (cameras, progress, atomic writes, PLY point clouds), not on
//! the engine.

pub mod colmap;
pub mod colmap_runner;
pub mod convert;
pub mod import;
pub mod poses;
pub mod similarity;
pub mod undistort;

/// Cameras for the unit tests (of this crate, and of crates that enable `test-support`).
#[cfg(any(test, feature = "test-support"))]
pub mod test_support {
    use glam::DVec3;
    use shared_types::{Camera, Intrinsics, WorldToCamera};

    /// A distortion-free camera `name` at `eye` looking at `target`, world z up.
    pub fn looking_at(name: &str, intrinsics: Intrinsics, eye: DVec3, target: DVec3) -> Camera {
        Camera {
            name: name.into(),
            intrinsics,
            distortion: Default::default(),
            world_to_camera: WorldToCamera::look_at(eye, target, DVec3::Z).unwrap(),
        }
    }
}
