//! The neural decay's f_θ on the device (`decay::gpu::GpuDecay`) against the host's
//! `Mlp` in f64: τ of every Gaussian and the weight gradient dL/dθ from dL/dτ, for both
//! input layouts, several workgroups and a partial last one; and the hard cases (zero
//! upstream, huge inputs, τ saturated at the ends of its range). Runs on lavapipe; without
//! an adapter the tests skip, except under `CI=true`.

use crate::common;

use common::{Rng, SceneSpec, random_scene};
use splat4d::Gaussians;
use splat4d::decay::gpu::GpuDecay;
use splat4d::decay::inputs::input_rows;
use splat4d::decay::mlp::{Mlp, MlpAdam};
use splat4d::decay::variants::{decayed_logit, exp_factor, pow_factor};
use splat4d::decay::{DecayConfig, DecayInputs, DecayVariant};
use splat4d::render::gpu::GpuBackend;

fn gpu() -> Option<&'static GpuBackend> {
    common::gpu("GPU neural decay test")
}

/// `count` random Gaussians (f32), spread in position, time, scale and opacity.
fn model(seed: u64, count: usize) -> Gaussians<f32> {
    let spec = SceneSpec {
        count,
        log_scale: (-3.0, 0.5),
        logit: (-4.0, 4.0),
        ..Default::default()
    };
    random_scene(seed, spec).cast()
}

/// τ and dL/dθ of the f64 reference for `model`, f_θ `mlp` and upstream `d_tau`.
fn reference(
    model: &Gaussians<f32>,
    mlp: &Mlp<f32>,
    config: &DecayConfig,
    d_tau: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let m64: Gaussians<f64> = model.cast();
    let x = input_rows(&m64, config.inputs);
    let mlp = mlp.cast::<f64>();
    let cache = mlp.forward(&x);
    let (lo, hi) = (config.f_min as f32 as f64, config.f_max as f32 as f64);
    let tau = cache.z.iter().map(|&z| Mlp::tau(z, lo, hi)).collect();
    let d_z: Vec<f64> = cache
        .z
        .iter()
        .zip(d_tau)
        .map(|(&z, &d)| d * Mlp::tau_derivative(z, lo, hi))
        .collect();
    (tau, mlp.backward(&x, &cache, &d_z, false).params)
}

fn device(backend: &GpuBackend, config: &DecayConfig, mlp: &Mlp<f32>) -> GpuDecay {
    let adam = MlpAdam::new(mlp.params.len(), 1e-3, 1e-4);
    GpuDecay::new(backend, config, mlp, &adam).unwrap()
}

/// Largest |a − b| relative to the largest |b|.
fn max_rel(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-30);
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y).abs())
        .fold(0.0, f64::max)
        / scale
}

fn upstream(seed: u64, n: usize) -> Vec<f32> {
    let mut rng = Rng(seed);
    (0..n).map(|_| rng.range(-1.0, 1.0) as f32).collect()
}

#[test]
fn device_tau_and_weight_gradient_match_the_f64_reference() {
    let Some(gpu) = gpu() else { return };
    // Official inputs with the default f_θ (9 → 32 → 32 → 1), paper inputs with a small
    // one-hidden-layer f_θ; 1000 and 3000 Gaussians: 4 and 12 workgroups, the last partial.
    let cases = [
        (DecayInputs::Official, 2, 32, 3000, 1),
        (DecayInputs::Paper, 1, 16, 1000, 2),
        (DecayInputs::Official, 3, 8, 257, 3),
    ];
    for (inputs, hidden_layers, hidden_width, count, seed) in cases {
        // The wide range keeps τ's resolution in f32 far above the compared error.
        let config = DecayConfig {
            inputs,
            hidden_layers,
            hidden_width,
            f_min: 0.01,
            f_max: 1.0,
            ..DecayConfig::neural()
        };
        let mlp = Mlp::<f32>::new(&config.mlp_dims(), seed);
        let m = model(seed + 10, count);
        let d_tau = upstream(seed + 20, count);
        let d64: Vec<f64> = d_tau.iter().map(|&d| d as f64).collect();
        let (tau_ref, grad_ref) = reference(&m, &mlp, &config, &d64);
        let mut dev = device(gpu, &config, &mlp);
        let tau = dev.tau(gpu, &m).unwrap();
        let grad = dev.weight_gradient(gpu, &m, &d_tau).unwrap();
        let e_tau = max_rel(&tau, &tau_ref);
        let e_grad = max_rel(&grad, &grad_ref);
        eprintln!(
            "{inputs:?} {:?}: τ error {e_tau:.2e}, dL/dθ error {e_grad:.2e}",
            config.mlp_dims()
        );
        assert!(e_tau < 1e-4, "{inputs:?}: τ differs by {e_tau:e}");
        assert!(e_grad < 1e-4, "{inputs:?}: dL/dθ differs by {e_grad:e}");
        assert!(
            grad_ref.iter().any(|g| g.abs() > 1e-3),
            "a vanishing reference gradient"
        );
        // Deterministic: the same bits on a second run.
        assert_eq!(grad, dev.weight_gradient(gpu, &m, &d_tau).unwrap());
    }
}

