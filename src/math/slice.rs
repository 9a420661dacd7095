//! Slicing a 4D Gaussian at time `t`: conditional 3D mean and
//! covariance, temporal weight `ω(t)`, forward and backward.
//!
//! The covariance is kept in factored form: with `L = R·diag(exp(s))` (rows 0..3 = `A`,
//! row 3 = `l`), `Σ = L Lᵀ`, `Σ44 = l·l`, `Σ12 = A l` and
//! `Σ3|t = Σ11 − Σ12 Σ12ᵀ / Σ44 = B Bᵀ` with `B = A − (A l) lᵀ / Σ44`.
//! Working with `B` keeps the sliced covariance positive semi-definite in `f32`, even for
//! nearly singular or badly scaled Gaussians.

use crate::math::numerics::{MIN_TIME_VARIANCE, Real, scale_from_log};
use crate::math::rotation4d::{Mat4, RotationAux, rotation, rotation_backward};

/// Gaussians whose temporal weight is at or below this are culled.
pub const TEMPORAL_CUTOFF: f64 = 0.05;

/// A 4D Gaussian sliced at time t.
#[derive(Clone, Copy, Debug)]
pub struct Slice<F> {
    /// Temporal weight `ω(t) = exp(−½ (t−μt)² / Σ44)`.
    pub omega: F,
    /// Conditional mean `μ(t)`.
    pub mean: [F; 3],
    /// Factor `B` (3×4) of the conditional covariance `Σ3|t = B Bᵀ`.
    pub factor: [[F; 4]; 3],
}

/// Forward intermediates needed by [`slice_backward`].
#[derive(Clone, Copy, Debug)]
pub struct SliceAux<F> {
    rot: RotationAux<F>,
    r: Mat4<F>,
    scale: [F; 4],
    scale_ok: [bool; 4],
    l: Mat4<F>,
    s44: F,
    s44_ok: bool,
    v: [F; 3],
    dt: F,
}

/// Gradients of a slice's inputs.
#[derive(Clone, Copy, Debug, Default)]
pub struct SliceGrad<F> {
    pub mean: [F; 4],
    pub log_scales: [F; 4],
    pub rot_left: [F; 4],
    pub rot_right: [F; 4],
}

/// Slice a Gaussian at `t`; `None` when it is culled (`ω ≤ 0.05`).
#[inline]
pub fn slice<F: Real>(
    mean: [F; 4],
    log_scales: [F; 4],
    ql: [F; 4],
    qr: [F; 4],
    t: F,
) -> Option<(Slice<F>, SliceAux<F>)> {
    let (r, rot) = rotation(ql, qr);
    let mut scale = [F::zero(); 4];
    let mut scale_ok = [false; 4];
    for k in 0..4 {
        (scale[k], scale_ok[k]) = scale_from_log(log_scales[k]);
    }
    let mut l = [[F::zero(); 4]; 4];
    for i in 0..4 {
        for k in 0..4 {
            l[i][k] = r[i][k] * scale[k];
        }
    }
    let lt = l[3];
    let raw44 = lt[0] * lt[0] + lt[1] * lt[1] + lt[2] * lt[2] + lt[3] * lt[3];
    let min44 = F::c(MIN_TIME_VARIANCE);
    let (s44, s44_ok) = if raw44 > min44 {
        (raw44, true)
    } else {
        (min44, false)
    };
    let dt = t - mean[3];
    let omega = (-F::c(0.5) * dt * dt / s44).exp();
    if !(omega > F::c(TEMPORAL_CUTOFF)) {
        return None;
    }
    let mut v = [F::zero(); 3];
    for i in 0..3 {
        v[i] = l[i][0] * lt[0] + l[i][1] * lt[1] + l[i][2] * lt[2] + l[i][3] * lt[3];
    }
    let shift = dt / s44;
    let inv44 = F::one() / s44;
    let mut m3 = [F::zero(); 3];
    let mut b = [[F::zero(); 4]; 3];
    for i in 0..3 {
        m3[i] = mean[i] + v[i] * shift;
        for k in 0..4 {
            b[i][k] = l[i][k] - v[i] * lt[k] * inv44;
        }
    }
    Some((
        Slice {
            omega,
            mean: m3,
            factor: b,
        },
        SliceAux {
            rot,
            r,
            scale,
            scale_ok,
            l,
            s44,
            s44_ok,
            v,
            dt,
        },
    ))
}

/// Backward of [`slice()`]: from dL/dω, dL/dμ(t), dL/dB to the Gaussian's parameters.
pub fn slice_backward<F: Real>(
    out: &Slice<F>,
    aux: &SliceAux<F>,
    d_omega: F,
    d_mean: [F; 3],
    d_factor: &[[F; 4]; 3],
) -> SliceGrad<F> {
    let half = F::c(0.5);
    let (s44, dt, v, l) = (aux.s44, aux.dt, aux.v, &aux.l);
    let lt = l[3];
    let inv44 = F::one() / s44;
    let mut d_l = [[F::zero(); 4]; 4];
    let mut d_v = [F::zero(); 3];
    let mut d_s44 = F::zero();
    let mut d_dt = F::zero();
    let mut grad = SliceGrad::default();

    // B = A − v lᵀ / s44
    for i in 0..3 {
        for k in 0..4 {
            let g = d_factor[i][k];
            d_l[i][k] += g;
            d_v[i] -= g * lt[k] * inv44;
            d_l[3][k] -= g * v[i] * inv44;
            d_s44 += g * v[i] * lt[k] * inv44 * inv44;
        }
    }
    // μ(t) = μ + v · dt / s44
    let mut dmv = F::zero();
    for i in 0..3 {
        grad.mean[i] = d_mean[i];
        d_v[i] += d_mean[i] * dt * inv44;
        dmv += d_mean[i] * v[i];
    }
    d_dt += dmv * inv44;
    d_s44 -= dmv * dt * inv44 * inv44;
    // ω = exp(−½ dt² / s44)
    let w = out.omega;
    d_dt -= d_omega * w * dt * inv44;
    d_s44 += d_omega * w * half * dt * dt * inv44 * inv44;
    // v = A l
    for i in 0..3 {
        for k in 0..4 {
            d_l[i][k] += d_v[i] * lt[k];
            d_l[3][k] += d_v[i] * l[i][k];
        }
    }
    // s44 = l·l
    if aux.s44_ok {
        for k in 0..4 {
            d_l[3][k] += F::c(2.0) * d_s44 * lt[k];
        }
    }
    // dt = t − μt
    grad.mean[3] = -d_dt;
    // L = R diag(scale)
    let mut d_r = [[F::zero(); 4]; 4];
    for i in 0..4 {
        for k in 0..4 {
            d_r[i][k] = d_l[i][k] * aux.scale[k];
        }
    }
    for k in 0..4 {
        if aux.scale_ok[k] {
            let mut ds = F::zero();
            for i in 0..4 {
                ds += d_l[i][k] * aux.r[i][k];
            }
            grad.log_scales[k] = ds * aux.scale[k];
        }
    }
    (grad.rot_left, grad.rot_right) = rotation_backward(&aux.rot, &d_r);
    grad
}
