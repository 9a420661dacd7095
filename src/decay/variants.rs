//! The per-step decay factors of each variant and their application to a stored opacity.
//!
//! Every factor `d` lies in `(0, 1]` and multiplies the stored opacity in probability
//! space: `o ← o·d`, written back as a logit. The hand-tuned variants (paper Tab. 3) are
//! functions of the current opacity `o`, bounded to the neural range `[f_min, f_max]`:
//! - `pow`: `d(o) = f_min + (f_max − f_min)·o^γ` (γ = `pow_gamma`, default 0.5);
//! - `exp`: `d(o) = f_max − (f_max − f_min)·exp(−o/κ)` (κ = `exp_kappa`, default 0.1).
//!
//! Both decay nearly transparent Gaussians fastest (towards pruning) and leave opaque
//! surfaces almost alone; `pow` is a gentle ramp over the whole range, `exp` saturates
//! once `o ≳ 3κ`.

use super::DecayConfig;
use crate::math::numerics::sigmoid;

/// The decay never pushes a logit below this (`o ≈ 9e-14`), keeping it finite.
pub const LOGIT_FLOOR: f64 = -30.0;

/// `pow` decay factor at opacity `o`.
pub fn pow_factor(o: f64, config: &DecayConfig) -> f64 {
    config.f_min + (config.f_max - config.f_min) * o.clamp(0.0, 1.0).powf(config.pow_gamma)
}

/// `exp` decay factor at opacity `o`.
pub fn exp_factor(o: f64, config: &DecayConfig) -> f64 {
    config.f_max - (config.f_max - config.f_min) * (-o.clamp(0.0, 1.0) / config.exp_kappa).exp()
}

/// The logit of `sigmoid(logit)·factor`, computed in `f64`; never larger than `logit`,
/// never below [`LOGIT_FLOOR`] (unless `logit` already was), so the opacity stays finite
/// and in (0, 1). Non-finite logits are returned unchanged (the trainer's NaN guard
/// reports them).
pub fn decayed_logit(logit: f32, factor: f64) -> f32 {
    if !logit.is_finite() || !(factor < 1.0) {
        return logit;
    }
    let x = logit as f64;
    let q = sigmoid(x) * factor.max(0.0);
    let y = if q > 0.0 {
        q.ln() - (-q).ln_1p()
    } else {
        LOGIT_FLOOR
    };
    let y = y.max(LOGIT_FLOOR.min(x)).min(x);
    (y as f32).min(logit)
}
