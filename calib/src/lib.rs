//! `calib`: geometry of the rig. COLMAP driving and model IO, camera models and
//! undistortion, calibration import, point initialisation from point maps.
//!
//! The poses stage calls [`poses::solve`] (COLMAP) or [`import::import_calibration`] then
//! [`poses::write_imported`]; frames are made pinhole with [`undistort::UndistortMap`].
//! Depends on `shared-types` (cameras, progress, atomic writes, PLY point clouds), not on
//! the engine.

pub mod colmap;
pub mod colmap_runner;
pub mod convert;
pub mod import;
pub mod init;
pub mod poses;
pub mod similarity;
pub mod undistort;
