//! Pseudo views: a training view's pixels, lifted to 3D with the render's own depth and
//! seen from a virtual camera beside the training camera, must show the training image.
//! The virtual camera's render is sampled where each lifted pixel lands and compared with
//! the training image (L1); the gradient reaches the virtual render's Gaussians and the
//! training render's depth (through where each pixel lands), so geometry that lines up
//! only for the training camera is pulled towards one surface that every nearby viewpoint
//! agrees on. Only landing points where the virtual view sees the same surface, or none,
//! take part: behind a farther one the colour gradient would repaint that surface, which
//! left a dark haze over a whole held-out view of the simulated jumping object. On by
//! default on the host step (docs/experiments/people-on-basketball.md, "Pseudo views").

use crate::model::Gaussians;
use crate::render::{Gradients, ImageGradients, RenderBackend, RenderOptions, Rendered};
use crate::train::{TrainError, View};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use shared_types::camera::{Camera, WorldToCamera};

/// `[train.pseudo_views]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PseudoViewConfig {
    /// Weight of the consistency L1 beside the image loss (0: off).
    pub weight: f64,
    /// How far the virtual camera sits beside the training camera, as a fraction of the
    /// distance to the nearest other training camera (in a random direction of the image
    /// plane each step).
    pub baseline: f64,
    /// Fraction of the run trained before the term starts (the geometry forms first).
    pub start: f64,
    /// Views of each batch that get a pseudo view (the first ones drawn; by default every
    /// view of a default batch).
    pub per_step: usize,
}

impl Default for PseudoViewConfig {
    fn default() -> Self {
        Self {
            weight: 0.3,
            baseline: 0.3,
            start: 0.25,
            per_step: crate::train::DEFAULT_BATCH_SIZE,
        }
    }
}

impl PseudoViewConfig {
    /// Why the settings are invalid, if they are.
    pub fn problem(&self) -> Option<&'static str> {
        if !(self.weight.is_finite() && self.weight >= 0.0) {
            return Some("pseudo_views.weight must be finite and ≥ 0 (0: off)");
        }
        if !(self.baseline > 0.0 && self.baseline <= 1.0) {
            return Some(
                "pseudo_views.baseline must be in (0, 1] (a fraction of the distance to the nearest other camera)",
            );
        }
        if !(0.0..=1.0).contains(&self.start) {
            return Some("pseudo_views.start must be in [0, 1] (a fraction of the run)");
        }
        if self.per_step == 0 {
            return Some("pseudo_views.per_step must be at least 1");
        }
        None
    }

    /// Whether the view at `position` in iteration `iteration`'s batch gets a pseudo view.
    pub fn applies(&self, iteration: u64, iterations: u64, position: usize) -> bool {
        self.weight > 0.0
            && position < self.per_step
            && iteration as f64 >= self.start * iterations as f64
    }
}

/// The virtual view of one training view at one step.
#[derive(Clone, Debug)]
pub struct VirtualView {
    /// The training camera moved by `shift` along its own x and y axes.
    pub camera: Camera,
    pub shift: [f64; 2],
    /// The term's weight for this view: the configured one times the batch's 1/n.
    pub weight: f32,
}

/// Where and when the pseudo views of one run are: each view's baseline length and the
/// settings. Both steps, host and device, draw their virtual views from it.
pub(crate) struct PseudoPlan {
    config: PseudoViewConfig,
    iterations: u64,
    seed: u64,
    /// Per dataset view, the virtual camera's distance from it.
    baselines: Vec<f64>,
}

impl PseudoPlan {
    pub fn new(config: PseudoViewConfig, iterations: u64, seed: u64, views: &[View]) -> Self {
        let cameras: Vec<&Camera> = views.iter().map(|v| &v.camera).collect();
        let baselines = nearest_other_centre(&cameras)
            .into_iter()
            .map(|d| config.baseline * d)
            .collect();
        Self {
            config,
            iterations,
            seed,
            baselines,
        }
    }

    /// The virtual view of dataset view `vi` at batch position `position` of iteration
    /// `iteration`, whose batch weighs each view `scale`; `None` when the term does not
    /// apply (or the view has no other camera to set its baseline).
    pub fn virtual_view(
        &self,
        iteration: u64,
        (vi, position): (usize, usize),
        camera: &Camera,
        scale: f32,
    ) -> Option<VirtualView> {
        let length = self.baselines[vi];
        if !self.config.applies(iteration, self.iterations, position) || length <= 0.0 {
            return None;
        }
        let shift = shift_for(self.seed, iteration, vi, length);
        Some(VirtualView {
            camera: shifted_camera(camera, shift),
            shift,
            weight: self.config.weight as f32 * scale,
        })
    }
}

