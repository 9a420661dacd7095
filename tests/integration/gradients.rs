//! Finite-difference checks (f64) of every hand-written gradient: each stage on its own
//! (slicing, projection, colour, blending) and the whole renderer per parameter group.

use crate::common;

use common::{Rng, SceneSpec, camera, dot, random_scene, rel_err, weights};
use splat4d::math::project::{PinholeCamera, project, project_backward};
use splat4d::math::sh::{ColourInput, colour, colour_backward};
use splat4d::math::slice::{slice, slice_backward};
use splat4d::model::ColourDegrees;
use splat4d::render::cpu::blend::{
    PixelRect, Splat, SplatGrad, TileOut, TileUpstream, blend_tile_backward, blend_tile_forward,
};
use splat4d::render::cpu::{self, render_with};
use splat4d::{Gaussians, ImageGradients, RenderOptions};

const H: f64 = 1e-6;
const TOL: f64 = 1e-3;

/// Central differences of `f` at `x`, one coordinate at a time.
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

fn arr4(v: &[f64]) -> [f64; 4] {
    [v[0], v[1], v[2], v[3]]
}

#[test]
fn slicing_gradients_match_finite_differences() {
    for seed in 0..20u64 {
        let mut rng = Rng(seed);
        let mut x: Vec<f64> = (0..16).map(|_| rng.normal() * 0.6).collect();
        x[3] = 0.5; // μt
        x[7] = rng.range(-0.5, 0.3); // log σt
        let t = 0.5 + 0.4 * rng.normal() * (x[7].exp());
        let w: Vec<f64> = (0..16).map(|_| rng.normal()).collect();
        let loss = |x: &[f64]| -> Option<f64> {
            let (s, _) = slice(
                arr4(&x[0..4]),
                arr4(&x[4..8]),
                arr4(&x[8..12]),
                arr4(&x[12..16]),
                t,
            )?;
            let mut l = w[0] * s.omega + w[1] * s.mean[0] + w[2] * s.mean[1] + w[3] * s.mean[2];
            for i in 0..3 {
                for k in 0..4 {
                    l += w[4 + 4 * i + k] * s.factor[i][k];
                }
            }
            Some(l)
        };
        let Some((s, aux)) = slice(
            arr4(&x[0..4]),
            arr4(&x[4..8]),
            arr4(&x[8..12]),
            arr4(&x[12..16]),
            t,
        ) else {
            continue;
        };
        let mut db = [[0.0; 4]; 3];
        for i in 0..3 {
            for k in 0..4 {
                db[i][k] = w[4 + 4 * i + k];
            }
        }
        let g = slice_backward(&s, &aux, w[0], [w[1], w[2], w[3]], &db);
        let numeric = fd(&x, &mut |v| loss(v).unwrap_or(f64::NAN));
        for (name, range, an) in [
            ("mean", 0..4, g.mean),
            ("log_scales", 4..8, g.log_scales),
            ("rot_left", 8..12, g.rot_left),
            ("rot_right", 12..16, g.rot_right),
        ] {
            let e = rel_err(&an, &numeric[range], 1e-9);
            assert!(
                e < TOL,
                "seed {seed} {name}: rel err {e:e} ({an:?} vs {:?})",
                &numeric[..]
            );
        }
    }
}

#[test]
fn projection_gradients_match_finite_differences() {
    let cam = PinholeCamera::<f64>::from_camera(&camera(64, 48), 0.01);
    for seed in 0..20u64 {
        let mut rng = Rng(100 + seed);
        let mut x: Vec<f64> = vec![
            rng.range(-0.6, 0.6),
            rng.range(-0.6, 0.6),
            rng.range(-0.6, 0.6),
        ];
        // Some seeds put the mean far off-screen to exercise the clamped Jacobian.
        if seed % 5 == 4 {
            x[0] += 6.0;
        }
        x.extend((0..12).map(|_| rng.normal() * 0.2));
        let w: Vec<f64> = (0..6).map(|_| rng.normal()).collect();
        let loss = |x: &[f64]| -> f64 {
            let b = [arr4(&x[3..7]), arr4(&x[7..11]), arr4(&x[11..15])];
            let (p, _) = project(&cam, [x[0], x[1], x[2]], &b).expect("in front of camera");
            w[0] * p.mean[0]
                + w[1] * p.mean[1]
                + 10.0 * (w[2] * p.conic[0] + w[3] * p.conic[1] + w[4] * p.conic[2])
                + w[5] * p.depth
        };
        let b = [arr4(&x[3..7]), arr4(&x[7..11]), arr4(&x[11..15])];
        let (_, aux) = project(&cam, [x[0], x[1], x[2]], &b).unwrap();
        let (dm, db) = project_backward(
            &cam,
            &aux,
            &b,
            [w[0], w[1]],
            [10.0 * w[2], 10.0 * w[3], 10.0 * w[4]],
            w[5],
        );
        let numeric = fd(&x, &mut |v| loss(v));
        let e = rel_err(&dm, &numeric[0..3], 1e-9);
        assert!(
            e < TOL,
            "seed {seed} mean: {e:e} {dm:?} vs {:?}",
            &numeric[0..3]
        );
        let db_flat: Vec<f64> = db.iter().flatten().copied().collect();
        let e = rel_err(&db_flat, &numeric[3..], 1e-9);
        assert!(e < TOL, "seed {seed} factor: {e:e}");
    }
}

