//! Structural similarity (SSIM) with an 11×11 Gaussian window (σ 1.5, data range 1) and
//! its exact backward pass. Images are interleaved RGB, row-major; every channel is
//! filtered separably with zero padding ("same" size), as in the 3DGS reference loss.
//! No IO, no loss weighting here (see `loss`).

use crate::math::numerics::Real;
use rayon::prelude::*;

/// Window half-width: the window is `2·RADIUS + 1 = 11` pixels wide.
pub const RADIUS: usize = 5;
/// Standard deviation of the Gaussian window in pixels.
pub const SIGMA: f64 = 1.5;
/// Stabilisers for data range 1: `(0.01)²` and `(0.03)²`.
pub const C1: f64 = 0.01 * 0.01;
pub const C2: f64 = 0.03 * 0.03;

fn window<F: Real>() -> [F; 2 * RADIUS + 1] {
    let mut w = [0.0f64; 2 * RADIUS + 1];
    for (k, v) in w.iter_mut().enumerate() {
        let d = k as f64 - RADIUS as f64;
        *v = (-d * d / (2.0 * SIGMA * SIGMA)).exp();
    }
    let s: f64 = w.iter().sum();
    w.map(|v| F::c(v / s))
}

/// Separable, zero-padded Gaussian filter of one plane (`w × h`). The operator is
/// symmetric, so it is also its own adjoint (used by the backward pass). Both passes are
/// sums of shifted rows (`axpy`), which the compiler vectorises; taps are added in the
/// same order as the direct 11-tap sum, so the result does not depend on the layout.
fn blur<F: Real>(src: &[F], w: usize, h: usize, tmp: &mut Vec<F>, out: &mut Vec<F>) {
    let g = window::<F>();
    tmp.clear();
    tmp.resize(w * h, F::zero());
    out.clear();
    out.resize(w * h, F::zero());
    if w == 0 || h == 0 {
        return;
    }
    // Horizontal: tap k reads x + k − RADIUS, inside the row only (zero padding).
    for (row, t) in src.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        for (k, &gk) in g.iter().enumerate() {
            let (to, from) = if k < RADIUS {
                (RADIUS - k, 0)
            } else {
                (0, k - RADIUS)
            };
            let len = w.saturating_sub(to + from);
            if len == 0 {
                continue;
            }
            axpy(gk, &row[from..from + len], &mut t[to..to + len]);
        }
    }
    // Vertical: output row y adds rows y + k − RADIUS of the horizontal pass.
    for (y, o) in out.chunks_exact_mut(w).enumerate() {
        for (k, &gk) in g.iter().enumerate() {
            let Some(yy) = (y + k).checked_sub(RADIUS).filter(|&yy| yy < h) else {
                continue;
            };
            axpy(gk, &tmp[yy * w..(yy + 1) * w], o);
        }
    }
}

