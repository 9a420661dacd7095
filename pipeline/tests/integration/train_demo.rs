//! Training on the demo scene (`fixtures/demo.toml`), drawn by the simulator's mesh
//! rasteriser (not by the Gaussian renderer): the 4 video cameras at every 3rd frame, each
//! at its own exact timestamp, at half resolution; initial points unprojected from their
//! depth maps (as a point-map initialisation would give). Reports held-out PSNR on the 4
//! held-out cameras at in-between frames, iterations/s, Gaussian count and peak memory.
//! Long: ignored by default. Run (numbers in BENCHMARKS.md, "Training"):
//! `TRAIN_DEMO_ITERS=1000 cargo test --release -p pipeline --test integration -- --ignored --nocapture train_demo::`

use crate::common;

use common::demo::{Trained, train_and_measure};
use splat4d::train::NoHooks;

const SCALE: usize = 2;

fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .map(str::to_string)
        })
        .and_then(|l| {
            l.split_whitespace()
                .nth(1)
                .and_then(|v| v.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

#[test]
#[ignore = "trains for minutes; run explicitly for BENCHMARKS.md"]
fn demo_scene_trains_and_reports_held_out_psnr() {
    let iterations: u64 = std::env::var("TRAIN_DEMO_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let (train_data, held_data, init) = common::demo::demo_data(SCALE);
    let config = common::demo::train_config(iterations);
    let dir = tempfile::tempdir().unwrap();
    let Trained {
        model,
        summary,
        train_psnr,
        held_psnr,
    } = train_and_measure(
        &config,
        (&train_data, &held_data, &init),
        dir.path(),
        &mut NoHooks,
    );
    let v0 = &train_data.views[0].image;
    println!(
        "demo {}x{}: {} train views, {} held-out views, {} initial points, {iterations} iterations (batch {}): \
         {:.0} s, {:.3} it/s, {} Gaussians, train PSNR {train_psnr:.2} dB, held-out PSNR {held_psnr:.2} dB, peak RSS {:.0} MiB",
        v0.width,
        v0.height,
        train_data.views.len(),
        held_data.views.len(),
        init.xyz.len(),
        config.batch_size,
        summary.seconds,
        iterations as f64 / summary.seconds,
        model.len(),
        peak_rss_mib()
    );
    assert!(
        train_psnr.is_finite() && held_psnr > 12.0,
        "held-out PSNR {held_psnr:.2} dB"
    );
}
