//! Training on top of frozen Gaussians (`Start::Model`): the shared static scene of time
//! chunks. Whatever the step does — Adam, densification, an opacity reset, the anisotropy
//! cap, the 4C4D decay on the host — the frozen Gaussians come out bit for bit as they went
//! in, the others train, the budget counts only the others, and a resume onto other frozen
//! Gaussians is refused.

use crate::train_scene;

use splat4d::decay::{DecayConfig, DecayHooks, DecayVariant};
use splat4d::model::init::gaussians_from_points;
use splat4d::train::{Background, Start, TrainConfig, TrainError, train_from};
use splat4d::{CpuBackend, Gaussians, NoProgress, load_model};

fn config() -> TrainConfig {
    let mut c = TrainConfig {
        background: Background::Colour([0.0; 3]),
        iterations: 40,
        checkpoint_every: 20,
        max_anisotropy: 4.0,
        ..Default::default()
    };
    c.degree_every = 10;
    c.densify.from_iteration = 5;
    c.densify.until_iteration = 35;
    c.densify.every = 10;
    c.densify.grad_threshold = 1e-6;
    c.densify.opacity_reset_every = 15;
    c.densify.max_gaussians = 260;
    c
}

/// The scene's plane as 150 frozen Gaussians, then 100 trainable ones of the disc's moments.
fn start(config: &TrainConfig) -> (Gaussians<f32>, usize) {
    let data = train_scene::dataset(48, 36);
    let opts = config.init_options();
    let plane = train_scene::points(15, 10, &[0.0, 0.5, 1.0]);
    let mut model = gaussians_from_points(&plane, data.time_mapping, &opts).unwrap();
    let frozen = model.len();
    let disc = train_scene::points(10, 10, &[0.25, 0.75]);
    model.append(&gaussians_from_points(&disc, data.time_mapping, &opts).unwrap());
    (model, frozen)
}

#[test]
fn frozen_gaussians_come_out_as_they_went_in_and_the_rest_trains() {
    let config = config();
    let data = train_scene::dataset(48, 36);
    let (first, frozen) = start(&config);
    let points = train_scene::points(4, 4, &[0.5]);
    let dir = tempfile::tempdir().unwrap();
    let mut decay = DecayHooks::new(&DecayConfig {
        variant: DecayVariant::Constant,
        ..Default::default()
    })
    .unwrap();
    let go = |hooks: &mut DecayHooks, first: &Gaussians<f32>, resume: bool| {
        train_from(
            &CpuBackend,
            &config,
            &data,
            Start::Model {
                model: first,
                frozen,
                points: &points,
            },
            dir.path(),
            resume,
            hooks,
            &NoProgress,
        )
    };
    let summary = go(&mut decay, &first, false).unwrap();
    let model = load_model(&summary.model_path).unwrap();
    let k = 3 * first.coeffs_per_channel();
    let f = frozen;
    assert_eq!(model.means[..f], first.means[..f]);
    assert_eq!(model.log_scales[..f], first.log_scales[..f]);
    assert_eq!(model.rot_left[..f], first.rot_left[..f]);
    assert_eq!(model.rot_right[..f], first.rot_right[..f]);
    assert_eq!(model.opacity_logits[..f], first.opacity_logits[..f]);
    assert_eq!(model.colours[..f * k], first.colours[..f * k]);
    // The rest trained and grew, within a budget that counts only them.
    let trainable = model.len() - f;
    assert_ne!(trainable, first.len() - f, "densification changed nothing");
    assert!(trainable <= config.densify.max_gaussians, "{trainable}");
    assert!(
        model.len() > config.densify.max_gaussians,
        "{}",
        model.len()
    );

    // A resume onto other frozen Gaussians is refused.
    let mut other = first.clone();
    other.means[0][0] += 0.25;
    let mut decay = DecayHooks::new(&DecayConfig::default()).unwrap();
    let err = go(&mut decay, &other, true).unwrap_err();
    assert!(matches!(err, TrainError::Resume(_)), "{err}");
    assert!(err.to_string().contains("frozen"), "{err}");
    // More frozen Gaussians than the model has is a configuration error.
    let e = train_from(
        &CpuBackend,
        &config,
        &data,
        Start::Model {
            model: &first,
            frozen: first.len() + 1,
            points: &points,
        },
        dir.path(),
        false,
        &mut splat4d::train::NoHooks,
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(e, TrainError::Config(_)), "{e}");
}
