//! Test helpers: a simulated capture with moving objects ([`sim_moments`]) and whether
//! COLMAP is installed.
#![allow(dead_code)]

pub mod sim_moments;

/// Whether the real `colmap` binary is available; tests that need it skip (with a message)
/// when it is not.
pub fn colmap_available() -> bool {
    calib::colmap_runner::find_colmap(None)
        .map_err(|e| eprintln!("skipping: {e}"))
        .is_ok()
}