#[test]
fn device_decay_hard_cases() {
    let Some(gpu) = gpu() else { return };
    let config = DecayConfig::neural();
    let mlp = Mlp::<f32>::new(&config.mlp_dims(), 5);
    let mut dev = device(gpu, &config, &mlp);
    let (lo, hi) = (config.f_min as f32, config.f_max as f32);

    // A zero upstream gives an exactly zero gradient.
    let m = model(31, 600);
    let zero = dev.weight_gradient(gpu, &m, &vec![0.0; 600]).unwrap();
    assert!(zero.iter().all(|&g| g == 0.0), "zero dL/dτ: {zero:?}");

    // Huge inputs: one Gaussian far out, logits and log-scales at extremes; the z-scoring
    // tames them and the result still matches the reference.
    let mut m = model(32, 500);
    m.means[7] = [1e15, -1e15, 1e14, 1e12];
    m.opacity_logits[8] = 1e30;
    m.opacity_logits[9] = -1e30;
    m.log_scales[10] = [1e12, -1e12, 1e10, -1e10];
    let d_tau = upstream(33, 500);
    let d64: Vec<f64> = d_tau.iter().map(|&d| d as f64).collect();
    let (tau_ref, grad_ref) = reference(&m, &mlp, &config, &d64);
    let tau = dev.tau(gpu, &m).unwrap();
    let grad = dev.weight_gradient(gpu, &m, &d_tau).unwrap();
    assert!(tau.iter().all(|&t| t >= lo && t <= hi), "τ out of range");
    assert!(grad.iter().all(|g| g.is_finite()), "non-finite gradient");
    assert!(max_rel(&tau, &tau_ref) < 1e-6, "τ with huge inputs");
    assert!(max_rel(&grad, &grad_ref) < 1e-3, "dL/dθ with huge inputs");

    // τ saturated at both ends of its range: weights scaled up so |z| is in the
    // millions. No NaN, τ exactly at f_min or f_max, and a zero gradient (dτ/dz = 0).
    let mut big = mlp.clone();
    big.params.iter_mut().for_each(|p| *p *= 400.0);
    let mut dev = device(gpu, &config, &big);
    let m = model(34, 700);
    let tau = dev.tau(gpu, &m).unwrap();
    let grad = dev.weight_gradient(gpu, &m, &upstream(35, 700)).unwrap();
    // What f_min + (f_max − f_min)·1 rounds to in f32 (the host computes the same).
    let top = lo + (hi - lo);
    assert!(tau.iter().all(|&t| t == lo || t == top), "τ not saturated");
    assert!(
        tau.contains(&lo) && tau.contains(&top),
        "both ends expected"
    );
    assert!(grad.iter().all(|&g| g == 0.0), "saturated τ: {grad:?}");
}

