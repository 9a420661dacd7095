//! Adam over the parameter groups of a [`Gaussians`] model, the reference learning-rate
//! schedules (position rate × scene extent with exponential decay) and the colour-degree
//! schedule. Moments are stored per Gaussian, laid out like the model, so that
//! densification can gather, copy or zero them alongside the Gaussians (see `densify`).

use crate::model::{ColourDegrees, Gaussians};
use crate::render::Gradients;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Learning rates per parameter group (`capture.toml` `[train.lr]`), reference 4DGS values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearningRates {
    /// Position (xyz) rate at iteration 0, multiplied by the scene extent.
    pub position_init: f64,
    /// Position rate at `position_decay_steps`, multiplied by the scene extent.
    pub position_final: f64,
    /// Iterations over which the position rate decays exponentially (0: the run length).
    pub position_decay_steps: u64,
    /// Time-of-mean rate, multiplied by the scene extent (constant).
    pub time: f64,
    /// Colour DC coefficient rate.
    pub colour_dc: f64,
    /// Rate of every other colour coefficient.
    pub colour_rest: f64,
    pub opacity: f64,
    pub scale: f64,
    pub rotation: f64,
}

impl Default for LearningRates {
    fn default() -> Self {
        Self {
            position_init: 1.6e-4,
            position_final: 1.6e-6,
            position_decay_steps: 0,
            time: 1.6e-4,
            colour_dc: 2.5e-3,
            colour_rest: 1.25e-4,
            opacity: 0.05,
            scale: 5e-3,
            rotation: 1e-3,
        }
    }
}

impl LearningRates {
    /// The rates of every group at `iteration` (0-based) of a run of `total` iterations
    /// in a scene of radius `extent`.
    pub fn at(&self, iteration: u64, total: u64, extent: f64) -> GroupRates {
        let steps = if self.position_decay_steps > 0 {
            self.position_decay_steps
        } else {
            total.max(1)
        };
        let f = (iteration as f64 / steps as f64).clamp(0.0, 1.0);
        let (a, b) = (
            self.position_init.max(1e-30),
            self.position_final.max(1e-30),
        );
        let position = (a.ln() * (1.0 - f) + b.ln() * f).exp() * extent;
        GroupRates {
            position: position as f32,
            time: (self.time * extent) as f32,
            colour_dc: self.colour_dc as f32,
            colour_rest: self.colour_rest as f32,
            opacity: self.opacity as f32,
            scale: self.scale as f32,
            rotation: self.rotation as f32,
        }
    }

    /// Every rate is finite and non-negative.
    pub fn is_valid(&self) -> bool {
        [
            self.position_init,
            self.position_final,
            self.time,
            self.colour_dc,
            self.colour_rest,
            self.opacity,
            self.scale,
            self.rotation,
        ]
        .iter()
        .all(|v| v.is_finite() && *v >= 0.0)
    }
}

/// Learning rates of one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupRates {
    pub position: f32,
    pub time: f32,
    pub colour_dc: f32,
    pub colour_rest: f32,
    pub opacity: f32,
    pub scale: f32,
    pub rotation: f32,
}

/// Colour degrees active at `iteration` (0-based): the spatial degree grows by one every
/// `every` iterations up to `capacity.spatial`, then the temporal degree does.
pub fn colour_degrees_at(iteration: u64, every: u64, capacity: ColourDegrees) -> ColourDegrees {
    let steps = iteration.checked_div(every).unwrap_or(u64::MAX);
    let spatial = steps.min(capacity.spatial as u64) as u32;
    let temporal = steps
        .saturating_sub(capacity.spatial as u64)
        .min(capacity.temporal as u64) as u32;
    ColourDegrees { spatial, temporal }
}

/// Per-Gaussian buffers shaped like the trainable arrays of [`Gaussians`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParamBuffers {
    pub means: Vec<[f32; 4]>,
    pub log_scales: Vec<[f32; 4]>,
    pub rot_left: Vec<[f32; 4]>,
    pub rot_right: Vec<[f32; 4]>,
    pub opacity_logits: Vec<f32>,
    /// `3 × coeffs` values per Gaussian, like [`Gaussians::colours`].
    pub colours: Vec<f32>,
}

