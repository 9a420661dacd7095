//! Adam on the GPU (`GpuAdam`, parameters and moments resident between steps) gives
//! `train::optim::Adam`: 12 steps on a random model with every colour degree (so the
//! colour stride is past the shader's 20 rate slots), fresh random gradients each step
//! with entries of 0, ±1e6 and ±1e-12 among normal ones, and the scheduled rates of each
//! step (the position rate decays). Parameters and both moments agree per element within
//! 1e-5 relative (parameters: relative to `max(|p|, 1e-6)`).
//!
//! Adapter policy as in `gpu_parity.rs`: without an adapter the tests skip with a message,
//! except under `CI=true`, where that is a failure.

use crate::common;

use common::{Rng, SceneSpec, random_scene};
use splat4d::render::RenderError;
use splat4d::render::gpu::GpuBackend;
use splat4d::train::gpu::GpuAdam;
use splat4d::train::optim::{Adam, LearningRates, ParamBuffers};
use splat4d::{Gaussians, Gradients};

/// Largest accepted relative error per element.
const TOLERANCE: f64 = 1e-5;

fn gpu() -> Option<&'static GpuBackend> {
    common::gpu("GPU Adam test")
}

fn model(count: usize) -> Gaussians<f32> {
    random_scene(
        3,
        SceneSpec {
            count,
            ..Default::default()
        },
    )
    .cast::<f32>()
}

/// A gradient entry: mostly normal values over four decades, sometimes an extreme one.
fn entry(rng: &mut Rng) -> f32 {
    let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
    match (rng.uniform() * 20.0) as u32 {
        0 => 0.0,
        1 => sign * 1e6,
        2 => sign * 1e-12,
        _ => (rng.normal() * 10f64.powf(rng.range(-3.0, 1.0))) as f32,
    }
}

fn random_gradients(rng: &mut Rng, model: &Gaussians<f32>) -> Gradients<f32> {
    let mut g = Gradients::zeros_like(model, false);
    for v in g
        .means
        .iter_mut()
        .chain(&mut g.log_scales)
        .chain(&mut g.rot_left)
        .chain(&mut g.rot_right)
        .flatten()
        .chain(&mut g.opacity_logits)
        .chain(&mut g.colours)
    {
        *v = entry(rng);
    }
    g
}

/// Per-element error of `got` against `want`, relative to how far each value travelled
/// (`scale`, at least `floor`): an f32 computation is good to a few ulps of the values it
/// worked with, so a value that cancelled towards zero is judged by the magnitudes it
/// came from, not by what is left. GPUs may round division and square root less tightly
/// than the CPU (WGSL allows 2.5 ulp) and fuse multiply-adds.
fn worst(
    got: impl Iterator<Item = f32>,
    want: impl Iterator<Item = f32>,
    scale: &[f64],
    floor: f64,
) -> f64 {
    got.zip(want)
        .zip(scale)
        .map(|((a, b), s)| {
            if a == b {
                0.0
            } else {
                (a as f64 - b as f64).abs() / s.max(floor)
            }
        })
        .fold(0.0, f64::max)
}

/// How far each value has travelled: its first magnitude plus every step's change.
struct Travel(Vec<f64>);

impl Travel {
    fn start(values: impl Iterator<Item = f32>) -> (Self, Vec<f32>) {
        let now: Vec<f32> = values.collect();
        (Self(now.iter().map(|v| v.abs() as f64).collect()), now)
    }

    fn step(&mut self, before: &mut Vec<f32>, values: impl Iterator<Item = f32>) {
        let now: Vec<f32> = values.collect();
        for ((t, a), b) in self.0.iter_mut().zip(before.iter()).zip(&now) {
            *t += (*b as f64 - *a as f64).abs();
        }
        *before = now;
    }
}

fn params(m: &Gaussians<f32>) -> ParamBuffers {
    ParamBuffers {
        means: m.means.clone(),
        log_scales: m.log_scales.clone(),
        rot_left: m.rot_left.clone(),
        rot_right: m.rot_right.clone(),
        opacity_logits: m.opacity_logits.clone(),
        colours: m.colours.clone(),
    }
}

