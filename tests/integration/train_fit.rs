//! The trainer fits an analytic dynamic scene (not drawn by the Gaussian renderer) to
//! more than 30 dB PSNR on its training views.

use crate::train_scene;

use splat4d::CpuBackend;
use splat4d::train::{NoHooks, TrainConfig, evaluate_psnr, train};
use splat4d::{NoProgress, load_model};

/// Train 300 iterations on the analytic scene at `width`×`height` (`resolution` of it),
/// then measure every full-size training view: (mean PSNR, worst PSNR).
fn fit(width: u32, height: u32, resolution: f64) -> (f64, f64) {
    let data = train_scene::dataset(width, height);
    let init = train_scene::points(20, 15, &[0.0, 0.5, 1.0]);
    let mut config = TrainConfig {
        background: splat4d::train::Background::Colour([0.0; 3]),
        iterations: 300,
        resolution,
        checkpoint_every: 0,
        ..Default::default()
    };
    config.degree_every = 200;
    config.densify.from_iteration = 100;
    config.densify.until_iteration = 250;
    config.densify.every = 100;
    config.densify.opacity_reset_every = 0;
    let (dir, summary) = train_scene::train_cpu(&config, &data, &init);
    assert!(dir.path().join("log.csv").exists());
    let model = load_model(&summary.model_path).unwrap();
    let psnr = evaluate_psnr(&CpuBackend, &model, &data, config.background.resolve(&data)).unwrap();
    let mean = psnr.iter().sum::<f64>() / psnr.len() as f64;
    let min = psnr.iter().copied().fold(f64::INFINITY, f64::min);
    eprintln!(
        "fit {width}×{height} at resolution {resolution}: {} Gaussians, mean PSNR {mean:.2} dB, worst {min:.2} dB, {:.1}s",
        model.len(),
        summary.seconds
    );
    (mean, min)
}

#[test]
fn small_dynamic_scene_fits_above_30_db() {
    let (mean, min) = fit(64, 48, 1.0);
    assert!(mean > 30.0, "mean training-view PSNR {mean:.2} dB");
    assert!(min > 28.0, "worst training-view PSNR {min:.2} dB");
}

#[test]
fn scene_changes_over_time_and_between_cameras() {
    let data = train_scene::dataset(64, 48);
    let diff = |a: usize, b: usize| {
        let (x, y) = (&data.views[a].image.data, &data.views[b].image.data);
        x.iter()
            .zip(y)
            .map(|(&p, &q)| (p as f64 - q as f64).abs())
            .sum::<f64>()
            / x.len() as f64
            / 255.0
    };
    // Same camera at t = 0 and t = 1 (the disc moved); two cameras at t = 0.
    assert!(diff(0, 16) > 0.01, "{}", diff(0, 16));
    assert!(diff(0, 1) > 0.01, "{}", diff(0, 1));
}

/// `resolution = 0.5` trains on half-size images; the model still draws the full-size
/// views, close to the quality of training at full size. Bad resolutions are refused.
#[test]
fn half_resolution_training_renders_the_full_size_views() {
    let (mean, _) = fit(128, 96, 0.5);
    assert!(mean > 32.0, "mean full-size PSNR {mean:.2} dB");
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(4, 3, &[0.0]);
    let dir = tempfile::tempdir().unwrap();
    for bad in [0.0, -0.5, 1.5, f64::NAN] {
        let c = TrainConfig {
            background: splat4d::train::Background::Colour([0.0; 3]),
            iterations: 2,
            resolution: bad,
            ..Default::default()
        };
        let e = train(
            &CpuBackend,
            &c,
            &data,
            &init,
            dir.path(),
            false,
            &mut NoHooks,
            &NoProgress,
        )
        .unwrap_err();
        assert!(e.to_string().contains("resolution"), "{e}");
    }
}

/// A run as long as the opacity reset period (3000 steps by default, so `iterations =
/// 3000` with the default schedule) must not end on a reset: the last half period has none.
#[test]
fn no_opacity_reset_in_the_last_half_period() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(12, 9, &[0.0, 1.0]);
    let run = |iterations: u64, reset_every: u64| {
        let mut config = TrainConfig {
            background: splat4d::train::Background::Colour([0.0; 3]),
            iterations,
            checkpoint_every: 0,
            ..Default::default()
        };
        // Resets in the densification window, no densification (every 1000).
        config.densify.from_iteration = 10;
        config.densify.until_iteration = 100;
        config.densify.every = 1000;
        config.densify.opacity_reset_every = reset_every;
        let (_dir, summary) = train_scene::train_cpu(&config, &data, &init);
        let model = load_model(&summary.model_path).unwrap();
        let max_opacity = model
            .opacity_logits
            .iter()
            .map(|&o| 1.0 / (1.0 + (-o as f64).exp()))
            .fold(0.0, f64::max);
        let psnr =
            evaluate_psnr(&CpuBackend, &model, &data, config.background.resolve(&data)).unwrap();
        (max_opacity, psnr.iter().sum::<f64>() / psnr.len() as f64)
    };
    // The reset due at the last step (80 of 80) does not come: the run ends as one
    // without resets, with its learned opacities (a reset caps them at 0.01).
    let (opacity, psnr) = run(80, 80);
    let (_, no_reset_psnr) = run(80, 0);
    eprintln!("max opacity {opacity}, PSNR {psnr:.2} dB (no resets: {no_reset_psnr:.2} dB)");
    assert!(opacity > 0.05, "max opacity {opacity}");
    assert_eq!(psnr, no_reset_psnr);
    // One due with half the run left (40 of 80) still comes.
    let (_, early_reset_psnr) = run(80, 40);
    assert_ne!(early_reset_psnr, no_reset_psnr);
}
