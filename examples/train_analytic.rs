//! Train on the analytic moving-disc scene of the trainer tests and report held-out PSNR,
//! iterations/s, peak memory and Gaussian count (the numbers in BENCHMARKS.md "Training").
//! Run: `cargo run --release -p splat4d --example train_analytic -- [iterations] [width]`.

#[path = "../tests/integration/train_scene/mod.rs"]
mod train_scene;

use splat4d::CpuBackend;
use splat4d::train::{NoHooks, TrainConfig, evaluate_psnr, train};
use splat4d::{NoProgress, load_model};

fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .map(|l| l.to_string())
        })
        .and_then(|l| {
            l.split_whitespace()
                .nth(1)
                .and_then(|v| v.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let iterations: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(3000);
    let width: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(160);
    let height = width * 3 / 4;
    let times: Vec<f64> = (0..9).map(|i| i as f64 / 8.0).collect();
    let train_data = train_scene::dataset_of(&train_scene::cameras(width, height), &times);
    let held_times: Vec<f64> = (0..4).map(|i| (i as f64 + 0.5) / 4.0).collect();
    let held = train_scene::dataset_of(&train_scene::held_out_cameras(width, height), &held_times);
    let init = train_scene::points(32, 24, &[0.0, 0.5, 1.0]);
    let mut config = TrainConfig {
        iterations,
        checkpoint_every: 0,
        ..Default::default()
    };
    let scale = iterations as f64 / 30_000.0;
    config.degree_every = (1000.0 * scale).max(1.0) as u64;
    config.densify.from_iteration = (500.0 * scale) as u64;
    config.densify.until_iteration = (15_000.0 * scale) as u64;
    config.densify.opacity_reset_every = 0;
    let dir = tempfile::tempdir().expect("temp dir");
    let s = train(
        &CpuBackend,
        &config,
        &train_data,
        &init,
        dir.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .expect("training");
    let model = load_model(&s.model_path).expect("model");
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let train_psnr =
        mean(evaluate_psnr(&CpuBackend, &model, &train_data, s.background).expect("eval"));
    let held_psnr = mean(evaluate_psnr(&CpuBackend, &model, &held, s.background).expect("eval"));
    println!(
        "{width}x{height}, {} train views, {} held-out views, {iterations} iterations (batch {}): {:.1} s, {:.2} it/s, \
         {} Gaussians (from {}), train PSNR {train_psnr:.2} dB, held-out PSNR {held_psnr:.2} dB, peak RSS {:.0} MiB",
        train_data.views.len(),
        held.views.len(),
        config.batch_size,
        s.seconds,
        iterations as f64 / s.seconds,
        model.len(),
        init.xyz.len(),
        peak_rss_mib()
    );
}
