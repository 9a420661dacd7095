//! Scalar type and the guarded numerics of the renderer: stable sigmoid, safe quaternion
//! normalisation, log-scale clamping. Every clamp and guard of the engine lives here, so
//! the stages never invent their own epsilons.

use std::fmt::Debug;
use std::ops::{AddAssign, MulAssign, SubAssign};

/// The float type the renderer runs in: `f32` on the hot path, `f64` in checks.
pub trait Real:
    num_traits::Float
    + num_traits::FloatConst
    + Copy
    + Send
    + Sync
    + Default
    + Debug
    + AddAssign
    + SubAssign
    + MulAssign
    + 'static
{
    /// A constant given in `f64`.
    fn c(x: f64) -> Self;
    /// The value as `f64`.
    fn f64(self) -> f64;
    /// `exp` for the blending hot loop: exact (`std`) in `f64`; in `f32` an inlined
    /// polynomial with relative error below 4e-7 (about 2 ulp) that lets the compiler keep
    /// the loop free of libm calls.
    fn exp_fast(self) -> Self;
}

impl Real for f32 {
    #[inline(always)]
    fn c(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn exp_fast(self) -> Self {
        exp_f32(self)
    }
}

impl Real for f64 {
    #[inline(always)]
    fn c(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn exp_fast(self) -> Self {
        self.exp()
    }
}

/// `e^x` in `f32`: Cody–Waite range reduction and a degree-6 Taylor polynomial; inputs are
/// clamped to [−87, 88] (no denormals, no overflow). Branch- and cast-free, so loops over
/// it vectorise.
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    const ROUND: f32 = 12_582_912.0; // 1.5·2^23: adding it rounds to an integer
    const BIAS: f32 = 8_388_608.0 + 127.0; // 2^23 + 127: puts n + 127 in the low mantissa bits
    let x = if x < -87.0 { -87.0 } else { x };
    let x = if x > 88.0 { 88.0 } else { x };
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    // 2^n: move the integer n + 127 (1..=215) from the mantissa into the exponent field.
    let scale = f32::from_bits((n + BIAS).to_bits() << 23);
    p * scale
}

/// `⌈x⌉` as an `i64` without a libm call (saturating for huge or NaN inputs).
#[inline(always)]
pub fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x { t + 1 } else { t }
}

/// `⌊x⌋` as an `i64` without a libm call (saturating for huge or NaN inputs).
#[inline(always)]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t - 1 } else { t }
}

/// Log-scales are clamped to this range before `exp` (scales ~1.5e-8 … 1.6e5), so that
/// squared scales stay inside `f32` range; the gradient is zero outside it.
pub const LOG_SCALE_MIN: f64 = -18.0;
pub const LOG_SCALE_MAX: f64 = 12.0;
/// Smallest temporal variance `Σ44` used in divisions.
pub const MIN_TIME_VARIANCE: f64 = 1e-30;
/// Quaternions with a norm below this are treated as the identity rotation.
pub const MIN_QUAT_NORM: f64 = 1e-12;

/// `1 / (1 + e^-x)` without overflow for large |x|.
#[inline]
pub fn sigmoid<F: Real>(x: F) -> F {
    if x >= F::zero() {
        F::one() / (F::one() + (-x).exp())
    } else {
        let e = x.exp();
        e / (F::one() + e)
    }
}

/// Inverse of [`sigmoid`] for `p` in (0, 1); clamps `p` away from 0 and 1.
pub fn logit(p: f64) -> f64 {
    let p = p.clamp(1e-12, 1.0 - 1e-12);
    (p / (1.0 - p)).ln()
}

/// `exp` of a clamped log-scale, and whether the clamp was inactive (gradient passes).
#[inline]
pub fn scale_from_log<F: Real>(log_scale: F) -> (F, bool) {
    let lo = F::c(LOG_SCALE_MIN);
    let hi = F::c(LOG_SCALE_MAX);
    if log_scale.is_nan() {
        return (F::one(), false);
    }
    if log_scale < lo {
        (lo.exp(), false)
    } else if log_scale > hi {
        (hi.exp(), false)
    } else {
        (log_scale.exp(), true)
    }
}

