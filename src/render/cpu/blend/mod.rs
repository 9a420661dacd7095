//! Front-to-back α-blending of depth-sorted splats in one 16×16 tile,
//! forward and backward. `α = min(0.99, opacity·exp(power))`, splats with `α < 1/255` or
//! outside their 3σ ellipse are skipped, a pixel stops before its transmittance would fall
//! below 1e-4. Outputs per pixel: RGB over a background, alpha `1 − T`, and depth
//! `Σ wᵢ zᵢ` (weights `wᵢ = αᵢ Tᵢ`, not normalised by alpha).

use crate::math::numerics::{Real, ceil_i64, floor_i64};
use crate::math::project::EXTENT_SIGMAS;

/// Largest α of one splat at one pixel.
pub const ALPHA_MAX: f64 = 0.99;
/// Splats with a smaller α at a pixel are skipped.
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// A pixel stops blending before its transmittance drops below this.
pub const TRANSMITTANCE_MIN: f64 = 1e-4;

/// A projected, coloured splat ready for blending. Build it with [`Splat::new`], which
/// also derives its support: the 3σ ellipse, shrunk to where `opacity·exp(power) ≥ 1/255`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Splat<F> {
    pub mean: [F; 2],
    pub conic: [F; 3],
    pub opacity: F,
    pub colour: [F; 3],
    pub depth: F,
    /// Pixels with a smaller `power` are outside the support (no `exp` needed).
    pub min_power: F,
    /// Inclusive pixel box `[x0, x1, y0, y1]` of the support (unclipped).
    pub rect: [i32; 4],
    /// Squared Mahalanobis radius of the support (≤ 9).
    pub support_d2: F,
}

impl<F: Real> Splat<F> {
    pub fn new(mean: [F; 2], conic: [F; 3], opacity: F, colour: [F; 3], depth: F) -> Self {
        let max_d2 = EXTENT_SIGMAS * EXTENT_SIGMAS;
        let op = opacity.f64().min(1.0);
        let d2 = if op > ALPHA_MIN {
            (2.0 * (op / ALPHA_MIN).ln()).min(max_d2)
        } else {
            0.0
        };
        // Covariance = conic⁻¹: Σxx = c/det, Σyy = a/det.
        let (a, b, c) = (conic[0].f64(), conic[1].f64(), conic[2].f64());
        let det = a * c - b * b;
        let (sxx, syy) = if det > 0.0 {
            (c / det, a / det)
        } else {
            (0.0, 0.0)
        };
        let (ex, ey) = ((d2 * sxx).sqrt(), (d2 * syy).sqrt());
        let (mx, my) = (mean[0].f64(), mean[1].f64());
        let to_i = |v: f64| v.clamp(-1e9, 1e9) as i32;
        let rect =
            if d2 > 0.0 && ex.is_finite() && ey.is_finite() && mx.is_finite() && my.is_finite() {
                [
                    to_i((mx - ex - 0.5).ceil()),
                    to_i((mx + ex - 0.5).floor()),
                    to_i((my - ey - 0.5).ceil()),
                    to_i((my + ey - 0.5).floor()),
                ]
            } else {
                [0, -1, 0, -1]
            };
        // A hair of slack so rounding never drops a pixel the α test would keep.
        Self {
            mean,
            conic,
            opacity,
            colour,
            depth,
            min_power: F::c(-0.5 * d2 * (1.0 + 1e-6) - 1e-9),
            rect,
            support_d2: F::c(d2),
        }
    }

    /// The support box clipped to a pixel rectangle, as `(x0, x1, y0, y1)` half-open.
    #[inline]
    pub fn clip(&self, r: PixelRect) -> Option<(u32, u32, u32, u32)> {
        let x0 = self.rect[0].max(r.x0 as i32);
        let x1 = (self.rect[1] + 1).min(r.x1 as i32);
        let y0 = self.rect[2].max(r.y0 as i32);
        let y1 = (self.rect[3] + 1).min(r.y1 as i32);
        if x0 >= x1 || y0 >= y1 {
            return None;
        }
        Some((x0 as u32, x1 as u32, y0 as u32, y1 as u32))
    }

    /// The pixels `[x0, x1)` of row centre `fy` that can lie inside the support ellipse,
    /// within `[lo, hi)`. Slightly generous: every pixel is still tested exactly.
    #[inline(always)]
    pub fn row_span(&self, fy: F, lo: u32, hi: u32) -> (u32, u32) {
        let [a, b, c] = self.conic;
        let dy = fy - self.mean[1];
        let bdy = b * dy;
        let disc = bdy * bdy - a * (c * dy * dy - self.support_d2);
        if !(a > F::zero()) || !disc.is_finite() {
            return (lo, hi);
        }
        if disc < F::zero() {
            return (lo, lo);
        }
        let root = disc.sqrt();
        let slack = F::c(0.01);
        let half = F::c(0.5);
        let x_lo = self.mean[0] + (-bdy - root) / a - half - slack;
        let x_hi = self.mean[0] + (-bdy + root) / a - half + slack;
        let start = ceil_i64(x_lo.f64()).clamp(lo as i64, hi as i64);
        let end = (floor_i64(x_hi.f64()) + 1).clamp(start, hi as i64);
        (start as u32, end as u32)
    }
}

