//! Finite-difference checks (f64) of the Neural Decaying Function: f_θ's hand-written
//! backward (inputs and weights), and the τ-factor path renderer → τ → f_θ's weights.

use crate::common;

use common::{SceneSpec, camera, dot, random_scene, rel_err, weights};
use splat4d::decay::DecayInputs;
use splat4d::decay::inputs::input_rows;
use splat4d::decay::mlp::Mlp;
use splat4d::render::cpu::{self, render_with};
use splat4d::{ImageGradients, RenderOptions};

const H: f64 = 1e-6;

/// Central differences of `f` at `x`.
fn fd(x: &[f64], f: &mut dyn FnMut(&[f64]) -> f64) -> Vec<f64> {
    let mut v = x.to_vec();
    (0..x.len())
        .map(|i| {
            let x0 = v[i];
            v[i] = x0 + H;
            let a = f(&v);
            v[i] = x0 - H;
            let b = f(&v);
            v[i] = x0;
            (a - b) / (2.0 * H)
        })
        .collect()
}

#[test]
fn mlp_backward_matches_finite_differences_for_weights_and_inputs() {
    for (dims, rows) in [
        (vec![9, 32, 32, 1], 700),
        (vec![12, 5, 1], 9),
        (vec![3, 1], 4),
    ] {
        let mlp = Mlp::<f64>::new(&dims, 3);
        // 1100 rows span three parallel chunks, so the chunked reduction is exercised.
        let x = weights(11, rows * dims[0])
            .iter()
            .map(|v| 2.0 * v)
            .collect::<Vec<_>>();
        let w = weights(12, rows);
        // The full sigmoid range keeps the finite differences well above round-off.
        let (f_min, f_max) = (0.0, 1.0);
        // Scalar loss L = Σ w·τ(z).
        let loss = |mlp: &Mlp<f64>, x: &[f64]| {
            let c = mlp.forward(x);
            c.z.iter()
                .zip(&w)
                .map(|(&z, &w)| w * Mlp::tau(z, f_min, f_max))
                .sum::<f64>()
        };
        let cache = mlp.forward(&x);
        let d_z: Vec<f64> = cache
            .z
            .iter()
            .zip(&w)
            .map(|(&z, &w)| w * Mlp::tau_derivative(z, f_min, f_max))
            .collect();
        let g = mlp.backward(&x, &cache, &d_z, true);

        let num_w = fd(&mlp.params, &mut |p| {
            let m = Mlp {
                dims: dims.clone(),
                params: p.to_vec(),
            };
            loss(&m, &x)
        });
        let e = rel_err(&g.params, &num_w, 1e-12);
        assert!(e < 1e-5, "{dims:?}: weight gradient rel. error {e:e}");

        // Inputs: check a prefix of rows (each coordinate costs two forwards).
        let k = rows.min(6) * dims[0];
        let num_x = fd(&x[..k], &mut |xs| {
            let mut full = x.clone();
            full[..k].copy_from_slice(xs);
            loss(&mlp, &full)
        });
        let gi = g.inputs.as_ref().unwrap();
        let e = rel_err(&gi[..k], &num_x, 1e-12);
        assert!(e < 1e-5, "{dims:?}: input gradient rel. error {e:e}");
    }
}

#[test]
fn f32_and_f64_forward_agree_and_tau_stays_in_range() {
    let dims = [9, 32, 32, 1];
    let m64 = Mlp::<f64>::new(&dims, 9);
    let m32: Mlp<f32> = m64.cast();
    let x: Vec<f64> = weights(5, 50 * 9).iter().map(|v| 3.0 * v).collect();
    let x32: Vec<f32> = x.iter().map(|&v| v as f32).collect();
    let (a, b) = (m64.forward(&x), m32.forward(&x32));
    for (za, zb) in a.z.iter().zip(&b.z) {
        assert!((za - *zb as f64).abs() < 1e-4 * (1.0 + za.abs()));
    }
    // Extreme outputs still map into [f_min, f_max].
    for z in [
        -1e30f32,
        -80.0,
        0.0,
        80.0,
        1e30,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ] {
        let t = Mlp::tau(z, 0.996f32, 0.998);
        assert!((0.996..=0.998).contains(&t), "τ({z}) = {t}");
    }
}

#[test]
fn tau_factor_gradient_reaches_the_mlp_weights() {
    // f64 end to end: z-scored official inputs → f_θ → τ → render opacity factor → image
    // → linear loss Σ w·rgb. Analytic: render backward's dL/dτ, then f_θ's backward.
    let model = random_scene(
        21,
        SceneSpec {
            count: 10,
            ..Default::default()
        },
    );
    let cam = camera(40, 30);
    let t = 0.5;
    // A wide τ range makes the path's gradient large enough to check.
    let (f_min, f_max) = (0.3, 1.0);
    for inputs in [DecayInputs::Official, DecayInputs::Paper] {
        let x = input_rows(&model, inputs);
        let mlp = Mlp::<f64>::new(&[inputs.width(), 4, 4, 1], 4);
        let w = weights(8, 3 * 40 * 30);
        let loss = |mlp: &Mlp<f64>| {
            let c = mlp.forward(&x);
            let tau: Vec<f64> = c.z.iter().map(|&z| Mlp::tau(z, f_min, f_max)).collect();
            let opts = RenderOptions {
                opacity_factor: Some(&tau),
                ..Default::default()
            };
            dot(&render_with(&model, &cam, t, &opts).unwrap().rgb, &w)
        };
        let cache = mlp.forward(&x);
        let tau: Vec<f64> = cache.z.iter().map(|&z| Mlp::tau(z, f_min, f_max)).collect();
        let opts = RenderOptions {
            opacity_factor: Some(&tau),
            ..Default::default()
        };
        let r = render_with(&model, &cam, t, &opts).unwrap();
        let g = cpu::backward(
            &r,
            &model,
            &ImageGradients {
                rgb: &w,
                alpha: None,
                depth: None,
            },
        )
        .unwrap();
        assert!(g.opacity_factor.iter().any(|v| v.abs() > 1e-6));
        let d_z: Vec<f64> = g
            .opacity_factor
            .iter()
            .zip(&cache.z)
            .map(|(&d, &z)| d * Mlp::tau_derivative(z, f_min, f_max))
            .collect();
        let analytic = mlp.backward(&x, &cache, &d_z, false).params;
        let numeric = fd(&mlp.params, &mut |p| {
            loss(&Mlp {
                dims: mlp.dims.clone(),
                params: p.to_vec(),
            })
        });
        let e = rel_err(&analytic, &numeric, 1e-9);
        assert!(e < 1e-4, "{inputs:?}: rel. error {e:e}");
        assert!(analytic.iter().map(|v| v.abs()).sum::<f64>() > 1e-6);
    }
}
