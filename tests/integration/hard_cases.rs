//! Numerically hard inputs stay finite and accurate: extreme temporal and spatial scales,
//! nearly singular covariances, the near plane, saturated opacities, far-away times,
//! thousands of stacked splats, degenerate quaternions, empty scenes, tiny and huge images.

use crate::common;

use common::{
    at_camera, camera, hard_model as model, push_extreme_scales, stacked_splats, weights,
};
use splat4d::render::cpu::{self, render_with};
use splat4d::render::reference::render_reference;
use splat4d::{Camera, Distortion, Gaussians, ImageGradients, RenderError, RenderOptions};

struct Outcome {
    mean_err: f64,
    max_err: f64,
    visible: usize,
}

/// Render in f32 and f64, compare with the reference, run both backward passes, and
/// check that everything is finite. Returns the f32-vs-reference error.
fn check(model: &Gaussians<f64>, cam: &Camera, t: f64) -> Outcome {
    let bg = [0.25, 0.5, 0.75];
    let opts = RenderOptions {
        background: bg,
        opacity_factor: None,
        near_plane: 0.01,
    };
    let reference = render_reference(model, cam, t, &opts).unwrap();
    let r64 = render_with(model, cam, t, &opts).unwrap();
    let e64 = r64
        .rgb
        .iter()
        .zip(&reference.rgb)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        e64 < 1e-8,
        "f64 renderer differs from the reference by {e64}"
    );
    let m32 = model.cast::<f32>();
    let opts32 = RenderOptions {
        background: bg.map(|x| x as f32),
        opacity_factor: None,
        near_plane: 0.01f32,
    };
    let r32 = render_with(&m32, cam, t as f32, &opts32).unwrap();
    assert!(
        r32.rgb
            .iter()
            .chain(&r32.alpha)
            .chain(&r32.depth)
            .all(|x| x.is_finite()),
        "non-finite f32 output"
    );
    let npix = r32.alpha.len();
    let w = weights(7, 3 * npix);
    let w32: Vec<f32> = w.iter().map(|&x| x as f32).collect();
    let wa: Vec<f32> = w32[..npix].to_vec();
    let g32 = cpu::backward(
        &r32,
        &m32,
        &ImageGradients {
            rgb: &w32,
            alpha: Some(&wa),
            depth: Some(&wa),
        },
    )
    .unwrap();
    let all32 = g32
        .means
        .iter()
        .chain(&g32.log_scales)
        .chain(&g32.rot_left)
        .chain(&g32.rot_right)
        .flatten()
        .chain(&g32.opacity_logits)
        .chain(&g32.colours)
        .chain(&g32.mean2d_norm);
    for x in all32 {
        assert!(x.is_finite(), "non-finite f32 gradient");
    }
    let wa64: Vec<f64> = w[..npix].to_vec();
    let g64 = cpu::backward(
        &r64,
        model,
        &ImageGradients {
            rgb: &w,
            alpha: Some(&wa64),
            depth: Some(&wa64),
        },
    )
    .unwrap();
    assert!(
        g64.means
            .iter()
            .flatten()
            .chain(&g64.opacity_logits)
            .all(|x| x.is_finite())
    );
    let diffs: Vec<f64> = r32
        .rgb
        .iter()
        .zip(&reference.rgb)
        .map(|(&a, b)| (a as f64 - b).abs())
        .collect();
    Outcome {
        mean_err: diffs.iter().sum::<f64>() / diffs.len() as f64,
        max_err: diffs.iter().copied().fold(0.0, f64::max),
        visible: r32.stats.visible,
    }
}

fn assert_accurate(o: &Outcome, what: &str) {
    assert!(
        o.mean_err < 1e-3 && o.max_err < 3e-2,
        "{what}: f32 vs reference mean {} max {}",
        o.mean_err,
        o.max_err
    );
}

#[test]
fn tiny_and_huge_temporal_variance() {
    let cam = camera(64, 48);
    let mut g = model();
    // Σ44 = e^-32 ≈ 1e-14: a Gaussian that exists for an instant.
    let a = g.push(
        [0.0, 0.0, 0.0, 0.5],
        [-1.5, -1.5, -1.5, -16.0],
        2.0,
        [1.0, 0.2, 0.1],
    );
    g.rot_left[a] = [1.0, 0.2, -0.1, 0.3]; // a pure spatial rotation (ql = qr)
    g.rot_right[a] = [1.0, 0.2, -0.1, 0.3];
    let b = g.push(
        [0.3, 0.1, 0.2, 0.5],
        [-1.6, -1.4, -1.9, 8.0],
        1.0,
        [0.1, 0.9, 0.1],
    );
    g.rot_left[b] = [0.9, 0.3, 0.2, -0.4];
    let o = check(&g, &cam, 0.5);
    assert_eq!(o.visible, 2);
    assert_accurate(&o, "Σ44 tiny/huge at t = μt");
    let o = check(&g, &cam, 0.5 + 1e-3);
    assert_eq!(
        o.visible, 1,
        "the temporally tiny Gaussian is culled away from its instant"
    );
    assert_accurate(&o, "Σ44 tiny/huge off its instant");
}