#[test]
fn gpu_adam_matches_the_cpu_over_steps_with_extreme_gradients() {
    let Some(gpu) = gpu() else { return };
    let mut cpu_model = model(300);
    assert!(
        3 * cpu_model.coeffs_per_channel() > 20,
        "the colour stride should pass the rate slots"
    );
    let mut gpu_model = cpu_model.clone();
    let mut adam = Adam::new(&cpu_model);
    let mut on_gpu = GpuAdam::new(gpu, &gpu_model).unwrap();
    let mut rng = Rng(11);
    let steps = 12;
    let schedule = LearningRates::default();
    let (mut p_travel, mut p_now) = Travel::start(params(&cpu_model).values());
    let (mut m_travel, mut m_now) = Travel::start(adam.m.values());
    let (mut v_travel, mut v_now) = Travel::start(adam.v.values());
    for it in 0..steps {
        let grads = random_gradients(&mut rng, &cpu_model);
        let rates = schedule.at(it, steps, 2.5);
        adam.step(&mut cpu_model, &grads, &rates);
        p_travel.step(&mut p_now, params(&cpu_model).values());
        m_travel.step(&mut m_now, adam.m.values());
        v_travel.step(&mut v_now, adam.v.values());
        on_gpu.set_gradients(gpu, &grads).unwrap();
        on_gpu.step(gpu, &rates).unwrap();
    }
    assert_eq!(on_gpu.steps(), steps);
    on_gpu.download(gpu, &mut gpu_model).unwrap();
    let (m, v) = on_gpu.moments(gpu).unwrap();
    let p_err = worst(
        params(&gpu_model).values(),
        params(&cpu_model).values(),
        &p_travel.0,
        1e-6,
    );
    let m_err = worst(m.values(), adam.m.values(), &m_travel.0, 1e-37);
    let v_err = worst(v.values(), adam.v.values(), &v_travel.0, 1e-37);
    eprintln!("after {steps} steps: parameters {p_err:.1e}, m {m_err:.1e}, v {v_err:.1e}");
    // The parameters moved (the test is not vacuous).
    let start = params(&model(300));
    let magnitude: Vec<f64> = start.values().map(|v| v.abs() as f64).collect();
    let moved = worst(
        params(&cpu_model).values(),
        start.values(),
        &magnitude,
        1e-6,
    );
    assert!(moved > 1e-3, "the parameters barely moved ({moved:.1e})");
    for (what, err) in [("parameters", p_err), ("m", m_err), ("v", v_err)] {
        assert!(err <= TOLERANCE, "{what}: relative error {err:.2e}");
    }
    // Untouched values stay: the model's other fields are as uploaded.
    assert_eq!(gpu_model.active, cpu_model.active);
    assert_eq!(gpu_model.len(), cpu_model.len());
}

#[test]
fn an_empty_model_steps_and_wrong_shapes_are_errors() {
    let Some(gpu) = gpu() else { return };
    let empty = model(0);
    let mut on_gpu = GpuAdam::new(gpu, &empty).unwrap();
    let rates = LearningRates::default().at(0, 10, 1.0);
    on_gpu
        .set_gradients(gpu, &Gradients::zeros_like(&empty, false))
        .unwrap();
    on_gpu.step(gpu, &rates).unwrap();
    let mut back = empty.clone();
    on_gpu.download(gpu, &mut back).unwrap();
    assert_eq!(back.len(), 0);

    let m = model(5);
    let on_gpu = GpuAdam::new(gpu, &m).unwrap();
    let mut grads = Gradients::zeros_like(&m, false);
    grads.colours.pop();
    let err = on_gpu.set_gradients(gpu, &grads).unwrap_err();
    assert!(matches!(err, RenderError::GradientLength { .. }), "{err}");
    let err = on_gpu
        .set_gradients(gpu, &Gradients::zeros_like(&model(4), false))
        .unwrap_err();
    assert!(matches!(err, RenderError::ModelMismatch { .. }), "{err}");
    let mut other = model(6);
    let err = on_gpu.download(gpu, &mut other).unwrap_err();
    assert!(matches!(err, RenderError::ModelMismatch { .. }), "{err}");
}

/// With `Adam::frozen`, the GPU leaves the first Gaussians' values and moments exactly as
/// they were and steps the rest as the CPU does.
#[test]
fn gpu_adam_leaves_the_frozen_gaussians_alone() {
    let Some(gpu) = gpu() else { return };
    let start = model(50);
    let (mut cpu_model, mut gpu_model) = (start.clone(), start.clone());
    let mut adam = Adam::new(&cpu_model);
    adam.frozen = 20;
    let mut on_gpu = GpuAdam::from_state(gpu, &gpu_model, &adam).unwrap();
    let mut rng = Rng(5);
    let schedule = LearningRates::default();
    for it in 0..4 {
        let grads = random_gradients(&mut rng, &cpu_model);
        let rates = schedule.at(it, 4, 2.5);
        adam.step(&mut cpu_model, &grads, &rates);
        on_gpu.set_gradients(gpu, &grads).unwrap();
        on_gpu.step(gpu, &rates).unwrap();
    }
    on_gpu.download(gpu, &mut gpu_model).unwrap();
    let k = 3 * start.coeffs_per_channel();
    for got in [&cpu_model, &gpu_model] {
        assert_eq!(got.means[..20], start.means[..20]);
        assert_eq!(got.rot_right[..20], start.rot_right[..20]);
        assert_eq!(got.opacity_logits[..20], start.opacity_logits[..20]);
        assert_eq!(got.colours[..20 * k], start.colours[..20 * k]);
        assert_ne!(got.means[20..], start.means[20..]);
    }
    let (m, _) = on_gpu.moments(gpu).unwrap();
    assert!(m.means[..20].iter().flatten().all(|&x| x == 0.0));
    assert!(adam.m.colours[..20 * k].iter().all(|&x| x == 0.0));
    let scale = vec![1.0; 50 * 4];
    let err = worst(
        gpu_model.means.as_flattened().iter().copied(),
        cpu_model.means.as_flattened().iter().copied(),
        &scale,
        1.0,
    );
    assert!(err <= TOLERANCE, "means: {err:.2e}");
}
