//! Integration tests of the engine (splat4d), as one test binary: each file here is a module, so
//! the dependencies are linked once, not once per file. One file's tests:
//! `cargo nextest run -p splat4d FILE::`.

mod browser;
mod common;
mod eval_support;
mod train_scene;

#[global_allocator]
static ALLOC: shared_types::fuzz::PeakAlloc = shared_types::fuzz::PeakAlloc;

mod decay_gradients;
mod decay_resume;
mod decay_variants;
mod eval_frames;
mod eval_lpips;
mod eval_report;
mod eval_timing;
mod export_formats;
mod fuzz_readers;
mod gpu_adam;
mod gpu_backward;
mod gpu_decay;
mod gpu_decay_train;
mod gpu_loss;
mod gpu_lpips;
mod gpu_parity;
mod gpu_pool;
mod gpu_profile;
mod gpu_train;
mod gpu_train_loop;
mod gradients;
mod hard_cases;
mod metrics_values;
mod model_file;
mod paths_geometry;
mod reference;
mod train_fit;
mod train_frozen;
mod train_hooks;
mod train_resume;
mod train_unseen;
mod viewer_browser;