#[test]
fn device_decay_round_trips_f_theta_and_rejects_unsupported_shapes() {
    let Some(gpu) = gpu() else { return };
    let config = DecayConfig::neural();
    let mlp = Mlp::<f32>::new(&config.mlp_dims(), 9);
    let mut adam = MlpAdam::new(mlp.params.len(), 1e-5, 1e-4);
    adam.step = 17;
    adam.m
        .iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v = i as f32);
    adam.v
        .iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v = 0.5 * i as f32);
    let dev = GpuDecay::new(gpu, &config, &mlp, &adam).unwrap();
    let mut back_mlp = Mlp::<f32>::new(&config.mlp_dims(), 0);
    let mut back_adam = MlpAdam::new(mlp.params.len(), 1e-5, 1e-4);
    dev.download(gpu, &mut back_mlp, &mut back_adam).unwrap();
    assert_eq!(back_mlp, mlp);
    assert_eq!(back_adam, adam);

    let wide = DecayConfig {
        hidden_width: 64,
        ..DecayConfig::neural()
    };
    assert!(!GpuDecay::supports(&wide));
    assert!(!GpuDecay::supports(&DecayConfig::none()));
    assert!(GpuDecay::supports(&config));
    for variant in [DecayVariant::Constant, DecayVariant::Pow, DecayVariant::Exp] {
        // The hand-tuned variants need no f_θ: any width will do.
        assert!(GpuDecay::supports(&DecayConfig {
            variant,
            ..wide.clone()
        }));
    }
    let wide_mlp = Mlp::<f32>::new(&wide.mlp_dims(), 0);
    let wide_adam = MlpAdam::new(wide_mlp.params.len(), 1e-5, 1e-4);
    assert!(GpuDecay::new(gpu, &wide, &wide_mlp, &wide_adam).is_err());
}

/// The write-back on the device against the host's `variants::decayed_logit` (f64): τ for
/// the Gaussians seen in the batch, β for the rest, over ordinary and extreme logits
/// (the −30 floor, ±1e30, ±∞, NaN); never raises a logit, leaves non-finite ones alone,
/// and reports the step's statistics.
#[test]
fn device_write_back_matches_the_host_decayed_logit() {
    let Some(gpu) = gpu() else { return };
    let config = DecayConfig::neural();
    let mlp = Mlp::<f32>::new(&config.mlp_dims(), 6);
    let mut dev = device(gpu, &config, &mlp);
    let mut m = model(41, 700);
    let extremes = [
        0.0,
        5.0,
        -5.0,
        20.0,
        50.0,
        89.0,
        100.0,
        -29.99,
        -30.0,
        -31.0,
        -100.0,
        1e30,
        -1e30,
        1e-8,
        -1e-8,
        16.0,
        -16.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ];
    for (k, &x) in extremes.iter().enumerate() {
        m.opacity_logits[3 * k] = x;
        m.opacity_logits[3 * k + 1] = x;
    }
    let seen: Vec<bool> = (0..700).map(|i| i % 3 != 1).collect();
    // The host's τ (f32 path of `DecayHooks`), before the write-back.
    let tau: Vec<f32> = {
        let cache = mlp.forward(&input_rows(&m, config.inputs));
        let (lo, hi) = (config.f_min as f32, config.f_max as f32);
        cache
            .z
            .iter()
            .map(|&z| {
                if z.is_nan() {
                    0.5 * (lo + hi)
                } else {
                    Mlp::tau(z, lo, hi)
                }
            })
            .collect()
    };
    let before = m.opacity_logits.clone();
    let out = dev.decay_opacities(gpu, &mut m, &seen).unwrap();
    let mut worst = 0.0f64;
    for i in 0..700 {
        let (x, y) = (before[i], m.opacity_logits[i]);
        let d = if seen[i] { tau[i] as f64 } else { config.beta };
        let want = decayed_logit(x, d);
        if !x.is_finite() {
            assert!(y.to_bits() == x.to_bits(), "{i}: non-finite {x} became {y}");
            continue;
        }
        assert!(y <= x, "{i}: logit {x} rose to {y}");
        assert!(
            y >= (-30.0f32).min(x),
            "{i}: logit {x} fell below the floor: {y}"
        );
        let err = (y as f64 - want as f64).abs() / (x.abs() as f64).max(1.0);
        worst = worst.max(err);
        assert!(
            err < 1e-5,
            "{i}: logit {x}, factor {d}: device {y}, host {want}"
        );
    }
    eprintln!("write-back: worst error {worst:.2e} (relative to max(1, |logit|))");
    assert_eq!(out.visible, seen.iter().filter(|&&s| s).count());
    let lo = tau
        .iter()
        .zip(&seen)
        .filter(|(_, s)| **s)
        .map(|(t, _)| *t)
        .fold(1.0f32, f32::min);
    assert_eq!(out.min_factor, lo);
    assert_eq!(out.max_factor, config.beta as f32);
    let sum: f64 = (0..700)
        .map(|i| if seen[i] { tau[i] as f64 } else { config.beta })
        .sum();
    assert!(
        (out.factor_sum as f64 - sum).abs() < 1e-4 * sum,
        "factor sum"
    );

    // An empty model: nothing to decay, an empty τ and a zero gradient.
    let mut empty = model(42, 0);
    assert!(dev.tau(gpu, &empty).unwrap().is_empty());
    let g = dev.weight_gradient(gpu, &empty, &[]).unwrap();
    assert!(g.iter().all(|&v| v == 0.0) && g.len() == mlp.params.len());
    assert_eq!(
        dev.decay_opacities(gpu, &mut empty, &[]).unwrap().visible,
        0
    );
}