/// Gradient of the loss with respect to one splat's blend inputs.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplatGrad<F> {
    pub mean: [F; 2],
    pub conic: [F; 3],
    pub opacity: F,
    pub colour: [F; 3],
    pub depth: F,
}

impl<F: Real> SplatGrad<F> {
    #[inline]
    pub fn add(&mut self, o: &Self) {
        for k in 0..2 {
            self.mean[k] += o.mean[k];
        }
        for k in 0..3 {
            self.conic[k] += o.conic[k];
            self.colour[k] += o.colour[k];
        }
        self.opacity += o.opacity;
        self.depth += o.depth;
    }
}

/// Pixels evaluated together by [`splat_alpha_lanes`] (branch-free, so it vectorises).
pub const LANES: usize = 8;

/// One splat's α at the pixel centres `(px0 + j + ½, fy)`, `j < LANES`, and `exp(power)`.
/// α is 0 where the splat is skipped (outside its 3σ / α ≥ 1/255 support); an α equal to
/// `ALPHA_MAX` with `opacity·g > ALPHA_MAX` was clamped.
#[inline(always)]
pub fn splat_alpha_lanes<F: Real>(
    s: &Splat<F>,
    px0: u32,
    fy: F,
    alpha: &mut [F; LANES],
    gauss: &mut [F; LANES],
) {
    let dy = fy - s.mean[1];
    let half = F::c(0.5);
    let cdy = s.conic[2] * dy * dy;
    let min_power = s.min_power.max(F::c(-0.5 * EXTENT_SIGMAS * EXTENT_SIGMAS));
    let base = F::c(px0 as f64);
    let (amax, amin) = (F::c(ALPHA_MAX), F::c(ALPHA_MIN));
    for j in 0..LANES {
        let fx = base + F::c(j as f64 + 0.5);
        let dx = fx - s.mean[0];
        let power = -half * (s.conic[0] * dx * dx + cdy) - s.conic[1] * dx * dy;
        let g = power.exp_fast();
        let a = (s.opacity * g).min(amax);
        let keep = power <= F::zero() && power >= min_power && a >= amin;
        alpha[j] = if keep { a } else { F::zero() };
        gauss[j] = g;
    }
}

/// A rectangle of pixels `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug)]
pub struct PixelRect {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl PixelRect {
    pub fn len(&self) -> usize {
        ((self.x1 - self.x0) * (self.y1 - self.y0)) as usize
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Forward result of one tile, pixels row-major within the tile.
#[derive(Clone, Debug, Default)]
pub struct TileOut<F> {
    pub rgb: Vec<F>,
    pub alpha: Vec<F>,
    pub depth: Vec<F>,
    /// Transmittance after the last contributing splat.
    pub final_t: Vec<F>,
    /// Number of list entries visited up to and including the last contributing one.
    pub n_contrib: Vec<u32>,
    /// Splat-pixel evaluations done in this tile (a work statistic: pixels of a splat's
    /// support that were tested; the SIMD kernel counts only still-blending pixels).
    pub evaluations: u64,
}

/// Blend one tile. `splats` are the tile's splats in depth order. Splat-major: each splat
/// visits only the pixels of its support (row spans of its ellipse), `LANES` pixels at a
/// time with branch-free masked updates; each pixel still sees splats front to back.
pub fn blend_tile_forward<F: Real>(
    rect: PixelRect,
    splats: &[Splat<F>],
    background: [F; 3],
    out: &mut TileOut<F>,
) {
    #[cfg(target_arch = "x86_64")]
    if use_avx2::<F>(rect) {
        // SAFETY: F is f32, so these are the same types; the CPU has AVX2 and FMA.
        unsafe {
            let splats = &*(splats as *const [Splat<F>] as *const [Splat<f32>]);
            let out = &mut *(out as *mut TileOut<F> as *mut TileOut<f32>);
            let background = background.map(|v| v.f64() as f32);
            return avx2::forward(rect, splats, background, out);
        }
    }
    scalar::forward(rect, splats, background, out)
}

/// Whether the AVX2+FMA `f32` kernels take this tile: `F` is `f32`, the tile fits their
/// state and the CPU has both features.
#[cfg(target_arch = "x86_64")]
fn use_avx2<F: Real>(rect: PixelRect) -> bool {
    std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>()
        && fits_tile(rect)
        && has_avx2_fma()
}

/// Whether the AVX2+FMA builds of the blend loops can run here.
#[cfg(target_arch = "x86_64")]
fn has_avx2_fma() -> bool {
    std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
}

/// Whether `rect` fits one 16×16 tile (the explicit SIMD kernels' state size).
fn fits_tile(rect: PixelRect) -> bool {
    rect.x1 - rect.x0 <= super::tiles::TILE && rect.y1 - rect.y0 <= super::tiles::TILE
}

/// Per-pixel upstream gradients of one tile (row-major within the tile).
pub struct TileUpstream<'a, F> {
    pub rgb: &'a [F],
    pub alpha: &'a [F],
    pub depth: &'a [F],
}

/// Backward of [`blend_tile_forward`]: adds each splat's gradient into `grads`
/// (aligned with `splats`). `final_t`/`n_contrib` come from the forward. Splats are
/// visited back to front; each pixel keeps its own running state.
#[allow(clippy::too_many_arguments)]
pub fn blend_tile_backward<F: Real>(
    rect: PixelRect,
    splats: &[Splat<F>],
    background: [F; 3],
    final_t: &[F],
    n_contrib: &[u32],
    up: &TileUpstream<F>,
    grads: &mut [SplatGrad<F>],
) {
    #[cfg(target_arch = "x86_64")]
    if use_avx2::<F>(rect) {
        // SAFETY: F is f32, so these are the same types; the CPU has AVX2 and FMA.
        unsafe {
            let splats = &*(splats as *const [Splat<F>] as *const [Splat<f32>]);
            let final_t = &*(final_t as *const [F] as *const [f32]);
            let up = &*(up as *const TileUpstream<F> as *const TileUpstream<f32>);
            let grads = &mut *(grads as *mut [SplatGrad<F>] as *mut [SplatGrad<f32>]);
            let background = background.map(|v| v.f64() as f32);
            return avx2::backward(rect, splats, background, final_t, n_contrib, up, grads);
        }
    }
    scalar::backward(rect, splats, background, final_t, n_contrib, up, grads)
}

#[cfg(target_arch = "x86_64")]
mod avx2;
mod scalar;

#[cfg(test)]
mod tests {
    use super::*;