#[test]
fn colour_gradients_match_finite_differences() {
    for seed in 0..10u64 {
        let mut rng = Rng(200 + seed);
        let degrees = [
            ColourDegrees::FULL,
            ColourDegrees {
                spatial: 1,
                temporal: 1,
            },
            ColourDegrees::DC,
        ][seed as usize % 3];
        let capacity = ColourDegrees::FULL;
        let k = capacity.coeff_count() * 3;
        let mut x: Vec<f64> = vec![
            rng.normal(),
            rng.normal(),
            rng.normal(),
            rng.range(0.0, 1.0),
        ];
        x.extend((0..k).map(|_| 0.2 * rng.normal()));
        for c in 0..3 {
            x[4 + c] = 2.0; // positive colour: away from the clamp at 0
        }
        let w: Vec<f64> = (0..3).map(|_| rng.normal()).collect();
        fn input(
            x: &[f64],
            capacity: ColourDegrees,
            active: ColourDegrees,
        ) -> ColourInput<'_, f64> {
            ColourInput {
                mean: arr4(&x[0..4]),
                coeffs: &x[4..],
                capacity,
                active,
                camera_centre: [0.3, -4.0, 0.5],
                t: 0.37,
                period: 1.3,
            }
        }
        let loss = |x: &[f64]| dot(&colour(&input(x, capacity, degrees)), &w);
        let mut d_coeffs = vec![0.0; k];
        let d_mean = colour_backward(
            &input(&x, capacity, degrees),
            [w[0], w[1], w[2]],
            &mut d_coeffs,
        );
        let numeric = fd(&x, &mut |v| loss(v));
        let e = rel_err(&d_mean, &numeric[0..4], 1e-9);
        assert!(
            e < TOL,
            "seed {seed} mean: {e:e} {d_mean:?} vs {:?}",
            &numeric[0..4]
        );
        let e = rel_err(&d_coeffs, &numeric[4..], 1e-9);
        assert!(e < TOL, "seed {seed} coeffs: {e:e}");
    }
}

fn splats_from(x: &[f64]) -> Vec<Splat<f64>> {
    x.chunks_exact(10)
        .map(|c| {
            Splat::new(
                [c[0], c[1]],
                [c[2], c[3], c[4]],
                c[5],
                [c[6], c[7], c[8]],
                c[9],
            )
        })
        .collect()
}

#[test]
fn blending_gradients_match_finite_differences() {
    let rect = PixelRect {
        x0: 16,
        y0: 32,
        x1: 32,
        y1: 48,
    };
    let n_pix = rect.len();
    for seed in 0..10u64 {
        let mut rng = Rng(300 + seed);
        let mut x = Vec::new();
        for k in 0..7 {
            let sx = rng.range(1.5, 5.0);
            let sy = rng.range(1.5, 5.0);
            let rho = rng.range(-0.6, 0.6);
            let det = sx * sx * sy * sy * (1.0 - rho * rho);
            x.extend([
                rng.range(14.0, 34.0),
                rng.range(30.0, 50.0),
                sy * sy / det,
                -rho * sx * sy / det,
                sx * sx / det,
                // one nearly opaque splat: the α = 0.99 clamp is exercised too
                if k == 3 { 3.0 } else { rng.range(0.2, 0.9) },
                rng.uniform(),
                rng.uniform(),
                rng.uniform(),
                1.0 + k as f64 * 0.3,
            ]);
        }
        let bg = [0.2, 0.5, 0.9];
        let wr = weights(seed, 3 * n_pix);
        let wa = weights(seed + 1, n_pix);
        let wd = weights(seed + 2, n_pix);
        let loss = |x: &[f64]| {
            let mut out = TileOut::default();
            blend_tile_forward(rect, &splats_from(x), bg, &mut out);
            dot(&out.rgb, &wr) + dot(&out.alpha, &wa) + dot(&out.depth, &wd)
        };
        let splats = splats_from(&x);
        let mut out = TileOut::default();
        blend_tile_forward(rect, &splats, bg, &mut out);
        let mut grads = vec![SplatGrad::default(); splats.len()];
        let up = TileUpstream {
            rgb: &wr,
            alpha: &wa,
            depth: &wd,
        };
        blend_tile_backward(
            rect,
            &splats,
            bg,
            &out.final_t,
            &out.n_contrib,
            &up,
            &mut grads,
        );
        let numeric = fd(&x, &mut |v| loss(v));
        let an: Vec<f64> = grads
            .iter()
            .flat_map(|g| {
                [
                    g.mean[0],
                    g.mean[1],
                    g.conic[0],
                    g.conic[1],
                    g.conic[2],
                    g.opacity,
                    g.colour[0],
                    g.colour[1],
                    g.colour[2],
                    g.depth,
                ]
            })
            .collect();
        for (name, fields) in [
            ("mean", 0..2),
            ("conic", 2..5),
            ("opacity", 5..6),
            ("colour", 6..9),
            ("depth", 9..10),
        ] {
            let pick = |v: &[f64]| -> Vec<f64> {
                v.chunks_exact(10)
                    .flat_map(|c| c[fields.clone()].to_vec())
                    .collect()
            };
            let e = rel_err(&pick(&an), &pick(&numeric), 1e-9);
            assert!(e < TOL, "seed {seed} {name}: rel err {e:e}");
        }
    }
}

