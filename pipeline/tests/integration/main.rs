//! Integration tests of the pipeline, as one test binary: each file here is a module, so
//! the dependencies are linked once, not once per file. One file's tests:
//! `cargo nextest run -p pipeline FILE::`.

#[path = "../../../tests/integration/browser/mod.rs"]
mod browser;
mod common;

#[global_allocator]
static ALLOC: shared_types::fuzz::PeakAlloc = shared_types::fuzz::PeakAlloc;

mod bench;
mod bench_ablation;
mod bench_tradeoff;
mod cli;
mod decay_demo;
mod demo_quality;
mod disk_full;
mod end_to_end;
mod engine_only;
mod eval_moving;
mod fuzz_config;
mod heldout_real;
mod import;
mod init_accuracy;
mod jumping_object;
mod known_lenses;
mod layout_errors;
mod long_capture;
mod panoptic_capture;
mod real_calibrations;
mod render_backend;
mod runner;
mod slurm;
mod stage_graph;
mod train_chunks;
mod train_demo;
mod train_stage;
mod view_browser;
mod viewer_demo;