impl ParamBuffers {
    /// Zeros for `n` Gaussians with `colour_len` colour values each.
    pub fn zeros(n: usize, colour_len: usize) -> Self {
        Self {
            means: vec![[0.0; 4]; n],
            log_scales: vec![[0.0; 4]; n],
            rot_left: vec![[0.0; 4]; n],
            rot_right: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            colours: vec![0.0; n * colour_len],
        }
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Rebuild from `sources`: entry `j` of the result is row `sources[j]` of `self`, or
    /// zeros where it is `None` (a new Gaussian's fresh moments).
    pub fn gather(&self, sources: &[Option<usize>]) -> Self {
        let k = if self.is_empty() {
            0
        } else {
            self.colours.len() / self.len()
        };
        let mut out = Self::zeros(0, k);
        for s in sources {
            match *s {
                Some(i) => {
                    out.means.push(self.means[i]);
                    out.log_scales.push(self.log_scales[i]);
                    out.rot_left.push(self.rot_left[i]);
                    out.rot_right.push(self.rot_right[i]);
                    out.opacity_logits.push(self.opacity_logits[i]);
                    out.colours
                        .extend_from_slice(&self.colours[i * k..(i + 1) * k]);
                }
                None => {
                    out.means.push([0.0; 4]);
                    out.log_scales.push([0.0; 4]);
                    out.rot_left.push([0.0; 4]);
                    out.rot_right.push([0.0; 4]);
                    out.opacity_logits.push(0.0);
                    out.colours.resize(out.colours.len() + k, 0.0);
                }
            }
        }
        out
    }

    /// Every value, group by group (for checkpoints).
    pub fn values(&self) -> impl Iterator<Item = f32> + '_ {
        self.means
            .iter()
            .chain(&self.log_scales)
            .chain(&self.rot_left)
            .chain(&self.rot_right)
            .flatten()
            .chain(&self.opacity_logits)
            .chain(&self.colours)
            .copied()
    }

    /// Inverse of [`ParamBuffers::values`] for `n` Gaussians of `colour_len` values each.
    pub fn from_values(
        n: usize,
        colour_len: usize,
        mut v: impl Iterator<Item = f32>,
    ) -> Option<Self> {
        let mut out = Self::zeros(n, colour_len);
        for arr in [
            &mut out.means,
            &mut out.log_scales,
            &mut out.rot_left,
            &mut out.rot_right,
        ] {
            for x in arr.iter_mut().flatten() {
                *x = v.next()?;
            }
        }
        for x in out.opacity_logits.iter_mut().chain(out.colours.iter_mut()) {
            *x = v.next()?;
        }
        Some(out)
    }
}

/// Adam (β₁ 0.9, β₂ 0.999, ε 1e-15 as in 3DGS) with one shared step counter.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    /// Steps taken (for bias correction).
    pub step: u64,
    /// First moments.
    pub m: ParamBuffers,
    /// Second moments.
    pub v: ParamBuffers,
    /// The model's first `frozen` Gaussians are left as they are, and so are their moments
    /// (a static scene shared by several time chunks; densification keeps them too). Not
    /// saved in checkpoints: the trainer sets it from where training starts.
    pub frozen: usize,
}

pub const BETA1: f32 = 0.9;
pub const BETA2: f32 = 0.999;
pub const EPSILON: f32 = 1e-15;

#[inline]
fn update(
    p: &mut [f32],
    g: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    lr: impl Fn(usize) -> f32,
    bc1: f32,
    bc2: f32,
) {
    for i in 0..p.len() {
        let gi = g[i];
        m[i] = BETA1 * m[i] + (1.0 - BETA1) * gi;
        v[i] = BETA2 * v[i] + (1.0 - BETA2) * gi * gi;
        let mh = m[i] / bc1;
        let vh = v[i] / bc2;
        p[i] -= lr(i) * mh / (vh.sqrt() + EPSILON);
    }
}

impl Adam {
    /// Fresh state for `model`.
    pub fn new(model: &Gaussians<f32>) -> Self {
        let k = 3 * model.coeffs_per_channel();
        Self {
            step: 0,
            m: ParamBuffers::zeros(model.len(), k),
            v: ParamBuffers::zeros(model.len(), k),
            frozen: 0,
        }
    }