    fn splats() -> Vec<Splat<f32>> {
        (0..40)
            .map(|k| {
                let f = k as f32;
                let (sx, sy, rho) = (
                    1.5 + (f * 0.37) % 4.0,
                    1.2 + (f * 0.53) % 5.0,
                    ((f * 0.71) % 1.2) - 0.6,
                );
                let det = sx * sx * sy * sy * (1.0 - rho * rho);
                Splat::new(
                    [(f * 7.3) % 20.0 - 2.0, (f * 3.1) % 20.0 - 2.0],
                    [sy * sy / det, -rho * sx * sy / det, sx * sx / det],
                    0.1 + (f * 0.13) % 0.95,
                    [(f * 0.3) % 1.0, (f * 0.7) % 1.0, (f * 0.11) % 1.0],
                    1.0 + f * 0.1,
                )
            })
            .collect()
    }

    fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
        let scale = a.iter().fold(0f32, |m, x| m.max(x.abs())).max(1e-6);
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol * scale)
    }

    /// The dispatched (possibly AVX2+FMA) kernels and the portable loops agree to f32
    /// rounding (FMA and a different summation order change the last bits).
    #[test]
    fn dispatched_and_portable_blends_agree() {
        let rect = PixelRect {
            x0: 0,
            y0: 0,
            x1: 16,
            y1: 16,
        };
        let s = splats();
        let bg = [0.1f32, 0.2, 0.3];
        let (mut a, mut b) = (TileOut::default(), TileOut::default());
        blend_tile_forward(rect, &s, bg, &mut a);
        scalar::forward(rect, &s, bg, &mut b);
        assert!(close(&a.rgb, &b.rgb, 1e-5), "{:?} vs {:?}", a.rgb, b.rgb);
        assert!(close(&a.depth, &b.depth, 1e-5));
        assert_eq!(a.n_contrib, b.n_contrib);
        assert!(a.evaluations > 0);
        let w: Vec<f32> = (0..3 * 256)
            .map(|i| ((i % 11) as f32 - 5.0) * 0.1)
            .collect();
        let up = TileUpstream {
            rgb: &w,
            alpha: &w[..256],
            depth: &w[256..512],
        };
        let mut ga = vec![SplatGrad::default(); s.len()];
        let mut gb = vec![SplatGrad::default(); s.len()];
        blend_tile_backward(rect, &s, bg, &a.final_t, &a.n_contrib, &up, &mut ga);
        scalar::backward(rect, &s, bg, &a.final_t, &a.n_contrib, &up, &mut gb);
        let flat = |g: &[SplatGrad<f32>]| -> Vec<f32> {
            g.iter()
                .flat_map(|x| {
                    let mut v = x.mean.to_vec();
                    v.extend(x.conic);
                    v.extend(x.colour);
                    v.extend([x.opacity, x.depth]);
                    v
                })
                .collect()
        };
        assert!(close(&flat(&ga), &flat(&gb), 1e-4));
    }
}
