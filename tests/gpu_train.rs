//! The trainer runs on the GPU backend (forward and backward on the GPU; loss, Adam and
//! densification on the host) and fits the analytic scene of `train_fit.rs` as the CPU
//! backend does: training-view PSNR within 0.3 dB of the CPU run's. A short run (with a
//! densification step) always; issue 17's 300-iteration run on request, as lavapipe needs
//! about 0.4 s per view.
//!
//! Adapter policy as in `gpu_parity.rs`: without an adapter the test skips with a message,
//! except under `CI=true`, where that is a failure.

mod train_scene;

use splat4d::render::RenderBackend;
use splat4d::render::gpu::{AdapterPolicy, GpuBackend};
use splat4d::train::{NoHooks, TrainConfig, evaluate_psnr, train};
use splat4d::{CpuBackend, NoProgress, load_model};

fn gpu() -> Option<GpuBackend> {
    match GpuBackend::new(AdapterPolicy::AllowSoftware) {
        Ok(g) => Some(g),
        Err(e) => {
            if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
                panic!(
                    "no GPU adapter under CI=true: {e}; run scripts/setup.sh (mesa-vulkan-drivers)"
                );
            }
            eprintln!("SKIPPED GPU training test: {e}");
            None
        }
    }
}

/// Train the analytic scene (`w×h` views) for `iterations` on `backend`, densifying at a
/// third and two thirds; the mean training-view PSNR, evaluated on the CPU.
fn fit(backend: &dyn RenderBackend, iterations: u64, w: u32, h: u32, batch: usize) -> f64 {
    let data = train_scene::dataset(w, h);
    let init = train_scene::points(16, 12, &[0.0, 0.5, 1.0]);
    let dir = tempfile::tempdir().unwrap();
    let mut config = TrainConfig {
        iterations,
        batch_size: batch,
        checkpoint_every: 0,
        ..Default::default()
    };
    config.degree_every = 2 * iterations / 3;
    config.densify.from_iteration = iterations / 3;
    config.densify.until_iteration = 5 * iterations / 6;
    config.densify.every = iterations / 3;
    config.densify.opacity_reset_every = 0;
    let summary = train(
        backend,
        &config,
        &data,
        &init,
        dir.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();
    let model = load_model(&summary.model_path).unwrap();
    let psnr = evaluate_psnr(&CpuBackend, &model, &data, config.background).unwrap();
    let mean = psnr.iter().sum::<f64>() / psnr.len() as f64;
    eprintln!(
        "{}: {} Gaussians, mean PSNR {mean:.2} dB, {:.1}s",
        backend.describe(),
        model.len(),
        summary.seconds
    );
    mean
}

fn compare(iterations: u64, w: u32, h: u32, batch: usize) {
    let Some(gpu) = gpu() else { return };
    let on_gpu = fit(&gpu, iterations, w, h, batch);
    let on_cpu = fit(&CpuBackend, iterations, w, h, batch);
    assert!(
        (on_gpu - on_cpu).abs() <= 0.3,
        "GPU {on_gpu:.2} dB vs CPU {on_cpu:.2} dB"
    );
}

#[test]
fn a_short_training_on_the_gpu_backend_matches_the_cpu() {
    compare(30, 32, 24, 2);
}

#[test]
#[ignore = "300 iterations × 4 views: ~10 min on lavapipe; run with --ignored where a GPU is"]
fn three_hundred_iterations_on_the_gpu_backend_match_the_cpu() {
    compare(300, 64, 48, 4);
}