/// The hand-tuned variants' write-back on the device against the host's factors in f64
/// (`constant`, `pow_factor`, `exp_factor` of the current opacity) and `decayed_logit`:
/// seen Gaussians get the variant's factor, the others β; opacities from 1e-13 to
/// 1 − 1e-13 and the −30 floor; the statistics match.
#[test]
fn device_hand_tuned_write_back_matches_the_host_factors() {
    let Some(gpu) = gpu() else { return };
    for variant in [DecayVariant::Constant, DecayVariant::Pow, DecayVariant::Exp] {
        let config = DecayConfig {
            variant,
            constant: 0.98,
            f_min: 0.9,
            f_max: 0.99,
            ..Default::default()
        };
        let mlp = Mlp::<f32>::new(&config.mlp_dims(), 3);
        let mut dev = device(gpu, &config, &mlp);
        let mut m = model(43, 600);
        for (k, &x) in [-30.0, -29.0, -12.0, -3.0, 0.0, 1e-6, 3.0, 12.0, 29.0]
            .iter()
            .enumerate()
        {
            m.opacity_logits[2 * k] = x;
        }
        let seen: Vec<bool> = (0..600).map(|i| i % 5 != 2).collect();
        let before = m.opacity_logits.clone();
        let factor = |x: f32| {
            let o = 1.0 / (1.0 + (-(x as f64)).exp());
            match variant {
                DecayVariant::Constant => config.constant,
                DecayVariant::Pow => pow_factor(o, &config),
                _ => exp_factor(o, &config),
            }
        };
        let out = dev.decay_opacities(gpu, &mut m, &seen).unwrap();
        let (mut lo, mut hi, mut sum) = (f64::INFINITY, 0.0f64, 0.0);
        for i in 0..600 {
            let x = before[i];
            let d = if seen[i] { factor(x) } else { config.beta };
            (lo, hi, sum) = (lo.min(d), hi.max(d), sum + d);
            let want = decayed_logit(x, d);
            let y = m.opacity_logits[i];
            assert!(y <= x, "{variant:?} {i}: logit {x} rose to {y}");
            let err = (y as f64 - want as f64).abs() / (x.abs() as f64).max(1.0);
            assert!(
                err < 1e-5,
                "{variant:?} {i}: logit {x}, factor {d}: device {y}, host {want}"
            );
        }
        assert_eq!(out.visible, seen.iter().filter(|&&s| s).count());
        assert!(!out.skipped, "no f_θ, nothing to skip");
        for (got, want) in [(out.min_factor, lo), (out.max_factor, hi)] {
            assert!(
                (got as f64 - want).abs() < 1e-6,
                "{variant:?}: factor range {got} against {want}"
            );
        }
        assert!((out.factor_sum as f64 - sum).abs() < 1e-4 * sum);
        assert_eq!(dev.steps(), 0, "{variant:?}: f_θ does not step");
    }
}
