//! The 4C4D seam: a render-time opacity factor reaches the renderer and its gradient comes
//! back; `after_step` may edit the model; hook state is carried through checkpoints.

use crate::train_scene;

use splat4d::CpuBackend;
use splat4d::train::{TrainConfig, TrainHooks, View, train};
use splat4d::{Gaussians, NoProgress};

#[derive(Default)]
struct Decay {
    calls: u64,
    grad_calls: u64,
    grad_abs: f64,
    loaded: Option<Vec<u8>>,
}

impl TrainHooks for Decay {
    fn opacity_factor(
        &mut self,
        _it: u64,
        model: &Gaussians<f32>,
        _view: &View,
    ) -> Option<Vec<f32>> {
        self.calls += 1;
        Some(vec![0.9; model.len()])
    }
    fn factor_gradient(&mut self, _it: u64, model: &Gaussians<f32>, gradient: &[f32]) {
        assert_eq!(gradient.len(), model.len());
        self.grad_calls += 1;
        self.grad_abs += gradient.iter().map(|g| g.abs() as f64).sum::<f64>();
    }
    fn after_step(&mut self, _it: u64, model: &mut Gaussians<f32>) {
        // The constant-decay ablation: shrink stored opacity a little every step.
        for o in &mut model.opacity_logits {
            *o -= 0.01;
        }
    }
    fn save_state(&self) -> Vec<u8> {
        self.calls.to_le_bytes().to_vec()
    }
    fn load_state(&mut self, state: &[u8]) {
        self.loaded = Some(state.to_vec());
    }
}

#[test]
fn decay_hooks_are_called_and_see_gradients() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(10, 8, &[0.5]);
    let dir = tempfile::tempdir().unwrap();
    let mut config = TrainConfig {
        background: splat4d::train::Background::Colour([0.0; 3]),
        iterations: 6,
        batch_size: 2,
        checkpoint_every: 3,
        ..Default::default()
    };
    config.densify.enabled = false;
    let mut hooks = Decay::default();
    train(
        &CpuBackend,
        &config,
        &data,
        &init,
        dir.path(),
        false,
        &mut hooks,
        &NoProgress,
    )
    .unwrap();
    assert_eq!(hooks.calls, 12);
    assert_eq!(hooks.grad_calls, 12);
    assert!(hooks.grad_abs > 0.0);

    config.iterations = 8;
    let mut again = Decay::default();
    train(
        &CpuBackend,
        &config,
        &data,
        &init,
        dir.path(),
        true,
        &mut again,
        &NoProgress,
    )
    .unwrap();
    assert_eq!(
        again.loaded,
        Some(12u64.to_le_bytes().to_vec()),
        "hook state restored from checkpoint 6"
    );
    assert_eq!(again.calls, 4);
}

#[test]
fn frames_load_at_the_working_resolution_with_scaled_intrinsics() {
    use splat4d::train::{Dataset, FrameSource};
    let data = train_scene::dataset(64, 48);
    let dir = tempfile::tempdir().unwrap();
    let v = &data.views[2];
    let path = dir.path().join("000002.png");
    image::RgbImage::from_raw(64, 48, v.image.data.clone())
        .unwrap()
        .save(&path)
        .unwrap();
    let frames = [FrameSource {
        camera: v.camera.clone(),
        time: 0.25,
        path,
    }];
    let d = Dataset::load(&frames, Some(32), data.time_mapping).unwrap();
    let w = &d.views[0];
    assert_eq!((w.image.width, w.image.height), (32, 24));
    assert_eq!(
        (w.camera.intrinsics.width, w.camera.intrinsics.height),
        (32, 24)
    );
    assert!((w.camera.intrinsics.fx - v.camera.intrinsics.fx / 2.0).abs() < 1e-9);
    let missing = [FrameSource {
        camera: v.camera.clone(),
        time: 0.0,
        path: dir.path().join("nope.png"),
    }];
    let e = Dataset::load(&missing, None, data.time_mapping).unwrap_err();
    assert!(e.to_string().contains("nope.png"));
}
