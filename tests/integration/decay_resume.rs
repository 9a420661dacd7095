//! Training with the neural decay hooks: an interrupted and resumed run is bit-identical
//! to a straight one (f_θ's weights and Adam moments travel in the checkpoint), and the
//! decay really acts (opacities shrink relative to plain 4DGS, f_θ trains).

use crate::train_scene;

use splat4d::CpuBackend;
use splat4d::decay::{DecayConfig, DecayHooks};
use splat4d::train::{NoHooks, TrainConfig, TrainError, TrainHooks, View, train};
use splat4d::{Gaussians, NoProgress, load_model};

fn config(iterations: u64) -> TrainConfig {
    let mut c = TrainConfig {
        iterations,
        checkpoint_every: 10,
        batch_size: 2,
        seed: 3,
        ..Default::default()
    };
    c.degree_every = 8;
    c.densify.from_iteration = 4;
    c.densify.every = 8;
    c.densify.grad_threshold = 2e-5;
    c.densify.opacity_reset_every = 0;
    c
}

fn decay() -> DecayConfig {
    DecayConfig {
        warmup: 3,
        lr: 1e-3, // larger than the default so f_θ visibly moves in a short run
        ..DecayConfig::neural()
    }
}

/// The decay hooks plus a stop request after `stop_at`.
struct StopAt {
    inner: DecayHooks,
    stop_at: u64,
}

impl TrainHooks for StopAt {
    fn opacity_factor(&mut self, it: u64, m: &Gaussians<f32>, v: &View) -> Option<Vec<f32>> {
        self.inner.opacity_factor(it, m, v)
    }
    fn factor_gradient(&mut self, it: u64, m: &Gaussians<f32>, g: &[f32]) {
        self.inner.factor_gradient(it, m, g)
    }
    fn after_step(&mut self, it: u64, m: &mut Gaussians<f32>) {
        self.inner.after_step(it, m)
    }
    fn save_state(&self) -> Vec<u8> {
        self.inner.save_state()
    }
    fn load_state(&mut self, s: &[u8]) {
        self.inner.load_state(s)
    }
    fn stop_requested(&mut self, it: u64) -> bool {
        it == self.stop_at
    }
}

#[test]
fn resumed_neural_decay_run_is_bit_identical() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(10, 8, &[0.0, 1.0]);
    let straight = tempfile::tempdir().unwrap();
    let mut hooks = DecayHooks::new(&decay()).unwrap();
    let initial_mlp = hooks.mlp().clone();
    train(
        &CpuBackend,
        &config(24),
        &data,
        &init,
        straight.path(),
        false,
        &mut hooks,
        &NoProgress,
    )
    .unwrap();
    assert_ne!(hooks.mlp(), &initial_mlp, "f_θ trained");
    let stats = hooks.last_stats().unwrap();
    assert_eq!(stats.iteration, 24);
    assert!(stats.visible > 0);

    let resumed = tempfile::tempdir().unwrap();
    let mut first = StopAt {
        inner: DecayHooks::new(&decay()).unwrap(),
        stop_at: 13,
    };
    let e = train(
        &CpuBackend,
        &config(24),
        &data,
        &init,
        resumed.path(),
        false,
        &mut first,
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(e, TrainError::Interrupted { iteration: 13, .. }),
        "{e}"
    );
    let mut second = DecayHooks::new(&decay()).unwrap();
    train(
        &CpuBackend,
        &config(24),
        &data,
        &init,
        resumed.path(),
        true,
        &mut second,
        &NoProgress,
    )
    .unwrap();
    assert!(second.state_error().is_none());
    assert_eq!(second.mlp(), hooks.mlp(), "f_θ weights");
    assert_eq!(second.optimiser(), hooks.optimiser(), "f_θ Adam state");
    let a = std::fs::read(straight.path().join("model.bin")).unwrap();
    let b = std::fs::read(resumed.path().join("model.bin")).unwrap();
    assert!(a == b, "resumed model differs from the straight run");

    // The same run without decay keeps more opacity.
    let plain = tempfile::tempdir().unwrap();
    train(
        &CpuBackend,
        &config(24),
        &data,
        &init,
        plain.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();
    let mean_opacity = |p: &std::path::Path| {
        let m = load_model(&p.join("model.bin")).unwrap();
        assert!(m.opacity_logits.iter().all(|l| l.is_finite()));
        m.opacity_logits
            .iter()
            .map(|&l| 1.0 / (1.0 + (-l as f64).exp()))
            .sum::<f64>()
            / m.len() as f64
    };
    let (with, without) = (mean_opacity(straight.path()), mean_opacity(plain.path()));
    assert!(with < without, "decayed {with} vs plain {without}");
}

#[test]
fn a_checkpoint_with_another_network_shape_is_reported_not_loaded() {
    let h = DecayHooks::new(&decay()).unwrap();
    let state = h.save_state();
    let mut other = DecayHooks::new(&DecayConfig {
        hidden_width: 16,
        ..decay()
    })
    .unwrap();
    let before = other.mlp().clone();
    other.load_state(&state);
    assert_eq!(other.mlp(), &before);
    assert!(other.state_error().unwrap().contains("layers"));
    other.load_state(&state[..20]);
    assert!(other.state_error().unwrap().contains("truncated"));
    let mut same = DecayHooks::new(&DecayConfig { seed: 9, ..decay() }).unwrap();
    same.load_state(&state);
    assert!(same.state_error().is_none());
    assert_eq!(same.mlp(), h.mlp());
}