/// `y += a·x` over two slices of equal length.
#[inline(always)]
fn axpy<F: Real>(a: F, x: &[F], y: &mut [F]) {
    for (yi, &xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// Local Gaussian-weighted moments of channel `c` of `a` and `b`: the blurred planes of
/// x, y, x², y² and xy.
fn channel_moments<F: Real>(
    a: &[F],
    b: &[F],
    c: usize,
    width: usize,
    height: usize,
) -> [Vec<F>; 5] {
    let n = width * height;
    let mut planes: [Vec<F>; 5] = Default::default();
    let mut mu: [Vec<F>; 5] = Default::default();
    for i in 0..n {
        let (x, y) = (a[3 * i + c], b[3 * i + c]);
        planes[0].push(x);
        planes[1].push(y);
        planes[2].push(x * x);
        planes[3].push(y * y);
        planes[4].push(x * y);
    }
    planes
        .par_iter()
        .zip(mu.par_iter_mut())
        .for_each(|(plane, m)| blur(plane, width, height, &mut Vec::new(), m));
    mu
}

/// SSIM of pixel `i` from its local moments `mu`, with the terms of its gradient.
struct PixelSsim<F> {
    s: F,
    mx: F,
    my: F,
    a1: F,
    a2: F,
    b1: F,
    b2: F,
}

fn pixel_ssim<F: Real>(mu: &[Vec<F>; 5], i: usize) -> PixelSsim<F> {
    let (c1, c2) = (F::c(C1), F::c(C2));
    let two = F::c(2.0);
    let (mx, my) = (mu[0][i], mu[1][i]);
    let sxx = mu[2][i] - mx * mx;
    let syy = mu[3][i] - my * my;
    let sxy = mu[4][i] - mx * my;
    let a1 = two * mx * my + c1;
    let a2 = two * sxy + c2;
    let b1 = mx * mx + my * my + c1;
    let b2 = sxx + syy + c2;
    PixelSsim {
        s: a1 * a2 / (b1 * b2),
        mx,
        my,
        a1,
        a2,
        b1,
        b2,
    }
}

/// Mean SSIM of `a` against `b` (interleaved RGB, `width × height`) and, when `grad` is
/// given, `d(mean SSIM)/d(a)` written into it (same layout as `a`).
pub fn ssim<F: Real>(
    a: &[F],
    b: &[F],
    width: usize,
    height: usize,
    mut grad: Option<&mut [F]>,
) -> F {
    let n = width * height;
    assert_eq!(a.len(), 3 * n, "ssim: image a has the wrong size");
    assert_eq!(b.len(), 3 * n, "ssim: image b has the wrong size");
    if n == 0 {
        return F::one();
    }
    let two = F::c(2.0);
    let inv_count = F::c(1.0 / (3 * n) as f64);
    let want_grad = grad.is_some();
    // One channel: (Σ S, d(mean SSIM)/d(a) of this channel when wanted).
    let channel = |c: usize| -> (F, Vec<F>) {
        let mu = channel_moments(a, b, c, width, height);
        // Per-pixel partials of S w.r.t. mu_x, E[x²] and E[xy] (times 1/count).
        let (mut d_mx, mut d_exx, mut d_exy) = (Vec::new(), Vec::new(), Vec::new());
        if want_grad {
            d_mx.resize(n, F::zero());
            d_exx.resize(n, F::zero());
            d_exy.resize(n, F::zero());
        }
        let mut total = F::zero();
        for i in 0..n {
            let PixelSsim {
                s,
                mx,
                my,
                a1,
                a2,
                b1,
                b2,
            } = pixel_ssim(&mu, i);
            total += s;
            if want_grad {
                let ds_dmx = two * my * a2 / (b1 * b2) - s * two * mx / b1;
                let ds_dsxx = -s / b2;
                let ds_dsxy = two * a1 / (b1 * b2);
                // sxx = E[x²] − mx², sxy = E[xy] − mx·my.
                d_mx[i] = (ds_dmx - two * mx * ds_dsxx - my * ds_dsxy) * inv_count;
                d_exx[i] = ds_dsxx * inv_count;
                d_exy[i] = ds_dsxy * inv_count;
            }
        }
        let mut g = Vec::new();
        if want_grad {
            // The blur is self-adjoint: back-propagate through it with the same filter.
            let mut back: [Vec<F>; 3] = Default::default();
            [&d_mx, &d_exx, &d_exy]
                .par_iter()
                .zip(back.par_iter_mut())
                .for_each(|(d, b)| blur(d, width, height, &mut Vec::new(), b));
            let [bm, bxx, bxy] = back;
            g = (0..n)
                .map(|i| bm[i] + two * a[3 * i + c] * bxx[i] + b[3 * i + c] * bxy[i])
                .collect();
        }
        (total, g)
    };
    let per_channel: Vec<(F, Vec<F>)> = (0..3).into_par_iter().map(channel).collect();
    let mut total = F::zero();
    for (c, (sum, g_c)) in per_channel.into_iter().enumerate() {
        total += sum;
        if let Some(g) = grad.as_deref_mut() {
            for (i, v) in g_c.into_iter().enumerate() {
                g[3 * i + c] = v;
            }
        }
    }
    total * inv_count
}

/// The SSIM map of `a` against `b`: the SSIM of every pixel and channel, interleaved RGB
/// like the images (its mean is [`ssim`]).
pub fn ssim_map<F: Real>(a: &[F], b: &[F], width: usize, height: usize) -> Vec<F> {
    let n = width * height;
    assert_eq!(a.len(), 3 * n, "ssim_map: image a has the wrong size");
    assert_eq!(b.len(), 3 * n, "ssim_map: image b has the wrong size");
    let per_channel: Vec<Vec<F>> = (0..3)
        .into_par_iter()
        .map(|c| {
            let mu = channel_moments(a, b, c, width, height);
            (0..n).map(|i| pixel_ssim(&mu, i).s).collect()
        })
        .collect();
    (0..3 * n).map(|k| per_channel[k % 3][k / 3]).collect()
}

/// Mean of the SSIM map over the pixels where `mask` (one flag per pixel, row-major) is
/// set, all three channels; `None` when no pixel is set. A full mask gives [`ssim`].
pub fn masked_ssim<F: Real>(
    a: &[F],
    b: &[F],
    width: usize,
    height: usize,
    mask: &[bool],
) -> Option<f64> {
    assert_eq!(
        mask.len(),
        width * height,
        "masked_ssim: the mask has the wrong size"
    );
    let inside = mask.iter().filter(|&&m| m).count();
    if inside == 0 {
        return None;
    }
    let map = ssim_map(a, b, width, height);
    let sum: f64 = map
        .chunks_exact(3)
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|(px, _)| px.iter().map(|v| v.f64()).sum::<f64>())
        .sum();
    Some(sum / (3 * inside) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(seed: u64, n: usize) -> Vec<f64> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64
            })
            .collect()
    }

    /// SSIM of pixel (x, y), channel c, straight from the definition in f64: a 2D
    /// Gaussian window (σ 1.5, 11×11, normalised 1D weights multiplied), zero outside.
    fn reference_pixel(
        a: &[f64],
        b: &[f64],
        w: usize,
        h: usize,
        x: usize,
        y: usize,
        c: usize,
    ) -> f64 {
        let g: Vec<f64> = (0..=2 * RADIUS)
            .map(|k| (-((k as f64 - RADIUS as f64).powi(2)) / (2.0 * SIGMA * SIGMA)).exp())
            .collect();
        let total: f64 = g.iter().sum();
        let [mut mx, mut my, mut exx, mut eyy, mut exy] = [0.0f64; 5];
        for (j, gy) in g.iter().enumerate() {
            for (i, gx) in g.iter().enumerate() {
                let (xx, yy) = (
                    x as i64 + i as i64 - RADIUS as i64,
                    y as i64 + j as i64 - RADIUS as i64,
                );
                if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                    continue;
                }
                let k = 3 * (yy as usize * w + xx as usize) + c;
                let wgt = gx * gy / (total * total);
                mx += wgt * a[k];
                my += wgt * b[k];
                exx += wgt * a[k] * a[k];
                eyy += wgt * b[k] * b[k];
                exy += wgt * a[k] * b[k];
            }
        }
        let (sxx, syy, sxy) = (exx - mx * mx, eyy - my * my, exy - mx * my);
        (2.0 * mx * my + C1) * (2.0 * sxy + C2) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
    }

    #[test]
    fn masked_ssim_is_the_mean_of_the_reference_map_inside_the_mask() {
        let (w, h) = (13, 9);
        let a = noise(4, 3 * w * h);
        let b: Vec<f64> = a
            .iter()
            .zip(noise(5, 3 * w * h))
            .map(|(x, n)| 0.7 * x + 0.3 * n)
            .collect();
        // A blob in the middle and a stray pixel at the border.
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                (3..8).contains(&x) && (2..6).contains(&y) || (x, y) == (12, 0)
            })
            .collect();
        let (mut sum, mut count) = (0.0, 0);
        for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            for c in 0..3 {
                sum += reference_pixel(&a, &b, w, h, i % w, i / w, c);
                count += 1;
            }
        }
        let got = masked_ssim(&a, &b, w, h, &mask).unwrap();
        assert!(
            (got - sum / count as f64).abs() < 1e-12,
            "{got} vs {}",
            sum / count as f64
        );
        // The map matches the reference everywhere.
        let map = ssim_map(&a, &b, w, h);
        for (k, v) in map.iter().enumerate() {
            let r = reference_pixel(&a, &b, w, h, (k / 3) % w, k / 3 / w, k % 3);
            assert!((v - r).abs() < 1e-12, "pixel {k}: {v} vs {r}");
        }
    }

    #[test]
    fn a_full_mask_gives_ssim_and_an_empty_one_none() {
        let (w, h) = (17, 11);
        let a = noise(6, 3 * w * h);
        let b = noise(7, 3 * w * h);
        let full = masked_ssim(&a, &b, w, h, &vec![true; w * h]).unwrap();
        assert!((full - ssim(&a, &b, w, h, None)).abs() < 1e-12);
        let a32: Vec<f32> = a.iter().map(|&v| v as f32).collect();
        let b32: Vec<f32> = b.iter().map(|&v| v as f32).collect();
        let full32 = masked_ssim(&a32, &b32, w, h, &vec![true; w * h]).unwrap();
        assert!((full32 - ssim(&a32, &b32, w, h, None) as f64).abs() < 1e-5);
        assert_eq!(masked_ssim(&a, &b, w, h, &vec![false; w * h]), None);
    }

    #[test]
    fn images_narrower_than_the_window_match_the_reference() {
        for (w, h) in [(1, 1), (3, 2), (2, 7), (4, 4), (6, 1)] {
            let a = noise(8, 3 * w * h);
            let b = noise(9, 3 * w * h);
            let map = ssim_map(&a, &b, w, h);
            for (k, v) in map.iter().enumerate() {
                let r = reference_pixel(&a, &b, w, h, (k / 3) % w, k / 3 / w, k % 3);
                assert!((v - r).abs() < 1e-12, "{w}×{h} pixel {k}: {v} vs {r}");
            }
        }
    }

    #[test]
    fn identical_images_score_one() {
        let a = noise(1, 3 * 20 * 13);
        assert!((ssim(&a, &a, 20, 13, None) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn gradient_matches_central_differences() {
        let (w, h) = (14, 9);
        let a = noise(2, 3 * w * h);
        let b = noise(3, 3 * w * h);
        let mut g = vec![0.0; a.len()];
        ssim(&a, &b, w, h, Some(&mut g));
        let eps = 1e-6;
        let mut worst = 0.0f64;
        for i in (0..a.len()).step_by(7) {
            let mut p = a.clone();
            p[i] += eps;
            let up = ssim(&p, &b, w, h, None);
            p[i] -= 2.0 * eps;
            let down = ssim(&p, &b, w, h, None);
            let fd = (up - down) / (2.0 * eps);
            worst = worst.max((fd - g[i]).abs() / (fd.abs().max(g[i].abs()).max(1e-6)));
        }
        assert!(worst < 1e-5, "relative error {worst}");
    }
}