/// The pseudo-view term of the host step: its plan and a reused gradient buffer.
pub(crate) struct PseudoViews {
    plan: PseudoPlan,
    /// The virtual view's gradients, made on first use and reused.
    g: Option<Gradients<f32>>,
}

/// The upstream gradients of a training render that the pseudo view adds.
pub(crate) struct DepthGradients {
    pub alpha: Vec<f32>,
    pub depth: Vec<f32>,
}

impl PseudoViews {
    pub fn new(plan: PseudoPlan) -> Self {
        Self { plan, g: None }
    }

    /// For view `vi` at batch position `position`, rendered as `r` against `target`:
    /// render the virtual view, add its gradient (scaled by `scale`, the batch's 1/n) to
    /// `grads`, and return the training render's extra upstream gradients; `None` when
    /// the term does not apply.
    #[allow(clippy::too_many_arguments)]
    pub fn apply(
        &mut self,
        backend: &dyn RenderBackend,
        model: &Gaussians<f32>,
        iteration: u64,
        (vi, position): (usize, usize),
        view: &View,
        options: &RenderOptions<'_, f32>,
        r: &Rendered<f32>,
        target: &[f32],
        scale: f32,
        grads: &mut Gradients<f32>,
    ) -> Result<Option<DepthGradients>, TrainError> {
        let Some(v) = self
            .plan
            .virtual_view(iteration, (vi, position), &view.camera, scale)
        else {
            return Ok(None);
        };
        let render_error = |source| TrainError::Render { index: vi, source };
        let rv = backend
            .render(model, &v.camera, view.time, options)
            .map_err(render_error)?;
        let c = consistency(
            &view.camera,
            v.shift,
            (r.width as usize, r.height as usize),
            (&r.alpha, &r.depth, target),
            (&rv.rgb, &rv.alpha, &rv.depth),
            v.weight,
        );
        let up = ImageGradients {
            rgb: &c.d_virtual_rgb,
            alpha: None,
            depth: None,
        };
        let g = self
            .g
            .get_or_insert_with(|| Gradients::zeros_like(model, false));
        backend.backward(model, &rv, &up, g).map_err(render_error)?;
        grads.add(g);
        Ok(Some(DepthGradients {
            alpha: c.d_alpha,
            depth: c.d_depth,
        }))
    }
}

/// `camera` moved by `shift` along its own x and y axes (orientation and lens kept).
pub fn shifted_camera(camera: &Camera, shift: [f64; 2]) -> Camera {
    let mut c = camera.clone();
    let t = camera.world_to_camera.translation() - DVec3::new(shift[0], shift[1], 0.0);
    c.world_to_camera = WorldToCamera::from_parts(camera.world_to_camera.rotation(), t);
    c
}

/// Per view, the distance to the nearest other camera centre (views of one camera share
/// a centre; 0 when there is no other camera).
pub fn nearest_other_centre(cameras: &[&Camera]) -> Vec<f64> {
    let centres: Vec<DVec3> = cameras.iter().map(|c| c.world_to_camera.centre()).collect();
    centres
        .iter()
        .map(|a| {
            centres
                .iter()
                .map(|b| a.distance(*b))
                .filter(|&d| d > 1e-6)
                .fold(f64::INFINITY, f64::min)
        })
        .map(|d| if d.is_finite() { d } else { 0.0 })
        .collect()
}

/// How far (as a ratio) the virtual view's depth at a landing point may lie from the
/// lifted point's for the two to be one surface.
const DEPTH_AGREEMENT: f64 = 0.95;

/// The consistency loss and its gradients.
pub struct Consistency {
    /// Loss (weighted mean over all pixels and channels).
    pub loss: f64,
    /// Fraction of pixels that took part.
    pub valid: f64,
    /// dL/d(virtual rgb).
    pub d_virtual_rgb: Vec<f32>,
    /// dL/d(training alpha), dL/d(training Σwz).
    pub d_alpha: Vec<f32>,
    pub d_depth: Vec<f32>,
}