/// Unit quaternion `q/|q|` and `|q|`; a (near) zero or non-finite quaternion becomes
/// the identity `(1,0,0,0)` with norm 0 (its gradient is then zero).
#[inline]
pub fn normalise_quat<F: Real>(q: [F; 4]) -> ([F; 4], F) {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n > F::c(MIN_QUAT_NORM)) || !n.is_finite() {
        return ([F::one(), F::zero(), F::zero(), F::zero()], F::zero());
    }
    let inv = F::one() / n;
    ([q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv], n)
}

/// Backward of [`normalise_quat`]: from dL/d(unit) to dL/dq.
#[inline]
pub fn normalise_quat_backward<F: Real>(unit: [F; 4], norm: F, d_unit: [F; 4]) -> [F; 4] {
    if norm == F::zero() {
        return [F::zero(); 4];
    }
    let dot = unit[0] * d_unit[0] + unit[1] * d_unit[1] + unit[2] * d_unit[2] + unit[3] * d_unit[3];
    let inv = F::one() / norm;
    [
        (d_unit[0] - unit[0] * dot) * inv,
        (d_unit[1] - unit[1] * dot) * inv,
        (d_unit[2] - unit[2] * dot) * inv,
        (d_unit[3] - unit[3] * dot) * inv,
    ]
}

/// Unit 3-vector and the length; a zero vector becomes +z with length 0.
#[inline]
pub fn normalise3<F: Real>(v: [F; 3]) -> ([F; 3], F) {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(n > F::c(1e-20)) {
        return ([F::zero(), F::zero(), F::one()], F::zero());
    }
    let inv = F::one() / n;
    ([v[0] * inv, v[1] * inv, v[2] * inv], n)
}

/// Backward of [`normalise3`].
#[inline]
pub fn normalise3_backward<F: Real>(unit: [F; 3], norm: F, d_unit: [F; 3]) -> [F; 3] {
    if norm == F::zero() {
        return [F::zero(); 3];
    }
    let dot = unit[0] * d_unit[0] + unit[1] * d_unit[1] + unit[2] * d_unit[2];
    let inv = F::one() / norm;
    [
        (d_unit[0] - unit[0] * dot) * inv,
        (d_unit[1] - unit[1] * dot) * inv,
        (d_unit[2] - unit[2] * dot) * inv,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigmoid_is_stable_at_extremes() {
        assert_eq!(sigmoid(1000.0f32), 1.0);
        assert_eq!(sigmoid(-1000.0f32), 0.0);
        assert!((sigmoid(0.3f64) - 1.0 / (1.0 + (-0.3f64).exp())).abs() < 1e-15);
        assert!((sigmoid(logit(0.25)) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn fast_exp_is_accurate() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -87.0 + 175.0 * i as f64 / 200_000.0;
            let got = exp_f32(x as f32) as f64;
            let want = (x as f32 as f64).exp();
            worst = worst.max(((got - want) / want).abs());
        }
        assert!(worst < 4e-7, "worst relative error {worst:e}");
        assert_eq!(exp_f32(0.0), 1.0);
    }

    #[test]
    fn quaternion_normalisation_gradient_matches_finite_differences() {
        let q = [0.3, -1.2, 0.7, 0.1f64];
        let w = [0.5, 0.2, -0.9, 1.3];
        let f = |q: [f64; 4]| {
            let (u, _) = normalise_quat(q);
            (0..4).map(|i| u[i] * w[i]).sum::<f64>()
        };
        let (u, n) = normalise_quat(q);
        let g = normalise_quat_backward(u, n, w);
        for i in 0..4 {
            let h = 1e-6;
            let (mut a, mut b) = (q, q);
            a[i] += h;
            b[i] -= h;
            let fd = (f(a) - f(b)) / (2.0 * h);
            assert!((fd - g[i]).abs() < 1e-8, "{i}: {fd} vs {}", g[i]);
        }
        assert_eq!(normalise_quat([0.0f32; 4]).0, [1.0, 0.0, 0.0, 0.0]);
    }
}