#[test]
fn nearly_singular_covariances_and_extreme_scales() {
    let cam = camera(64, 48);
    let mut g = model();
    push_extreme_scales(&mut g);
    let b = g.push(
        [0.2, 0.0, -0.2, 0.5],
        [-1.0, -13.8, -13.8, 0.0],
        1.5,
        [0.1, 0.9, 0.9],
    );
    g.rot_left[b] = [0.7, -0.4, 0.1, 0.6];
    let o = check(&g, &cam, 0.5);
    assert!(o.visible >= 4);
    assert_accurate(&o, "singular / extreme scales");
}

#[test]
fn near_plane_and_behind_the_camera() {
    let cam = camera(64, 48);
    let mut g = model();
    g.push(
        at_camera(&cam, 0.0, 0.0, 0.005, 0.5),
        [-3.0, -3.0, -3.0, 0.0],
        2.0,
        [1.0, 0.0, 0.0],
    );
    g.push(
        at_camera(&cam, 0.01, 0.0, 0.05, 0.5),
        [0.0, 0.0, 0.0, 0.0],
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
        [0.0, 0.0, 0.0, 0.0],
        2.0,
        [1.0, 1.0, 0.0],
    );
    g.push(
        at_camera(&cam, 30.0, 0.0, 0.02, 0.5),
        [-1.0, -1.0, -1.0, 0.0],
        2.0,
        [1.0, 0.0, 1.0],
    );
    let o = check(&g, &cam, 0.5);
    assert_accurate(&o, "near plane");
}

#[test]
fn saturated_opacities_and_far_times() {
    let cam = camera(64, 48);
    let mut g = model();
    g.push([0.0, 0.0, 0.0, 0.5], [-1.5; 4], 30.0, [1.0, 0.0, 0.0]);
    g.push([0.2, -0.5, 0.1, 0.5], [-1.5; 4], -30.0, [0.0, 1.0, 0.0]);
    g.push([-0.2, 0.5, 0.1, 0.5], [-1.2; 4], 29.0, [0.0, 0.0, 1.0]);
    let o = check(&g, &cam, 0.5);
    assert_eq!(o.visible, 2, "logit −30 is invisible");
    assert_accurate(&o, "opacity ±30");
    for t in [1e4, -1e6, 1e30] {
        let o = check(&g, &cam, t);
        assert_eq!(o.visible, 0);
        assert!(o.max_err < 1e-6);
    }
}

#[test]
fn ten_thousand_splats_stacked_on_one_pixel() {
    let cam = camera(32, 32);
    let g = stacked_splats(10_000);
    let o = check(&g, &cam, 0.5);
    assert_eq!(o.visible, 10_000);
    assert_accurate(&o, "stacked");
    // f32 and f64 gradients of the stacked pile agree (no drift in the back-to-front
    // transmittance recovery).
    let opts = RenderOptions {
        background: [0.0; 3],
        opacity_factor: None,
        near_plane: 0.01,
    };
    let r64 = render_with(&g, &cam, 0.5, &opts).unwrap();
    let w = vec![1.0; 3 * 32 * 32];
    let g64 = cpu::backward(
        &r64,
        &g,
        &ImageGradients {
            rgb: &w,
            alpha: None,
            depth: None,
        },
    )
    .unwrap();
    let m32 = g.cast::<f32>();
    let opts32 = RenderOptions {
        background: [0.0f32; 3],
        opacity_factor: None,
        near_plane: 0.01,
    };
    let r32 = render_with(&m32, &cam, 0.5, &opts32).unwrap();
    let w32 = vec![1.0f32; 3 * 32 * 32];
    let g32 = cpu::backward(
        &r32,
        &m32,
        &ImageGradients {
            rgb: &w32,
            alpha: None,
            depth: None,
        },
    )
    .unwrap();
    let a: Vec<f64> = g64.opacity_logits.clone();
    let b: Vec<f64> = g32.opacity_logits.iter().map(|&x| x as f64).collect();
    let e = common::rel_err(&a, &b, 1e-12);
    assert!(e < 1e-2, "stacked opacity gradients f32 vs f64: {e}");
}