/// Lift each training pixel with `alpha > 0.5` to its expected depth `depth/alpha`, land
/// it in the virtual view (the training camera moved by `shift` in its own x/y; same
/// intrinsics and size), sample the virtual render bilinearly there and compare with
/// `target` (L1). Pixels whose landing point is off the image, or where the virtual view
/// sees another surface (its own depth there more than 5 % nearer or farther), do not
/// take part.
pub fn consistency(
    camera: &Camera,
    shift: [f64; 2],
    (width, height): (usize, usize),
    (alpha, depth, target): (&[f32], &[f32], &[f32]),
    (virtual_rgb, virtual_alpha, virtual_depth): (&[f32], &[f32], &[f32]),
    weight: f32,
) -> Consistency {
    let k = &camera.intrinsics;
    let npix = width * height;
    let norm = weight as f64 / (3 * npix) as f64;
    let mut out = Consistency {
        loss: 0.0,
        valid: 0.0,
        d_virtual_rgb: vec![0.0; 3 * npix],
        d_alpha: vec![0.0; npix],
        d_depth: vec![0.0; npix],
    };
    let mut valid = 0usize;
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            let a = alpha[p] as f64;
            if a <= 0.5 {
                continue;
            }
            let z = depth[p] as f64 / a;
            if z <= 1e-6 {
                continue;
            }
            let u = (x as f64 + 0.5 - k.cx) / k.fx;
            let v = (y as f64 + 0.5 - k.cy) / k.fy;
            // Landing point in the virtual image (pixel-index space: centre at integer).
            let sx = k.fx * (u - shift[0] / z) + k.cx - 0.5;
            let sy = k.fy * (v - shift[1] / z) + k.cy - 0.5;
            if !(sx >= 0.0 && sy >= 0.0 && sx < (width - 1) as f64 && sy < (height - 1) as f64) {
                continue;
            }
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (fa, fb) = (sx - x0 as f64, sy - y0 as f64);
            let q00 = y0 * width + x0;
            let idx = [q00, q00 + 1, q00 + width, q00 + width + 1];
            // The virtual view must see the same surface there, or none: its nearest
            // corner's depth well in front hides the point, and well behind means a
            // surface the colour gradient would repaint with this pixel's colour.
            let qn = idx[(fa >= 0.5) as usize + 2 * (fb >= 0.5) as usize];
            let av = virtual_alpha[qn] as f64;
            if av > 0.5
                && !(DEPTH_AGREEMENT * z..=z / DEPTH_AGREEMENT)
                    .contains(&(virtual_depth[qn] as f64 / av))
            {
                continue;
            }
            valid += 1;
            let w = [
                (1.0 - fa) * (1.0 - fb),
                fa * (1.0 - fb),
                (1.0 - fa) * fb,
                fa * fb,
            ];
            let mut dz = 0.0;
            for c in 0..3 {
                let s = |i: usize| virtual_rgb[3 * idx[i] + c] as f64;
                let warped: f64 = (0..4).map(|i| w[i] * s(i)).sum();
                let e = warped - target[3 * p + c] as f64;
                out.loss += norm * e.abs();
                let g = norm * e.signum();
                for i in 0..4 {
                    out.d_virtual_rgb[3 * idx[i] + c] += (g * w[i]) as f32;
                }
                let d_sx = (1.0 - fb) * (s(1) - s(0)) + fb * (s(3) - s(2));
                let d_sy = (1.0 - fa) * (s(2) - s(0)) + fa * (s(3) - s(1));
                dz += g * (d_sx * k.fx * shift[0] + d_sy * k.fy * shift[1]) / (z * z);
            }
            // z = D / A.
            out.d_depth[p] = (dz / a) as f32;
            out.d_alpha[p] = (-dz * depth[p] as f64 / (a * a)) as f32;
        }
    }
    out.valid = valid as f64 / npix as f64;
    out
}

