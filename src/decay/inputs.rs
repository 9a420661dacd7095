//! The per-Gaussian input rows of f_θ. Two layouts (`DecayInputs`):
//! - `paper` (§3.2): `(x, y, z, 2·o − 1, ql, qr)` — 12 values, both unit quaternions;
//! - `official` (the authors' code): `(2·o − 1, x, y, z, t, sx, sy, sz, st)` — 9 values.
//!
//! `o = sigmoid(opacity logit)`; positions (and time, log-scales) are z-scored over the
//! current Gaussians, so the inputs are scale-free. The statistics are treated as
//! constants (no gradient flows back through them or into the Gaussians: f_θ's inputs
//! are detached, see docs/decay.md).

use super::DecayInputs;
use crate::math::numerics::{Real, normalise_quat, sigmoid};
use crate::model::Gaussians;

/// Smallest standard deviation used by the z-scoring (constant columns map to 0).
const MIN_STD: f64 = 1e-6;

impl DecayInputs {
    /// Values per Gaussian.
    pub fn width(self) -> usize {
        match self {
            DecayInputs::Paper => 12,
            DecayInputs::Official => 9,
        }
    }
}

/// Mean and standard deviation of each column `k` of `rows` (computed in f64).
fn column_stats<F: Real>(
    n: usize,
    value: impl Fn(usize, usize) -> F,
    cols: usize,
) -> Vec<(f64, f64)> {
    (0..cols)
        .map(|k| {
            if n == 0 {
                return (0.0, 1.0);
            }
            let mean = (0..n).map(|i| value(i, k).f64()).sum::<f64>() / n as f64;
            let var = (0..n)
                .map(|i| (value(i, k).f64() - mean).powi(2))
                .sum::<f64>()
                / n as f64;
            (mean, var.sqrt().max(MIN_STD))
        })
        .collect()
}

/// The input matrix (`len × width`, row-major) of every Gaussian of `model`.
pub fn input_rows<F: Real>(model: &Gaussians<F>, inputs: DecayInputs) -> Vec<F> {
    let n = model.len();
    let width = inputs.width();
    let mut out = Vec::with_capacity(n * width);
    let opacity = |i: usize| F::c(2.0) * sigmoid(model.opacity_logits[i]) - F::one();
    let z = |x: F, (m, s): (f64, f64)| F::c((x.f64() - m) / s);
    match inputs {
        DecayInputs::Paper => {
            let pos = column_stats(n, |i, k| model.means[i][k], 3);
            for i in 0..n {
                for k in 0..3 {
                    out.push(z(model.means[i][k], pos[k]));
                }
                out.push(opacity(i));
                out.extend_from_slice(&normalise_quat(model.rot_left[i]).0);
                out.extend_from_slice(&normalise_quat(model.rot_right[i]).0);
            }
        }
        DecayInputs::Official => {
            let pos = column_stats(n, |i, k| model.means[i][k], 4);
            let sc = column_stats(n, |i, k| model.log_scales[i][k], 4);
            for i in 0..n {
                out.push(opacity(i));
                for k in 0..4 {
                    out.push(z(model.means[i][k], pos[k]));
                }
                for k in 0..4 {
                    out.push(z(model.log_scales[i][k], sc[k]));
                }
            }
        }
    }
    out
}
