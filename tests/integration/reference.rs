//! The fast renderer (f64 and f32) against the straightforward f64 per-pixel reference
//! renderer on random scenes (proptest), plus f32-vs-f64 gradient agreement.

use crate::common;

use common::{SceneSpec, camera, random_scene, rel_err, weights};
use proptest::prelude::*;
use splat4d::model::ColourDegrees;
use splat4d::render::cpu::{self, render_with};
use splat4d::render::reference::render_reference;
use splat4d::{ImageGradients, RenderOptions};

fn max_abs(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn mean_abs(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len().max(1) as f64
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn fast_renderer_matches_reference(
        seed in any::<u64>(),
        count in 0usize..40,
        width in 1u32..70,
        height in 1u32..50,
        t in 0.0f64..1.0,
        small in -3.5f64..-2.0,
        big in -1.8f64..-0.5,
        spatial in 0u32..4,
        temporal in 0u32..3,
        bg in prop::array::uniform3(0.0f64..1.0),
    ) {
        let spec = SceneSpec {
            count,
            log_scale: (small, big),
            logit: (-3.0, 4.0),
            rest: 0.3,
            degrees: ColourDegrees { spatial, temporal },
        };
        let model = random_scene(seed, spec);
        let cam = camera(width, height);
        let opts = RenderOptions { background: bg, opacity_factor: None, near_plane: 0.01 };
        let reference = render_reference(&model, &cam, t, &opts).unwrap();
        let fast = render_with(&model, &cam, t, &opts).unwrap();
        prop_assert!(max_abs(&fast.rgb, &reference.rgb) < 1e-9, "rgb f64 {}", max_abs(&fast.rgb, &reference.rgb));
        prop_assert!(max_abs(&fast.alpha, &reference.alpha) < 1e-9);
        prop_assert!(max_abs(&fast.depth, &reference.depth) < 1e-8);

        let model32 = model.cast::<f32>();
        let opts32 = RenderOptions { background: bg.map(|x| x as f32), opacity_factor: None, near_plane: 0.01f32 };
        let fast32 = render_with(&model32, &cam, t as f32, &opts32).unwrap();
        let up = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
        let (rgb, alpha, depth) = (up(&fast32.rgb), up(&fast32.alpha), up(&fast32.depth));
        // f32 can flip a threshold decision (α ≥ 1/255, T ≥ 1e-4, the 3σ edge) at a few
        // pixels; those change a pixel by at most about one small α.
        prop_assert!(mean_abs(&rgb, &reference.rgb) < 2e-4, "rgb f32 mean {}", mean_abs(&rgb, &reference.rgb));
        prop_assert!(max_abs(&rgb, &reference.rgb) < 2e-2, "rgb f32 max {}", max_abs(&rgb, &reference.rgb));
        prop_assert!(max_abs(&alpha, &reference.alpha) < 2e-2);
        prop_assert!(mean_abs(&depth, &reference.depth) < 1e-3);
    }
}

#[test]
fn f32_gradients_agree_with_f64_gradients() {
    let cam = camera(96, 72);
    for seed in 0..4u64 {
        let model = random_scene(
            seed,
            SceneSpec {
                count: 40,
                ..SceneSpec::default()
            },
        );
        let npix = 96 * 72;
        let wr = weights(seed, 3 * npix);
        let wa = weights(seed + 3, npix);
        let opts = RenderOptions {
            background: [0.2, 0.2, 0.2],
            opacity_factor: None,
            near_plane: 0.01,
        };
        let r64 = render_with(&model, &cam, 0.5, &opts).unwrap();
        let g64 = cpu::backward(
            &r64,
            &model,
            &ImageGradients {
                rgb: &wr,
                alpha: Some(&wa),
                depth: None,
            },
        )
        .unwrap();
        let m32 = model.cast::<f32>();
        let opts32 = RenderOptions {
            background: [0.2f32; 3],
            opacity_factor: None,
            near_plane: 0.01,
        };
        let r32 = render_with(&m32, &cam, 0.5, &opts32).unwrap();
        let wr32: Vec<f32> = wr.iter().map(|&x| x as f32).collect();
        let wa32: Vec<f32> = wa.iter().map(|&x| x as f32).collect();
        let g32 = cpu::backward(
            &r32,
            &m32,
            &ImageGradients {
                rgb: &wr32,
                alpha: Some(&wa32),
                depth: None,
            },
        )
        .unwrap();
        let f4 = |v: &Vec<[f64; 4]>| v.iter().flatten().copied().collect::<Vec<_>>();
        let f4_32 = |v: &Vec<[f32; 4]>| v.iter().flatten().map(|&x| x as f64).collect::<Vec<_>>();
        let f1_32 = |v: &Vec<f32>| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
        let pairs = [
            ("means", f4(&g64.means), f4_32(&g32.means)),
            ("log_scales", f4(&g64.log_scales), f4_32(&g32.log_scales)),
            ("rot_left", f4(&g64.rot_left), f4_32(&g32.rot_left)),
            ("rot_right", f4(&g64.rot_right), f4_32(&g32.rot_right)),
            (
                "opacity",
                g64.opacity_logits.clone(),
                f1_32(&g32.opacity_logits),
            ),
            ("colours", g64.colours.clone(), f1_32(&g32.colours)),
            (
                "mean2d_norm",
                g64.mean2d_norm.clone(),
                f1_32(&g32.mean2d_norm),
            ),
        ];
        for (name, a, b) in pairs {
            let e = rel_err(&a, &b, 1e-9);
            assert!(e < 1e-3, "seed {seed} {name}: f32 vs f64 rel err {e:e}");
        }
    }
}