#[test]
fn zero_norm_quaternions_act_as_identity() {
    let cam = camera(48, 32);
    let mut g = model();
    let a = g.push(
        [0.0, 0.0, 0.0, 0.5],
        [-1.5, -1.0, -2.0, 0.0],
        1.0,
        [0.5, 0.2, 0.9],
    );
    let mut h = g.clone();
    g.rot_left[a] = [0.0; 4];
    g.rot_right[a] = [0.0; 4];
    h.rot_left[a] = [1.0, 0.0, 0.0, 0.0];
    let o = check(&g, &cam, 0.5);
    assert_accurate(&o, "zero quaternion");
    let opts = RenderOptions::default();
    let ra = render_with(&g, &cam, 0.5, &opts).unwrap();
    let rb = render_with(&h, &cam, 0.5, &opts).unwrap();
    assert_eq!(ra.rgb, rb.rgb);
}

#[test]
fn empty_scene_tiny_image_and_huge_image() {
    let g = model();
    let cam = camera(40, 30);
    let o = check(&g, &cam, 0.5);
    assert_eq!(o.visible, 0);
    assert!(o.max_err < 1e-6, "empty scene shows the background");

    let mut g = model();
    g.push([0.0, 0.0, 0.0, 0.5], [-1.0; 4], 1.0, [0.9, 0.1, 0.1]);
    let tiny = camera(1, 1);
    let o = check(&g, &tiny, 0.5);
    assert_eq!(o.visible, 1);
    assert_accurate(&o, "1×1");

    let big = camera(4000, 3000);
    for k in 0..20 {
        let f = k as f64 / 20.0;
        g.push(
            [f - 0.5, 0.3 * f, 0.4 - f, 0.5],
            [-2.5, -2.0, -3.0, 0.0],
            0.5,
            [f, 1.0 - f, 0.5],
        );
    }
    let m32 = g.cast::<f32>();
    let r = render_with(&m32, &big, 0.5, &RenderOptions::default()).unwrap();
    assert_eq!(r.rgb.len(), 3 * 4000 * 3000);
    assert!(r.rgb.iter().all(|x| x.is_finite()));
    let covered = r.alpha.iter().filter(|&&a| a > 0.5).count();
    assert!(
        covered > 100_000,
        "the big Gaussian covers much of the big image ({covered} px)"
    );
    let w = vec![1.0f32; 3 * 4000 * 3000];
    let grads = cpu::backward(
        &r,
        &m32,
        &ImageGradients {
            rgb: &w,
            alpha: None,
            depth: None,
        },
    )
    .unwrap();
    assert!(grads.means.iter().flatten().all(|x| x.is_finite()));
}

#[test]
fn refuses_bad_inputs_with_typed_errors() {
    let mut g = model();
    g.push([0.0, 0.0, 0.0, 0.5], [-1.0; 4], 1.0, [0.9, 0.1, 0.1]);
    let mut cam = camera(16, 16);
    cam.distortion = Distortion::radial_tangential(0.1, 0.0, 0.0, 0.0, 0.0);
    let err = render_with(&g, &cam, 0.5, &RenderOptions::default()).unwrap_err();
    assert!(matches!(err, RenderError::DistortedCamera { .. }), "{err}");
    assert!(err.to_string().contains("undistort"));

    let cam = camera(16, 16);
    let factor = [0.5, 0.5];
    let opts = RenderOptions {
        opacity_factor: Some(&factor[..]),
        ..RenderOptions::default()
    };
    assert!(matches!(
        render_with(&g, &cam, 0.5, &opts),
        Err(RenderError::OpacityFactorLength {
            expected: 1,
            got: 2
        })
    ));

    let mut zero = camera(16, 16);
    zero.intrinsics.width = 0;
    assert!(matches!(
        render_with(&g, &zero, 0.5, &RenderOptions::default()),
        Err(RenderError::EmptyImage { .. })
    ));

    let r = render_with(&g, &cam, 0.5, &RenderOptions::default()).unwrap();
    let short = vec![0.0; 5];
    let err = cpu::backward(
        &r,
        &g,
        &ImageGradients {
            rgb: &short,
            alpha: None,
            depth: None,
        },
    )
    .unwrap_err();
    assert!(matches!(
        err,
        RenderError::GradientLength { what: "rgb", .. }
    ));
    let mut bigger = g.clone();
    bigger.push([0.0; 4], [0.0; 4], 0.0, [0.0; 3]);
    let full = vec![0.0; 3 * 256];
    let err = cpu::backward(
        &r,
        &bigger,
        &ImageGradients {
            rgb: &full,
            alpha: None,
            depth: None,
        },
    )
    .unwrap_err();
    assert!(matches!(err, RenderError::ModelMismatch { .. }));

    let mut broken = g.clone();
    broken.colours.pop();
    assert!(matches!(
        render_with(&broken, &cam, 0.5, &RenderOptions::default()),
        Err(RenderError::InconsistentModel(_))
    ));
}