/// Flattened parameter groups of a model.
fn groups(m: &Gaussians<f64>) -> Vec<(&'static str, Vec<f64>)> {
    let flat = |v: &Vec<[f64; 4]>| v.iter().flatten().copied().collect::<Vec<_>>();
    vec![
        ("means", flat(&m.means)),
        ("log_scales", flat(&m.log_scales)),
        ("rot_left", flat(&m.rot_left)),
        ("rot_right", flat(&m.rot_right)),
        ("opacity_logits", m.opacity_logits.clone()),
        ("colours", m.colours.clone()),
    ]
}

fn set_group(m: &mut Gaussians<f64>, group: usize, v: &[f64]) {
    let quad = |v: &[f64]| v.chunks_exact(4).map(arr4).collect::<Vec<_>>();
    match group {
        0 => m.means = quad(v),
        1 => m.log_scales = quad(v),
        2 => m.rot_left = quad(v),
        3 => m.rot_right = quad(v),
        4 => m.opacity_logits = v.to_vec(),
        _ => m.colours = v.to_vec(),
    }
}

#[test]
fn render_gradients_match_finite_differences_per_parameter_group() {
    let cam = camera(48, 40);
    for seed in 0..3u64 {
        let model = random_scene(seed, SceneSpec::default());
        let n = model.len();
        let factor: Vec<f64> = (0..n).map(|i| 0.6 + 0.05 * i as f64).collect();
        let npix = 48 * 40;
        let (wr, wa, wd) = (
            weights(seed, 3 * npix),
            weights(seed + 7, npix),
            weights(seed + 9, npix),
        );
        let t = 0.47;
        let loss = |m: &Gaussians<f64>, f: &[f64]| {
            let opts = RenderOptions {
                background: [0.1, 0.3, 0.6],
                opacity_factor: Some(f),
                near_plane: 0.01,
            };
            let r = render_with(m, &cam, t, &opts).unwrap();
            dot(&r.rgb, &wr) + dot(&r.alpha, &wa) + 0.1 * dot(&r.depth, &wd)
        };
        let opts = RenderOptions {
            background: [0.1, 0.3, 0.6],
            opacity_factor: Some(&factor),
            near_plane: 0.01,
        };
        let r = render_with(&model, &cam, t, &opts).unwrap();
        assert!(r.stats.visible >= n - 1, "scene should be visible");
        let wd_scaled: Vec<f64> = wd.iter().map(|w| 0.1 * w).collect();
        let up = ImageGradients {
            rgb: &wr,
            alpha: Some(&wa),
            depth: Some(&wd_scaled),
        };
        let g = cpu::backward(&r, &model, &up).unwrap();
        let flat = |v: &Vec<[f64; 4]>| v.iter().flatten().copied().collect::<Vec<_>>();
        let analytic = [
            flat(&g.means),
            flat(&g.log_scales),
            flat(&g.rot_left),
            flat(&g.rot_right),
            g.opacity_logits.clone(),
            g.colours.clone(),
        ];
        for (gi, (name, x)) in groups(&model).into_iter().enumerate() {
            let mut m = model.clone();
            let numeric = fd(&x, &mut |v| {
                set_group(&mut m, gi, v);
                loss(&m, &factor)
            });
            let e = rel_err(&analytic[gi], &numeric, 1e-9);
            assert!(e < TOL, "seed {seed} {name}: rel err {e:e}");
        }
        let numeric = fd(&factor, &mut |f| loss(&model, f));
        let e = rel_err(&g.opacity_factor, &numeric, 1e-9);
        assert!(e < TOL, "seed {seed} opacity_factor: rel err {e:e}");
    }
}
