//! `calib`: geometry of the rig. COLMAP driving and model IO, camera models and
//! undistortion, calibration import, point initialisation from point maps.
//!
//! Depends on the engine crate only for the shared camera types.
