//! The photometric training loss `(1 − λ)·L1 + λ·(1 − SSIM)` (λ = 0.2 by default) with its
//! gradient w.r.t. the rendered image, and PSNR. Images are interleaved RGB in `[0, 1]`.

use crate::math::numerics::Real;
use crate::metrics::ssim::ssim;

/// Value and parts of one image loss.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossValue {
    pub total: f64,
    pub l1: f64,
    pub ssim: f64,
    /// Mean squared error (for PSNR).
    pub mse: f64,
}

/// Loss of `rendered` against `target` (`width × height`, RGB) with SSIM weight
/// `lambda_ssim`; writes `d(total)/d(rendered)` into `grad` when given.
pub fn image_loss<F: Real>(
    rendered: &[F],
    target: &[F],
    width: usize,
    height: usize,
    lambda_ssim: f64,
    grad: Option<&mut [F]>,
) -> LossValue {
    let count = rendered.len().max(1) as f64;
    let mut l1 = 0.0;
    let mut se = 0.0;
    for (&r, &t) in rendered.iter().zip(target) {
        let d = (r - t).f64();
        l1 += d.abs();
        se += d * d;
    }
    l1 /= count;
    let mse = se / count;
    let s = if lambda_ssim != 0.0 {
        match grad {
            Some(g) => {
                let s = ssim(rendered, target, width, height, Some(g));
                let (wl, ws) = (F::c((1.0 - lambda_ssim) / count), F::c(-lambda_ssim));
                for ((gi, &r), &t) in g.iter_mut().zip(rendered).zip(target) {
                    *gi = *gi * ws + wl * sign(r - t);
                }
                s.f64()
            }
            None => ssim(rendered, target, width, height, None).f64(),
        }
    } else {
        if let Some(g) = grad {
            let wl = F::c(1.0 / count);
            for ((gi, &r), &t) in g.iter_mut().zip(rendered).zip(target) {
                *gi = wl * sign(r - t);
            }
        }
        1.0
    };
    LossValue {
        total: (1.0 - lambda_ssim) * l1 + lambda_ssim * (1.0 - s),
        l1,
        ssim: s,
        mse,
    }
}

fn sign<F: Real>(x: F) -> F {
    if x > F::zero() {
        F::one()
    } else if x < F::zero() {
        -F::one()
    } else {
        F::zero()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loss_gradient_matches_central_differences() {
        let (w, h) = (12, 10);
        let n = 3 * w * h;
        let a: Vec<f64> = (0..n).map(|i| ((i * 37 % 101) as f64) / 101.0).collect();
        let b: Vec<f64> = (0..n)
            .map(|i| ((i * 53 % 97) as f64) / 97.0 + 0.003)
            .collect();
        let mut g = vec![0.0; n];
        image_loss(&a, &b, w, h, 0.2, Some(&mut g));
        for i in (0..n).step_by(11) {
            let eps = 1e-7;
            let mut p = a.clone();
            p[i] += eps;
            let up = image_loss(&p, &b, w, h, 0.2, None).total;
            p[i] -= 2.0 * eps;
            let down = image_loss(&p, &b, w, h, 0.2, None).total;
            let fd = (up - down) / (2.0 * eps);
            assert!(
                (fd - g[i]).abs() < 1e-6 * fd.abs().max(1e-3),
                "i={i}: fd {fd} vs {}",
                g[i]
            );
        }
    }
}
