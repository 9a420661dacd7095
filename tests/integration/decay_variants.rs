//! The decay variants on a toy model, driven through the `TrainHooks` seam exactly as the
//! trainer calls it: the intended per-step factors, once per step for a batch of views,
//! β for invisible Gaussians, nothing during warm-up; stability with extreme inputs; the
//! TOML config.

use crate::common;

use common::camera;
use splat4d::decay::variants::{decayed_logit, exp_factor, pow_factor};
use splat4d::decay::{DecayConfig, DecayHooks, DecayInputs, DecayVariant, VisibilityMode};
use splat4d::math::numerics::sigmoid;
use splat4d::train::{ImageU8, TrainHooks, View};
use splat4d::{ColourDegrees, Gaussians, TimeMapping};

/// Gaussians 0–2 in front of the camera (opacities 0.05, 0.5, 0.95), 3 behind it, 4 in
/// front but outside its time span.
fn toy() -> Gaussians<f32> {
    let mut g = Gaussians::new(ColourDegrees::DC, TimeMapping::default());
    let logit = |p: f64| (p / (1.0 - p)).ln() as f32;
    for (i, p) in [0.05, 0.5, 0.95].into_iter().enumerate() {
        g.push(
            [0.2 * i as f32, 0.0, 0.0, 0.5],
            [-2.0; 4],
            logit(p),
            [0.5; 3],
        );
    }
    g.push([0.0, -9.0, 0.0, 0.5], [-2.0; 4], logit(0.5), [0.5; 3]);
    g.push(
        [0.0, 0.0, 0.0, 5.0],
        [-2.0, -2.0, -2.0, -3.0],
        logit(0.5),
        [0.5; 3],
    );
    g
}

fn view() -> View {
    let cam = camera(32, 24);
    View::at_image_size(cam, 0.5, ImageU8::from_f32(32, 24, &vec![0.5; 32 * 24 * 3]))
}

fn opacities(g: &Gaussians<f32>) -> Vec<f64> {
    g.opacity_logits
        .iter()
        .map(|&l| sigmoid(l as f64))
        .collect()
}

/// One trainer step (0-based `it`) with `views` renders; returns the factors applied.
fn step(h: &mut DecayHooks, g: &mut Gaussians<f32>, it: u64, views: usize) -> Vec<f64> {
    let before = opacities(g);
    let v = view();
    for _ in 0..views {
        if let Some(f) = h.opacity_factor(it, g, &v) {
            assert_eq!(f.len(), g.len());
            let grad = vec![0.1f32; g.len()];
            h.factor_gradient(it, g, &grad);
        }
    }
    h.after_step(it + 1, g);
    opacities(g)
        .iter()
        .zip(&before)
        .map(|(a, b)| a / b)
        .collect()
}

fn config(variant: DecayVariant) -> DecayConfig {
    DecayConfig {
        variant,
        warmup: 2,
        ..Default::default()
    }
}

#[test]
fn each_variant_applies_its_factor_once_per_step() {
    let close = |a: f64, b: f64| (a - b).abs() < 2e-6;
    let beta = DecayConfig::default().beta;
    for variant in [
        DecayVariant::None,
        DecayVariant::Constant,
        DecayVariant::Pow,
        DecayVariant::Exp,
        DecayVariant::Neural,
    ] {
        let c = config(variant);
        let mut h = DecayHooks::new(&c).unwrap();
        let mut g = toy();
        // Warm-up: steps 1 and 2 change nothing.
        for it in 0..2 {
            assert!(step(&mut h, &mut g, it, 2).iter().all(|&r| r == 1.0));
        }
        let o = opacities(&g);
        let tau = h.tau(&g);
        // A batch of 3 views of the same camera: still ONE factor per Gaussian.
        let r = step(&mut h, &mut g, 2, 3);
        for i in 0..3 {
            let want = match variant {
                DecayVariant::None => 1.0,
                DecayVariant::Constant => c.constant,
                DecayVariant::Pow => pow_factor(o[i], &c),
                DecayVariant::Exp => exp_factor(o[i], &c),
                DecayVariant::Neural => tau[i] as f64,
            };
            assert!(close(r[i], want), "{variant:?} #{i}: {} vs {want}", r[i]);
        }
        // Behind the camera / outside the time span: β (nothing for `none`).
        let want = if variant == DecayVariant::None {
            1.0
        } else {
            beta
        };
        assert!(close(r[3], want) && close(r[4], want), "{variant:?}: {r:?}");
        if variant != DecayVariant::None {
            let s = h.last_stats().unwrap();
            assert_eq!((s.iteration, s.visible, s.invisible), (3, 3, 2));
        }
    }
}

#[test]
fn hand_tuned_factors_decay_faint_gaussians_fastest_within_the_range() {
    let c = DecayConfig::default();
    for f in [pow_factor, exp_factor] {
        let xs: Vec<f64> = (0..=20).map(|k| f(k as f64 / 20.0, &c)).collect();
        assert!(xs.windows(2).all(|w| w[0] <= w[1]), "{xs:?}");
        assert!(xs.iter().all(|&x| (c.f_min..=c.f_max).contains(&x)));
        assert!(xs[0] < xs[20]);
    }
}

