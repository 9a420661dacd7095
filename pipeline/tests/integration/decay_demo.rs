//! The 4C4D decay ablation on the demo scene (`fixtures/demo.toml`, drawn by the
//! simulator's mesh rasteriser): the 4 video cameras train, the 4 held-out cameras at
//! in-between frames evaluate. Trains every variant of
//! `DecayConfig::variants_for_ablation()` with the same 4DGS settings and prints held-out
//! PSNR and Gaussian count (numbers in BENCHMARKS.md, "4C4D decay"). Built like
//! `train_demo.rs`. Long: ignored by default. Run:
//! `DECAY_DEMO_ITERS=1500 DECAY_DEMO_SCALE=4 cargo test --release -p pipeline --test integration -- --ignored --nocapture decay_demo::`
//! (`DECAY_DEMO_ONLY=none,neural` picks variants by label prefix;
//! `DECAY_DEMO_MAX_GAUSSIANS=N` caps densification, for long stability runs.)

use crate::common;

use common::demo::{Trained, train_and_measure};
use splat4d::decay::{DecayConfig, DecayHooks};
use std::io::Write;

fn env_or<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

#[test]
#[ignore = "trains every decay variant for minutes; run explicitly for BENCHMARKS.md"]
fn decay_variants_on_the_demo_scene() {
    let iterations: u64 = env_or("DECAY_DEMO_ITERS", 1500);
    let scale: usize = env_or("DECAY_DEMO_SCALE", 4);
    let warmup: u64 = env_or("DECAY_DEMO_WARMUP", 500);
    let only: Vec<String> = std::env::var("DECAY_DEMO_ONLY")
        .map(|s| s.split(',').map(str::to_string).collect())
        .unwrap_or_default();
    let (train_data, held_data, init) = common::demo::demo_data(scale);
    let mut config = common::demo::train_config(iterations);
    config.densify.max_gaussians = env_or("DECAY_DEMO_MAX_GAUSSIANS", config.densify.max_gaussians);
    let v0 = &train_data.views[0].image;
    println!(
        "decay demo {}x{}: {} train views, {} held-out views, {} initial points, {iterations} iterations (batch {}), warm-up {warmup}",
        v0.width,
        v0.height,
        train_data.views.len(),
        held_data.views.len(),
        init.xyz.len(),
        config.batch_size,
    );
    println!("| variant | held-out PSNR (dB) | train PSNR (dB) | Gaussians | seconds |");
    println!("|---|---|---|---|---|");
    let mut results = Vec::new();
    for (label, mut decay) in DecayConfig::variants_for_ablation() {
        if !only.is_empty() && !only.iter().any(|o| label.starts_with(o.as_str())) {
            continue;
        }
        decay.warmup = warmup;
        let mut hooks = DecayHooks::new(&decay).unwrap();
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
            &mut hooks,
        );
        println!(
            "| {label} | {held_psnr:.2} | {train_psnr:.2} | {} | {:.0} |",
            model.len(),
            summary.seconds
        );
        // Stability: the Gaussian count over the run (log.csv) and the last decay step.
        let log = std::fs::read_to_string(dir.path().join("log.csv")).unwrap();
        let counts: Vec<usize> = log
            .lines()
            .skip(1)
            .filter_map(|l| l.split(',').nth(5)?.parse().ok())
            .collect();
        let opacity: Vec<f32> = model
            .opacity_logits
            .iter()
            .map(|&o| 1.0 / (1.0 + (-o).exp()))
            .collect();
        println!(
            "  {label}: Gaussians min {} max {} final {}; opacity mean {:.3} min {:.2e}; last decay step {:?}",
            counts.iter().min().unwrap_or(&0),
            counts.iter().max().unwrap_or(&0),
            model.len(),
            opacity.iter().sum::<f32>() / opacity.len().max(1) as f32,
            opacity.iter().cloned().fold(f32::INFINITY, f32::min),
            hooks.last_stats(),
        );
        std::io::stdout().flush().ok();
        assert!(model.opacity_logits.iter().all(|o| o.is_finite()));
        results.push((label, held_psnr));
    }
    assert!(results.iter().all(|(_, p)| p.is_finite()));
}
