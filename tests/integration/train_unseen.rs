//! `[train.densify] min_cameras`: Gaussians that no training camera sees are pruned at
//! densification (nothing constrains them, and any other viewpoint may look through
//! them); with `min_cameras = 0` they stay.

use crate::train_scene;

use splat4d::load_model;
use splat4d::train::TrainConfig;
use splat4d::train::densify::cameras_seeing;

/// Points behind every training camera (the cameras stand at z = 3 looking down).
const BEHIND: usize = 12;

/// Train on the analytic scene from its plane's points and [`BEHIND`] points behind the
/// cameras: (Gaussians the run pruned as unseen, Gaussians of the model no camera sees).
fn train_with(min_cameras: usize) -> (usize, usize) {
    let data = train_scene::dataset(48, 36);
    let mut init = train_scene::points(12, 9, &[0.0, 0.5, 1.0]);
    for k in 0..BEHIND {
        let x = -1.0 + 2.0 * k as f32 / (BEHIND - 1) as f32;
        init.xyz.push([x, 0.3, 5.0]);
        init.rgb.push([200, 40, 40]);
        init.time.as_mut().unwrap().push(0.5);
    }
    let mut config = TrainConfig {
        background: splat4d::train::Background::Colour([0.0; 3]),
        iterations: 120,
        checkpoint_every: 0,
        ..Default::default()
    };
    config.densify.from_iteration = 20;
    config.densify.until_iteration = 60;
    config.densify.every = 20;
    config.densify.opacity_reset_every = 0;
    config.densify.min_cameras = min_cameras;
    let (_dir, summary) = train_scene::train_cpu(&config, &data, &init);
    let model = load_model(&summary.model_path).unwrap();
    let cameras = data.cameras();
    let unseen = model
        .means
        .iter()
        .filter(|m| cameras_seeing(&cameras, [m[0], m[1], m[2]]) == 0)
        .count();
    (summary.pruned_unseen, unseen)
}

#[test]
fn gaussians_no_training_camera_sees_are_pruned_by_default() {
    assert_eq!(TrainConfig::default().densify.min_cameras, 1);
    let (pruned, left) = train_with(1);
    assert!(pruned >= BEHIND, "pruned {pruned} unseen Gaussians");
    assert_eq!(left, 0, "{left} Gaussians no camera sees are left");
    // Without the test they get no gradient and stay where they started.
    let (pruned, left) = train_with(0);
    assert_eq!(pruned, 0);
    assert!(left >= BEHIND, "{left} unseen Gaussians left");
}