#[test]
fn neural_factor_reaches_the_render_only_for_visible_gaussians_and_trains_f_theta() {
    let mut h = DecayHooks::new(&config(DecayVariant::Neural)).unwrap();
    let g = toy();
    let v = view();
    assert!(h.opacity_factor(1, &g, &v).is_none(), "warm-up");
    let f = h.opacity_factor(2, &g, &v).unwrap();
    let tau = h.tau(&g);
    assert_eq!(&f[..3], &tau[..3]);
    assert_eq!(&f[3..], &[1.0, 1.0]);
    let before = h.mlp().params.clone();
    h.factor_gradient(2, &g, &[1.0; 5]);
    let mut g2 = g.clone();
    h.after_step(3, &mut g2);
    assert_ne!(h.mlp().params, before, "f_θ took an Adam step");
    assert_eq!(h.optimiser().step, 1);
    // Without visibility every Gaussian gets τ, in the render and in the stored opacity.
    let c = DecayConfig {
        visibility: VisibilityMode::Off,
        ..config(DecayVariant::Neural)
    };
    let mut h = DecayHooks::new(&c).unwrap();
    let f = h.opacity_factor(2, &g, &v).unwrap();
    assert!(f.iter().all(|&x| (0.996..=0.998).contains(&x)));
}

#[test]
fn densification_between_steps_is_handled() {
    let mut h = DecayHooks::new(&config(DecayVariant::Neural)).unwrap();
    let mut g = toy();
    step(&mut h, &mut g, 2, 2);
    // The trainer densifies after `after_step`; the next step sees more Gaussians.
    let i = g.push([0.1, 0.0, 0.0, 0.5], [-2.0; 4], 0.0, [0.5; 3]);
    let r = step(&mut h, &mut g, 3, 2);
    assert_eq!(r.len(), i + 1);
    assert!((0.996..=0.998).contains(&(r[i] + 1e-7)));
    // A model changed between render and after_step (not done by the trainer) is left
    // alone rather than decayed with stale factors.
    let v = view();
    h.opacity_factor(4, &g, &v);
    g.push([0.1, 0.0, 0.0, 0.5], [-2.0; 4], 0.0, [0.5; 3]);
    let before = g.opacity_logits.clone();
    h.after_step(5, &mut g);
    assert_eq!(g.opacity_logits, before);
}

#[test]
fn opacities_stay_finite_and_in_the_open_unit_interval_under_extreme_inputs() {
    for inputs in [DecayInputs::Official, DecayInputs::Paper] {
        let c = DecayConfig {
            inputs,
            warmup: 0,
            lr: 1e-1, // far above the default, to push f_θ to its bounds
            ..DecayConfig::neural()
        };
        let mut h = DecayHooks::new(&c).unwrap();
        let mut g = toy();
        // Extreme positions, scales, rotations and opacities.
        g.push(
            [1e30, -1e30, 3e29, 1e20],
            [40.0, -40.0, 0.0, 9.0],
            80.0,
            [0.5; 3],
        );
        g.push([0.0, 0.0, 1.0, 0.5], [-2.0; 4], -80.0, [0.5; 3]);
        g.rot_left[1] = [0.0; 4];
        g.rot_right[2] = [1e20, -1e20, 0.0, 3.0];
        let v = view();
        for it in 0..2000u64 {
            if let Some(f) = h.opacity_factor(it, &g, &v) {
                assert!(f.iter().all(|&x| (0.996..=1.0).contains(&x)), "{f:?}");
                let huge = if it % 2 == 0 { 1e30 } else { -1e30 };
                h.factor_gradient(it, &g, &vec![huge; g.len()]);
            }
            h.after_step(it + 1, &mut g);
            let s = h.last_stats().unwrap();
            assert!(s.min_factor >= 0.996 - 1e-7 && s.max_factor <= 0.999 + 1e-9);
            assert!(h.mlp().params.iter().all(|p| p.is_finite()));
        }
        for (i, &l) in g.opacity_logits.iter().enumerate() {
            let p = sigmoid(l);
            assert!(
                l.is_finite() && p > 0.0 && p < 1.0,
                "#{i}: logit {l}, opacity {p}"
            );
        }
    }
    // The write-back alone: never increases, stays finite, floor respected.
    for l in [-1e4f32, -80.0, -30.0, -5.0, 0.0, 5.0, 30.0, 80.0, 1e4] {
        for d in [1e-9, 0.5, 0.996, 0.999, 1.0] {
            let y = decayed_logit(l, d);
            assert!(y.is_finite() && y <= l, "{l} × {d} → {y}");
            assert!(y >= -30.0 || y == l);
        }
    }
}

#[test]
fn config_reads_from_toml_and_rejects_unknown_keys_and_bad_values() {
    let c: DecayConfig = toml::from_str(
        "variant = \"pow\"\nvisibility = \"near_plane\"\nbeta = 1.0\ninputs = \"paper\"\nwarmup = 100\n",
    )
    .unwrap();
    assert_eq!(c.variant, DecayVariant::Pow);
    assert_eq!(c.visibility, VisibilityMode::NearPlane);
    assert_eq!((c.beta, c.inputs, c.warmup), (1.0, DecayInputs::Paper, 100));
    assert_eq!(c.f_min, 0.996);
    let back: DecayConfig = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
    assert_eq!(back, c);
    let e = toml::from_str::<DecayConfig>("varient = \"pow\"").unwrap_err();
    assert!(e.to_string().contains("varient"));
    for bad in [
        "beta = 1.5",
        "f_min = 0.999\nf_max = 0.99",
        "constant = 0.0",
    ] {
        let c: DecayConfig = toml::from_str(bad).unwrap();
        let e = DecayHooks::new(&c).err().expect(bad).to_string();
        assert!(e.contains("[decay]"), "{e}");
    }
    let labels: Vec<String> = DecayConfig::variants_for_ablation()
        .into_iter()
        .map(|(l, c)| {
            c.validate().unwrap();
            l
        })
        .collect();
    assert_eq!(labels.len(), 7);
    assert_eq!(labels[0], "none");
}