    /// One Adam step of every group of `model` with gradients `grads`.
    pub fn step(&mut self, model: &mut Gaussians<f32>, grads: &Gradients<f32>, rates: &GroupRates) {
        assert_eq!(
            self.m.len(),
            model.len(),
            "Adam state out of step with the model"
        );
        self.step += 1;
        let t = self.step as i32;
        let bc1 = 1.0 - BETA1.powi(t);
        let bc2 = 1.0 - BETA2.powi(t);
        let r = *rates;
        let (m, v) = (&mut self.m, &mut self.v);
        // Values of the frozen Gaussians: 4 per Gaussian in the vec4 groups, 1 for opacity.
        let f = self.frozen.min(model.len());
        rayon::join(
            || {
                let pos = |i: usize| if i % 4 == 3 { r.time } else { r.position };
                update(
                    &mut model.means.as_flattened_mut()[4 * f..],
                    &grads.means.as_flattened()[4 * f..],
                    &mut m.means.as_flattened_mut()[4 * f..],
                    &mut v.means.as_flattened_mut()[4 * f..],
                    pos,
                    bc1,
                    bc2,
                );
                let groups = [
                    (
                        &mut model.log_scales,
                        &grads.log_scales,
                        &mut m.log_scales,
                        &mut v.log_scales,
                        r.scale,
                    ),
                    (
                        &mut model.rot_left,
                        &grads.rot_left,
                        &mut m.rot_left,
                        &mut v.rot_left,
                        r.rotation,
                    ),
                    (
                        &mut model.rot_right,
                        &grads.rot_right,
                        &mut m.rot_right,
                        &mut v.rot_right,
                        r.rotation,
                    ),
                ];
                for (p, g, mm, vv, lr) in groups {
                    update(
                        &mut p.as_flattened_mut()[4 * f..],
                        &g.as_flattened()[4 * f..],
                        &mut mm.as_flattened_mut()[4 * f..],
                        &mut vv.as_flattened_mut()[4 * f..],
                        |_| lr,
                        bc1,
                        bc2,
                    );
                }
                update(
                    &mut model.opacity_logits[f..],
                    &grads.opacity_logits[f..],
                    &mut m.opacity_logits[f..],
                    &mut v.opacity_logits[f..],
                    |_| r.opacity,
                    bc1,
                    bc2,
                );
            },
            || {
                let k = 3 * model.capacity.coeff_count();
                if k == 0 {
                    return;
                }
                (
                    model.colours[k * f..].par_chunks_mut(k),
                    grads.colours[k * f..].par_chunks(k),
                    m.colours[k * f..].par_chunks_mut(k),
                    v.colours[k * f..].par_chunks_mut(k),
                )
                    .into_par_iter()
                    .with_min_len(1024)
                    .for_each(|(p, g, mm, vv)| {
                        update(
                            p,
                            g,
                            mm,
                            vv,
                            |i| if i < 3 { r.colour_dc } else { r.colour_rest },
                            bc1,
                            bc2,
                        )
                    });
            },
        );
    }

    /// Apply a densification edit: see [`ParamBuffers::gather`].
    pub fn gather(&mut self, sources: &[Option<usize>]) {
        self.m = self.m.gather(sources);
        self.v = self.v.gather(sources);
    }

    /// Zero the opacity moments (after an opacity reset).
    pub fn reset_opacity(&mut self) {
        self.m.opacity_logits.fill(0.0);
        self.v.opacity_logits.fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::TimeMapping;

    #[test]
    fn first_step_moves_each_parameter_by_its_rate() {
        let mut g = Gaussians::<f32>::new(ColourDegrees::DC, TimeMapping::default());
        g.push([0.0; 4], [0.0; 4], 0.0, [0.5; 3]);
        let mut grads = Gradients::zeros_like(&g, false);
        grads.means[0] = [1.0, -2.0, 0.0, 3.0];
        grads.opacity_logits[0] = -0.5;
        let mut adam = Adam::new(&g);
        let rates = LearningRates::default().at(0, 100, 2.0);
        adam.step(&mut g, &grads, &rates);
        assert!((g.means[0][0] + rates.position).abs() < 1e-9);
        assert!((g.means[0][1] - rates.position).abs() < 1e-9);
        assert_eq!(g.means[0][2], 0.0);
        assert!((g.means[0][3] + rates.time).abs() < 1e-9);
        assert!((g.opacity_logits[0] - rates.opacity).abs() < 1e-7);
    }

    #[test]
    fn position_rate_decays_exponentially() {
        let lr = LearningRates::default();
        assert!((lr.at(0, 100, 1.0).position as f64 - 1.6e-4).abs() < 1e-10);
        assert!((lr.at(50, 100, 1.0).position as f64 - 1.6e-5).abs() < 1e-10);
        assert!((lr.at(100, 100, 3.0).position as f64 - 4.8e-6).abs() < 1e-10);
    }

    #[test]
    fn degree_schedule_grows_spatial_then_temporal() {
        let cap = ColourDegrees::FULL;
        assert_eq!(colour_degrees_at(999, 1000, cap), ColourDegrees::DC);
        assert_eq!(
            colour_degrees_at(2000, 1000, cap),
            ColourDegrees {
                spatial: 2,
                temporal: 0
            }
        );
        assert_eq!(
            colour_degrees_at(4000, 1000, cap),
            ColourDegrees {
                spatial: 3,
                temporal: 1
            }
        );
        assert_eq!(colour_degrees_at(99_000, 1000, cap), cap);
    }
}
