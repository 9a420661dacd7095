//! The wgpu renderer draws what the CPU renderer draws: random scenes and every hard case
//! of `hard_cases.rs`, RGB and alpha within 1e-4 mean absolute error, depth within 1e-4
//! of its mean, the same Gaussians drawn, the same (tile, splat) pair counts.
//!
//! Runs on any adapter, software ones included (Mesa's lavapipe in CI). Without an adapter
//! it skips with a message, except under `CI=true`, where that is a failure
//! (`scripts/setup.sh` installs `mesa-vulkan-drivers`).

use crate::common;

use common::{
    Rng, SceneSpec, at_camera, camera, hard_model, push_extreme_scales, random_scene,
    stacked_splats,
};
use glam::DVec3;
use splat4d::model::ColourDegrees;
use splat4d::render::gpu::GpuBackend;
use splat4d::render::{CpuBackend, RenderBackend, Rendered, ViewRequest};
use splat4d::{Camera, Distortion, Gaussians, ImageGradients, RenderError, RenderOptions};

fn gpu() -> Option<&'static GpuBackend> {
    common::gpu("GPU parity test")
}

fn mean_abs(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    if a.is_empty() {
        return 0.0;
    }
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() as f64)
        .sum::<f64>()
        / a.len() as f64
}

/// Compare one frame of each backend; returns the RGB mean absolute error.
fn compare(cpu: &Rendered, gpu: &Rendered, what: &str) -> f64 {
    assert_eq!((cpu.width, cpu.height), (gpu.width, gpu.height), "{what}");
    for x in gpu
        .rgb
        .iter()
        .chain(&gpu.alpha)
        .chain(&gpu.depth)
        .chain(&gpu.radii)
    {
        assert!(x.is_finite(), "{what}: non-finite GPU output");
    }
    let rgb = mean_abs(&cpu.rgb, &gpu.rgb);
    let alpha = mean_abs(&cpu.alpha, &gpu.alpha);
    let depth_scale =
        cpu.depth.iter().map(|d| d.abs() as f64).sum::<f64>() / cpu.depth.len().max(1) as f64;
    let depth = mean_abs(&cpu.depth, &gpu.depth) / depth_scale.max(1e-6);
    assert!(rgb < 1e-4, "{what}: RGB mean abs error {rgb:e}");
    assert!(alpha < 1e-4, "{what}: alpha mean abs error {alpha:e}");
    assert!(depth < 1e-4, "{what}: relative depth error {depth:e}");
    assert_eq!(
        cpu.stats.visible, gpu.stats.visible,
        "{what}: Gaussians drawn"
    );
    assert_eq!(
        cpu.stats.tile_pairs, gpu.stats.tile_pairs,
        "{what}: (tile, splat) pairs"
    );
    for (i, (a, b)) in cpu.radii.iter().zip(&gpu.radii).enumerate() {
        assert!(
            (a - b).abs() <= 1e-3 * a.abs().max(1.0),
            "{what}: radius of {i}: {a} vs {b}"
        );
    }
    rgb
}

/// Render `model` at `t` on both backends and compare.
fn check(model: &Gaussians<f64>, cam: &Camera, t: f64, what: &str) -> Option<f64> {
    let gpu = gpu()?;
    let m = model.cast::<f32>();
    let options = RenderOptions {
        background: [0.25f32, 0.5, 0.75],
        opacity_factor: None,
        near_plane: 0.01,
    };
    let c = CpuBackend.render(&m, cam, t as f32, &options).unwrap();
    let g = gpu.render(&m, cam, t as f32, &options).unwrap();
    Some(compare(&c, &g, what))
}

#[test]
fn random_scenes_match_the_cpu_at_several_times() {
    let cam = camera(96, 72);
    for seed in 0..4 {
        let spec = SceneSpec {
            count: 300,
            ..SceneSpec::default()
        };
        let model = random_scene(seed, spec);
        for t in [0.0, 0.35, 0.5, 0.9] {
            let Some(e) = check(&model, &cam, t, &format!("seed {seed}, t {t}")) else {
                return;
            };
            eprintln!("seed {seed} t {t}: rgb mean abs {e:.2e}");
        }
    }
}

#[test]
fn a_large_scene_exercises_every_scan_level_and_sort_pass() {
    // 70 000 Gaussians: three levels of the 256-wide scan; 320×240 has 300 tiles (9 bits).
    let cam = camera(320, 240);
    let spec = SceneSpec {
        count: 70_000,
        log_scale: (-4.5, -2.5),
        degrees: ColourDegrees::DC,
        ..SceneSpec::default()
    };
    let model = random_scene(11, spec);
    check(&model, &cam, 0.5, "70k Gaussians");
}

