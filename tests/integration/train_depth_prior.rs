//! The sparse depth prior (`[train] depth_prior`, `train::depth_prior`) through the real
//! trainer: on the analytic plane scene, trained from points on the plane, the expected
//! depth the model renders stays closer to the plane's with the prior than without it,
//! and the colour still fits.

use crate::train_scene;

use glam::DVec3;
use splat4d::train::{Background, NoHooks, TrainConfig, evaluate_psnr, train};
use splat4d::{CpuBackend, NoProgress, RenderBackend, RenderOptions, load_model};

/// Train `iterations` with the prior's `weight`; the mean relative error of the rendered
/// expected depth (Σ wz / Σ w) against the plane's true camera depth over every training
/// view's well-covered pixels, and the mean training-view PSNR.
fn train_with(weight: f64, iterations: u64) -> (f64, f64) {
    let data = train_scene::dataset(48, 36);
    let mut init = train_scene::points(16, 12, &[0.5]);
    // Static structure seen over the whole clip.
    init.time_span = Some(vec![1.0; init.xyz.len()]);
    let dir = tempfile::tempdir().unwrap();
    let mut config = TrainConfig {
        background: Background::Colour([0.0; 3]),
        iterations,
        checkpoint_every: 0,
        depth_prior: weight,
        ..Default::default()
    };
    config.densify.from_iteration = 50;
    config.densify.until_iteration = iterations - 50;
    config.densify.every = 50;
    config.densify.opacity_reset_every = 0;
    let summary = train(
        &CpuBackend,
        &config,
        &data,
        &init,
        dir.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();
    let model = load_model(&summary.model_path).unwrap();
    let (mut error, mut pixels) = (0.0, 0usize);
    for view in &data.views {
        let r = CpuBackend
            .render(
                &model,
                &view.camera,
                view.time,
                &RenderOptions::<f32>::default(),
            )
            .unwrap();
        let (w, h) = (r.width, r.height);
        let eye = view.camera.world_to_camera.centre();
        for y in 0..h {
            for x in 0..w {
                let k = (y * w + x) as usize;
                if r.alpha[k] < 0.5 {
                    continue;
                }
                let ray = view
                    .camera
                    .pixel_ray(glam::DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
                let hit: DVec3 = eye + ray * (-eye.z / ray.z);
                let truth = view.camera.world_to_camera.apply(hit).z;
                let rendered = r.depth[k] as f64 / r.alpha[k] as f64;
                error += (rendered - truth).abs() / truth;
                pixels += 1;
            }
        }
    }
    assert!(pixels > 1000, "only {pixels} covered pixels");
    let psnr = evaluate_psnr(&CpuBackend, &model, &data, [0.0; 3]).unwrap();
    let mean_psnr = psnr.iter().sum::<f64>() / psnr.len() as f64;
    (error / pixels as f64, mean_psnr)
}

#[test]
fn the_depth_prior_keeps_rendered_depth_on_the_init_surface_and_the_colour_fits() {
    let (free, free_psnr) = train_with(0.0, 200);
    let (held, held_psnr) = train_with(2.0, 200);
    eprintln!(
        "relative depth error: {free:.4} without the prior ({free_psnr:.2} dB), {held:.4} with it ({held_psnr:.2} dB)"
    );
    assert!(held < 0.8 * free, "{held} with the prior against {free}");
    assert!(held_psnr > 24.0, "{held_psnr} dB");
}