/// The virtual camera's shift for (seed, iteration, view): `length` in a direction of the
/// image plane drawn from a hash of the three, so a resumed run draws the same.
pub fn shift_for(seed: u64, iteration: u64, view: usize, length: f64) -> [f64; 2] {
    let mut h = (seed ^ iteration.rotate_left(32))
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((view as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9));
    h ^= h >> 31;
    h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^= h >> 29;
    let angle = (h >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::TAU;
    [length * angle.cos(), length * angle.sin()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::camera::Intrinsics;

    fn camera(w: u32, h: u32) -> Camera {
        Camera {
            name: "c".into(),
            intrinsics: Intrinsics::from_hfov(w, h, 60.0),
            distortion: Default::default(),
            world_to_camera: WorldToCamera::IDENTITY,
        }
    }

    /// The depth and alpha gradients match central differences of the loss, and the
    /// virtual image's gradient is the loss's slope in each of its values.
    #[test]
    fn gradients_match_finite_differences() {
        let (w, h) = (24usize, 18usize);
        let cam = camera(w as u32, h as u32);
        let n = w * h;
        let alpha: Vec<f32> = (0..n).map(|i| 0.7 + 0.2 * ((i % 7) as f32 / 7.0)).collect();
        let depth: Vec<f32> = (0..n)
            .map(|i| alpha[i] * (3.0 + 0.3 * ((i * 13 % 11) as f32 / 11.0)))
            .collect();
        let target: Vec<f32> = (0..3 * n).map(|i| ((i * 7 % 17) as f32) / 17.0).collect();
        let vrgb: Vec<f32> = (0..3 * n)
            .map(|i| {
                let p = i / 3;
                let (x, y) = ((p % w) as f32, (p / w) as f32);
                (0.3 * x).sin() * 0.5 + 0.5 + 0.1 * (0.4 * y + (i % 3) as f32).cos()
            })
            .collect();
        let (valpha, vdepth) = (vec![0.0f32; n], vec![0.0f32; n]);
        let shift = [0.11, -0.07];
        let run = |a: &[f32], d: &[f32], v: &[f32]| {
            consistency(
                &cam,
                shift,
                (w, h),
                (a, d, &target),
                (v, &valpha, &vdepth),
                0.7,
            )
        };
        let base = run(&alpha, &depth, &vrgb);
        assert!(base.valid > 0.5 && base.loss > 0.0);
        let fd = |f: &dyn Fn(f32) -> f64, eps: f32| (f(eps) - f(-eps)) / (2.0 * eps as f64);
        let close = |fd: f64, an: f32, what: &str| {
            let an = an as f64;
            assert!(
                (fd - an).abs() <= 2e-2 * an.abs().max(1e-5),
                "{what}: fd {fd} an {an}"
            );
        };
        for p in [5 * w + 7, 9 * w + 12, 12 * w + 3] {
            let f = |e: f32| {
                let mut d = depth.clone();
                d[p] += e;
                run(&alpha, &d, &vrgb).loss
            };
            close(fd(&f, 1e-3), base.d_depth[p], "depth");
            let f = |e: f32| {
                let mut a = alpha.clone();
                a[p] += e;
                run(&a, &depth, &vrgb).loss
            };
            close(fd(&f, 1e-4), base.d_alpha[p], "alpha");
        }
        for i in [3 * (6 * w + 5), 3 * (10 * w + 14) + 1] {
            let f = |e: f32| {
                let mut v = vrgb.clone();
                v[i] += e;
                run(&alpha, &depth, &v).loss
            };
            close(fd(&f, 1e-4), base.d_virtual_rgb[i], "virtual rgb");
        }
    }

    /// From a quarter of the run on, every view of a default batch of 4 gets a pseudo
    /// view and a fifth would not; a weight of 0 turns the term off and a NaN one is
    /// refused.
    #[test]
    fn the_term_applies_from_its_start_to_every_view_of_a_default_batch() {
        let default = PseudoViewConfig::default();
        assert!(default.applies(10, 10, 0) && !default.applies(2, 10, 0));
        assert!(default.applies(10, 10, 3) && !default.applies(10, 10, 4));
        let off = PseudoViewConfig {
            weight: 0.0,
            ..default
        };
        assert!(!off.applies(10, 10, 0));
        let bad = PseudoViewConfig {
            weight: f64::NAN,
            ..default
        };
        assert!(bad.problem().is_some() && default.problem().is_none());
    }

    /// A pixel whose landing point is hidden behind a nearer surface of the virtual view,
    /// or lies in front of a farther one, takes no part; a see-through landing point
    /// (virtual alpha ≤ 0.5) does.
    #[test]
    fn landing_points_on_another_surface_take_no_part() {
        let (w, h) = (16usize, 12usize);
        let cam = camera(w as u32, h as u32);
        let n = w * h;
        let (alpha, depth) = (vec![1.0f32; n], vec![4.0f32; n]);
        let (target, vrgb) = (vec![0.2f32; 3 * n], vec![0.6f32; 3 * n]);
        let run_with = |va: f32, vd: f32| {
            let (va, vdep) = (vec![va; n], vec![va * vd; n]);
            consistency(
                &cam,
                [0.05, 0.0],
                (w, h),
                (&alpha, &depth, &target),
                (&vrgb, &va, &vdep),
                1.0,
            )
        };
        let run = |vd: f32| run_with(1.0, vd);
        let seen = run(4.0);
        assert!(seen.valid > 0.8 && (seen.loss - 0.4 * seen.valid).abs() < 1e-6);
        let hidden = run(2.0);
        assert_eq!((hidden.valid, hidden.loss), (0.0, 0.0));
        let behind = run(6.0);
        assert_eq!((behind.valid, behind.loss), (0.0, 0.0));
        assert!(run(4.0 / 0.96).valid > 0.8 && run(4.0 * 0.96).valid > 0.8);
        // Seen through: the surface the training camera sees is missing there.
        assert!(run_with(0.3, 6.0).valid > 0.8);
    }

    /// On a model: a textured wall seen as one surface is consistent from beside the
    /// camera; the same wall with its splats scattered in depth along the camera's rays
    /// (the same picture from the camera) is not, and the term says so.
    #[test]
    fn scattered_depths_cost_more_than_one_surface() {
        use crate::model::TimeMapping;
        use crate::model::init::{InitOptions, gaussians_from_points};
        use crate::render::{RenderBackend, RenderOptions};
        use crate::{ColourDegrees, CpuBackend};
        use shared_types::PointCloud;

        let (w, h) = (64u32, 48u32);
        let cam = camera(w, h);
        let (nx, ny, z) = (64, 48, 4.0f32);
        let wall = |scatter: f32| {
            let (mut xyz, mut rgb) = (Vec::new(), Vec::new());
            for j in 0..ny {
                for i in 0..nx {
                    let (u, v) = (
                        (i as f32 / nx as f32 - 0.5) * 2.6,
                        (j as f32 / ny as f32 - 0.5) * 1.9,
                    );
                    // Along the ray through (u, v, 1): same pixel, another depth.
                    let k = 1.0 + scatter * (((i * 7 + j * 13) % 11) as f32 / 5.0 - 1.0);
                    xyz.push([u * z * k, v * z * k, z * k]);
                    // A smooth texture: resampling it costs little, misplacing it much.
                    let wave = |phase: f32| {
                        (127.0 + 100.0 * (i as f32 * 0.45 + j as f32 * 0.2 + phase).sin()) as u8
                    };
                    let c = [wave(0.0), wave(2.1), wave(4.2)];
                    rgb.push(c);
                }
            }
            let n = xyz.len();
            let cloud = PointCloud {
                xyz,
                rgb,
                time: Some(vec![0.5; n]),
                time_span: Some(vec![1.0; n]),
            };
            let options = InitOptions {
                opacity: 0.95,
                time_scale_fraction: 0.2,
                capacity: ColourDegrees {
                    spatial: 0,
                    temporal: 0,
                },
                seed: 0,
                flatness: 0.0,
                velocity: false,
            };
            gaussians_from_points(
                &cloud,
                TimeMapping::frames_over_30(0.0, 30.0, 1.0),
                &options,
            )
            .unwrap()
        };
        let loss = |model: &Gaussians<f32>| {
            let options = RenderOptions::default();
            let r = CpuBackend.render(model, &cam, 0.5, &options).unwrap();
            let shift = [0.8, 0.2];
            let rv = CpuBackend
                .render(model, &shifted_camera(&cam, shift), 0.5, &options)
                .unwrap();
            let c = consistency(
                &cam,
                shift,
                (w as usize, h as usize),
                (&r.alpha, &r.depth, &r.rgb),
                (&rv.rgb, &rv.alpha, &rv.depth),
                1.0,
            );
            assert!(c.valid > 0.5, "valid {}", c.valid);
            c.loss / c.valid
        };
        let (surface, scattered) = (loss(&wall(0.0)), loss(&wall(0.4)));
        assert!(
            scattered > 2.0 * surface,
            "one surface {surface}, scattered {scattered}"
        );
    }
}