#[test]
fn opacity_factor_and_odd_image_sizes() {
    let Some(gpu) = gpu() else { return };
    let model = random_scene(
        5,
        SceneSpec {
            count: 200,
            ..SceneSpec::default()
        },
    )
    .cast::<f32>();
    let mut rng = Rng(3);
    let factor: Vec<f32> = (0..model.len()).map(|_| rng.uniform() as f32).collect();
    for (w, h) in [(1, 1), (17, 33), (100, 3)] {
        let cam = camera(w, h);
        let options = RenderOptions {
            background: [0.1f32, 0.0, 0.3],
            opacity_factor: Some(&factor),
            near_plane: 0.01,
        };
        let c = CpuBackend.render(&model, &cam, 0.5, &options).unwrap();
        let g = gpu.render(&model, &cam, 0.5, &options).unwrap();
        compare(&c, &g, &format!("{w}×{h} with an opacity factor"));
    }
}

#[test]
fn a_batch_of_views_equals_views_rendered_alone() {
    let Some(gpu) = gpu() else { return };
    let model = random_scene(
        8,
        SceneSpec {
            count: 400,
            ..SceneSpec::default()
        },
    )
    .cast::<f32>();
    let mut second = camera(64, 40);
    second.world_to_camera = common::look_at(DVec3::new(-3.0, -2.0, 1.0), DVec3::ZERO, DVec3::Z);
    let cams = [camera(96, 72), second, camera(33, 21)];
    let times = [0.2f32, 0.5, 0.8];
    let views: Vec<ViewRequest> = cams
        .iter()
        .zip(times)
        .map(|(camera, t)| ViewRequest {
            camera,
            t,
            options: RenderOptions::default(),
        })
        .collect();
    let batch = gpu.render_batch(&model, &views).unwrap();
    assert_eq!(batch.len(), 3);
    for (v, frame) in views.iter().zip(&batch) {
        let alone = gpu.render(&model, v.camera, v.t, &v.options).unwrap();
        assert_eq!(frame.rgb, alone.rgb, "batch and single render differ");
        let cpu = CpuBackend
            .render(&model, v.camera, v.t, &v.options)
            .unwrap();
        compare(&cpu, frame, "batched view");
    }
}

#[test]
fn tiny_and_huge_temporal_variance() {
    let cam = camera(64, 48);
    let mut g = hard_model();
    let a = g.push(
        [0.0, 0.0, 0.0, 0.5],
        [-1.5, -1.5, -1.5, -16.0],
        2.0,
        [1.0, 0.2, 0.1],
    );
    g.rot_left[a] = [1.0, 0.2, -0.1, 0.3];
    g.rot_right[a] = [1.0, 0.2, -0.1, 0.3];
    let b = g.push(
        [0.3, 0.1, 0.2, 0.5],
        [-1.6, -1.4, -1.9, 8.0],
        1.0,
        [0.1, 0.9, 0.1],
    );
    g.rot_left[b] = [0.9, 0.3, 0.2, -0.4];
    for t in [0.5, 0.5 + 1e-3, 40.0] {
        check(&g, &cam, t, &format!("temporal variance, t {t}"));
    }
}

#[test]
fn nearly_singular_covariances_and_extreme_scales() {
    let cam = camera(64, 48);
    let mut g = hard_model();
    push_extreme_scales(&mut g);
    let b = g.push(
        [0.2, 0.0, -0.2, 0.5],
        [-1.0, -13.8, -13.8, 0.0],
        1.5,
        [0.1, 0.9, 0.9],
    );
    g.rot_left[b] = [0.7, -0.4, 0.1, 0.6];
    g.push(
        [0.0, 0.1, 0.0, 0.5],
        [f64::NAN, -1.0, -1.0, 0.0],
        0.5,
        [0.5, 0.5, 0.5],
    );
    check(&g, &cam, 0.5, "singular covariances");
}

