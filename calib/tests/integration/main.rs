//! Integration tests of calib, as one test binary: each file here is a module, so
//! the dependencies are linked once, not once per file. One file's tests:
//! `cargo nextest run -p calib FILE::`.

mod common;

#[global_allocator]
static ALLOC: shared_types::fuzz::PeakAlloc = shared_types::fuzz::PeakAlloc;

mod colmap_failures;
mod colmap_model_io;
mod fuzz_readers;
mod import;
mod opencv_models;
mod opencv_rational_calibration;
mod pose2sim_import;
mod solve_synthetic;
mod strecha_real;
mod undistort_opencv;
mod undistort_points;
mod undistort_render;
