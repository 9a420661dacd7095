//! Front-to-back α-blending of depth-sorted splats in one 16×16 tile (REFERENCE.md §1),
//! forward and backward. `α = min(0.99, opacity·exp(power))`, splats with `α < 1/255` or
//! outside their 3σ ellipse are skipped, a pixel stops before its transmittance would fall
//! below 1e-4. Outputs per pixel: RGB over a background, alpha `1 − T`, and depth
//! `Σ wᵢ zᵢ` (weights `wᵢ = αᵢ Tᵢ`, not normalised by alpha).

use crate::numerics::Real;
use crate::project::EXTENT_SIGMAS;

/// Largest α of one splat at one pixel.
pub const ALPHA_MAX: f64 = 0.99;
/// Splats with a smaller α at a pixel are skipped.
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// A pixel stops blending before its transmittance drops below this.
pub const TRANSMITTANCE_MIN: f64 = 1e-4;

/// A projected, coloured splat ready for blending.
#[derive(Clone, Copy, Debug, Default)]
pub struct Splat<F> {
    pub mean: [F; 2],
    pub conic: [F; 3],
    pub opacity: F,
    pub colour: [F; 3],
    pub depth: F,
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

/// One splat's contribution at a pixel centre: `(α, exp(power), α was clamped)`, or
/// `None` when it is skipped.
#[inline(always)]
pub fn splat_alpha<F: Real>(s: &Splat<F>, px: F, py: F) -> Option<(F, F, bool)> {
    let dx = px - s.mean[0];
    let dy = py - s.mean[1];
    let power = -F::c(0.5) * (s.conic[0] * dx * dx + s.conic[2] * dy * dy) - s.conic[1] * dx * dy;
    let min_power = F::c(-0.5 * EXTENT_SIGMAS * EXTENT_SIGMAS);
    if power > F::zero() || power < min_power {
        return None;
    }
    let g = power.exp();
    let raw = s.opacity * g;
    let amax = F::c(ALPHA_MAX);
    let (alpha, clamped) = if raw > amax { (amax, true) } else { (raw, false) };
    if alpha < F::c(ALPHA_MIN) {
        return None;
    }
    Some((alpha, g, clamped))
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
}

/// Blend one tile. `splats` are the tile's splats in depth order.
pub fn blend_tile_forward<F: Real>(rect: PixelRect, splats: &[Splat<F>], background: [F; 3], out: &mut TileOut<F>) {
    let n = rect.len();
    out.rgb.clear();
    out.rgb.resize(3 * n, F::zero());
    out.alpha.clear();
    out.alpha.resize(n, F::zero());
    out.depth.clear();
    out.depth.resize(n, F::zero());
    out.final_t.clear();
    out.final_t.resize(n, F::one());
    out.n_contrib.clear();
    out.n_contrib.resize(n, 0);
    let t_min = F::c(TRANSMITTANCE_MIN);
    let half = F::c(0.5);
    let w = rect.x1 - rect.x0;
    for py in rect.y0..rect.y1 {
        for px in rect.x0..rect.x1 {
            let p = ((py - rect.y0) * w + (px - rect.x0)) as usize;
            let (fx, fy) = (F::c(px as f64) + half, F::c(py as f64) + half);
            let mut t = F::one();
            let mut c = [F::zero(); 3];
            let mut d = F::zero();
            let mut last = 0u32;
            for (k, s) in splats.iter().enumerate() {
                let Some((alpha, _, _)) = splat_alpha(s, fx, fy) else { continue };
                let next_t = t * (F::one() - alpha);
                if next_t < t_min {
                    break;
                }
                let wgt = alpha * t;
                c[0] += s.colour[0] * wgt;
                c[1] += s.colour[1] * wgt;
                c[2] += s.colour[2] * wgt;
                d += s.depth * wgt;
                t = next_t;
                last = k as u32 + 1;
            }
            for ch in 0..3 {
                out.rgb[3 * p + ch] = c[ch] + t * background[ch];
            }
            out.alpha[p] = F::one() - t;
            out.depth[p] = d;
            out.final_t[p] = t;
            out.n_contrib[p] = last;
        }
    }
}

/// Per-pixel upstream gradients of one tile (row-major within the tile).
pub struct TileUpstream<'a, F> {
    pub rgb: &'a [F],
    pub alpha: &'a [F],
    pub depth: &'a [F],
}

/// Backward of [`blend_tile_forward`]: adds each splat's gradient into `grads`
/// (aligned with `splats`). `final_t`/`n_contrib` come from the forward.
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
    let half = F::c(0.5);
    let one = F::one();
    let w = rect.x1 - rect.x0;
    for py in rect.y0..rect.y1 {
        for px in rect.x0..rect.x1 {
            let p = ((py - rect.y0) * w + (px - rect.x0)) as usize;
            let (fx, fy) = (F::c(px as f64) + half, F::c(py as f64) + half);
            let dc = [up.rgb[3 * p], up.rgb[3 * p + 1], up.rgb[3 * p + 2]];
            let dd = up.depth[p];
            let da = up.alpha[p];
            let t_final = final_t[p];
            let bg_dot = background[0] * dc[0] + background[1] * dc[1] + background[2] * dc[2];
            let mut t = t_final;
            let mut acc_c = [F::zero(); 3];
            let mut acc_d = F::zero();
            let mut last_alpha = F::zero();
            let mut last_c = [F::zero(); 3];
            let mut last_d = F::zero();
            for k in (0..n_contrib[p] as usize).rev() {
                let s = &splats[k];
                let Some((alpha, g, clamped)) = splat_alpha(s, fx, fy) else { continue };
                let inv_one_minus = one / (one - alpha);
                t = t * inv_one_minus;
                let wgt = alpha * t;
                let gr = &mut grads[k];
                gr.colour[0] += wgt * dc[0];
                gr.colour[1] += wgt * dc[1];
                gr.colour[2] += wgt * dc[2];
                gr.depth += wgt * dd;
                for ch in 0..3 {
                    acc_c[ch] = last_alpha * last_c[ch] + (one - last_alpha) * acc_c[ch];
                }
                acc_d = last_alpha * last_d + (one - last_alpha) * acc_d;
                last_alpha = alpha;
                last_c = s.colour;
                last_d = s.depth;
                let mut d_alpha = ((s.colour[0] - acc_c[0]) * dc[0]
                    + (s.colour[1] - acc_c[1]) * dc[1]
                    + (s.colour[2] - acc_c[2]) * dc[2]
                    + (s.depth - acc_d) * dd)
                    * t;
                d_alpha += t_final * inv_one_minus * (da - bg_dot);
                if clamped {
                    continue;
                }
                // α = opacity · exp(power)
                gr.opacity += g * d_alpha;
                let d_power = s.opacity * g * d_alpha;
                let dx = fx - s.mean[0];
                let dy = fy - s.mean[1];
                gr.conic[0] -= half * dx * dx * d_power;
                gr.conic[1] -= dx * dy * d_power;
                gr.conic[2] -= half * dy * dy * d_power;
                gr.mean[0] += (s.conic[0] * dx + s.conic[1] * dy) * d_power;
                gr.mean[1] += (s.conic[2] * dy + s.conic[1] * dx) * d_power;
            }
        }
    }
}