#[test]
fn near_plane_and_behind_the_camera() {
    let cam = camera(64, 48);
    let mut g = hard_model();
    g.push(
        at_camera(&cam, 0.0, 0.0, 0.005, 0.5),
        [-3.0, -3.0, -3.0, 0.0],
        2.0,
        [1.0, 0.0, 0.0],
    );
    g.push(
        at_camera(&cam, 0.01, 0.0, 0.05, 0.5),
        [0.0; 4],
        2.0,
        [0.0, 1.0, 0.0],
    );
    g.push(
        at_camera(&cam, 0.0, 0.0, -1.0, 0.5),
        [0.5, 0.5, 0.5, 0.0],
        2.0,
        [0.0, 0.0, 1.0],
    );
    g.push(
        at_camera(&cam, 0.0, 0.0, 0.0, 0.5),
        [0.0; 4],
        2.0,
        [1.0, 1.0, 0.0],
    );
    g.push(
        at_camera(&cam, 30.0, 0.0, 0.02, 0.5),
        [-1.0, -1.0, -1.0, 0.0],
        2.0,
        [1.0, 0.0, 1.0],
    );
    check(&g, &cam, 0.5, "near plane");
}

#[test]
fn saturated_opacities_and_far_times() {
    let cam = camera(64, 48);
    let mut g = hard_model();
    g.push([0.0, 0.0, 0.0, 0.5], [-1.5; 4], 30.0, [1.0, 0.0, 0.0]);
    g.push([0.2, -0.5, 0.1, 0.5], [-1.5; 4], -30.0, [0.0, 1.0, 0.0]);
    g.push([-0.2, 0.5, 0.1, 0.5], [-1.2; 4], 29.0, [0.0, 0.0, 1.0]);
    for t in [0.5, 1e4, -1e6, 1e30] {
        check(&g, &cam, t, &format!("saturated opacity, t {t}"));
    }
}

#[test]
fn ten_thousand_splats_stacked_on_one_pixel() {
    let cam = camera(32, 32);
    let g = stacked_splats(10_000);
    check(&g, &cam, 0.5, "10k stacked splats");
}

#[test]
fn zero_quaternions_and_empty_scenes() {
    let cam = camera(48, 32);
    let mut g = hard_model();
    let a = g.push(
        [0.0, 0.0, 0.0, 0.5],
        [-1.5, -1.0, -2.0, 0.0],
        1.0,
        [0.5, 0.2, 0.9],
    );
    g.rot_left[a] = [0.0; 4];
    g.rot_right[a] = [0.0; 4];
    check(&g, &cam, 0.5, "zero quaternions");
    check(&hard_model(), &cam, 0.5, "empty scene");
}

#[test]
fn refuses_what_it_cannot_do_with_typed_errors() {
    let Some(gpu) = gpu() else { return };
    let model = random_scene(1, SceneSpec::default()).cast::<f32>();
    let mut cam = camera(16, 16);
    let frame = gpu
        .render(&model, &cam, 0.5, &RenderOptions::default())
        .unwrap();
    let up = vec![0.0f32; 3 * 16 * 16];
    let mut out = splat4d::Gradients::zeros_like(&model, false);
    let up = ImageGradients {
        rgb: &up,
        alpha: None,
        depth: None,
    };
    // A GPU frame is not the CPU backend's (the GPU backward has its own tests).
    let err = CpuBackend
        .backward(&model, &frame, &up, &mut out)
        .unwrap_err();
    assert!(matches!(err, RenderError::WrongBackend { .. }), "{err}");
    let factor = vec![1.0f32; 3];
    let opts = RenderOptions {
        opacity_factor: Some(&factor),
        ..RenderOptions::default()
    };
    let err = gpu.render(&model, &cam, 0.5, &opts).unwrap_err();
    assert!(
        matches!(err, RenderError::OpacityFactorLength { .. }),
        "{err}"
    );
    cam.distortion = Distortion::Fisheye {
        k1: 0.1,
        k2: 0.0,
        k3: 0.0,
        k4: 0.0,
    };
    let err = gpu
        .render(&model, &cam, 0.5, &RenderOptions::default())
        .unwrap_err();
    assert!(matches!(err, RenderError::DistortedCamera { .. }), "{err}");
    assert!(gpu.describe().starts_with("gpu: "), "{}", gpu.describe());
}

/// Mesa's lavapipe (the CI adapter) counts as software: `pipeline demo` must not take the
/// GPU schedule on it, and `auto` must not pick it.
#[test]
fn lavapipe_is_a_software_adapter() {
    let Some(gpu) = gpu() else { return };
    let name = gpu.adapter().name.to_lowercase();
    if name.contains("llvmpipe") || name.contains("lavapipe") || name.contains("swiftshader") {
        assert!(gpu.is_software(), "{}", gpu.describe());
    } else {
        eprintln!("{} is a hardware adapter", gpu.describe());
        assert!(!gpu.is_software());
    }
}
