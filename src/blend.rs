//! Front-to-back α-blending of depth-sorted splats in one 16×16 tile (REFERENCE.md §1),
//! forward and backward. `α = min(0.99, opacity·exp(power))`, splats with `α < 1/255` or
//! outside their 3σ ellipse are skipped, a pixel stops before its transmittance would fall
//! below 1e-4. Outputs per pixel: RGB over a background, alpha `1 − T`, and depth
//! `Σ wᵢ zᵢ` (weights `wᵢ = αᵢ Tᵢ`, not normalised by alpha).

use crate::numerics::{Real, ceil_i64, floor_i64};
use crate::project::EXTENT_SIGMAS;

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
    if std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>()
        && fits_tile(rect)
        && has_avx2_fma()
    {
        // SAFETY: F is f32, so these are the same types; the CPU has AVX2 and FMA.
        unsafe {
            let splats = &*(splats as *const [Splat<F>] as *const [Splat<f32>]);
            let out = &mut *(out as *mut TileOut<F> as *mut TileOut<f32>);
            let background = [
                background[0].f64() as f32,
                background[1].f64() as f32,
                background[2].f64() as f32,
            ];
            return avx2::forward(rect, splats, background, out);
        }
    }
    blend_tile_forward_impl(rect, splats, background, out)
}

/// Whether the AVX2+FMA builds of the blend loops can run here.
#[cfg(target_arch = "x86_64")]
fn has_avx2_fma() -> bool {
    std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
}

/// Whether `rect` fits one 16×16 tile (the explicit SIMD kernels' state size).
fn fits_tile(rect: PixelRect) -> bool {
    rect.x1 - rect.x0 <= crate::tiles::TILE && rect.y1 - rect.y0 <= crate::tiles::TILE
}

#[inline(always)]
fn blend_tile_forward_impl<F: Real>(
    rect: PixelRect,
    splats: &[Splat<F>],
    background: [F; 3],
    out: &mut TileOut<F>,
) {
    let n = rect.len();
    let padded = n + LANES;
    let zero = F::zero();
    let one = F::one();
    // Per-pixel state, structure of arrays, padded so a lane group never runs off the end.
    let mut trans = vec![one; padded];
    let mut cr = vec![zero; padded];
    let mut cg = vec![zero; padded];
    let mut cb = vec![zero; padded];
    let mut dep = vec![zero; padded];
    let mut last = vec![0u32; padded];
    let mut done = vec![zero; padded];
    let mut alive = n as i64;
    let mut evaluations = 0u64;
    let mut lane_alpha = [zero; LANES];
    let mut lane_g = [zero; LANES];
    let t_min = F::c(TRANSMITTANCE_MIN);
    let half = F::c(0.5);
    let w = rect.x1 - rect.x0;
    for (k, s) in splats.iter().enumerate() {
        if alive <= 0 {
            break;
        }
        let Some((x0, x1, y0, y1)) = s.clip(rect) else {
            continue;
        };
        let kk = k as u32 + 1;
        for py in y0..y1 {
            let fy = F::c(py as f64) + half;
            let row = ((py - rect.y0) * w) as usize;
            let (sx0, sx1) = s.row_span(fy, x0, x1);
            let mut px0 = sx0;
            while px0 < sx1 {
                splat_alpha_lanes(s, px0, fy, &mut lane_alpha, &mut lane_g);
                let m = (sx1 - px0).min(LANES as u32) as usize;
                evaluations += m as u64;
                let base = row + (px0 - rect.x0) as usize;
                let t: &mut [F; LANES] = (&mut trans[base..base + LANES]).try_into().unwrap();
                let r: &mut [F; LANES] = (&mut cr[base..base + LANES]).try_into().unwrap();
                let g: &mut [F; LANES] = (&mut cg[base..base + LANES]).try_into().unwrap();
                let b: &mut [F; LANES] = (&mut cb[base..base + LANES]).try_into().unwrap();
                let d: &mut [F; LANES] = (&mut dep[base..base + LANES]).try_into().unwrap();
                let l: &mut [u32; LANES] = (&mut last[base..base + LANES]).try_into().unwrap();
                let dn: &mut [F; LANES] = (&mut done[base..base + LANES]).try_into().unwrap();
                let mut stops = 0i64;
                for j in 0..LANES {
                    let a = if j < m { lane_alpha[j] } else { zero };
                    let live = a > zero && dn[j] == zero;
                    let next_t = t[j] * (one - a);
                    let stop = live && next_t < t_min;
                    let contrib = live && !(next_t < t_min);
                    let wgt = if contrib { a * t[j] } else { zero };
                    r[j] += s.colour[0] * wgt;
                    g[j] += s.colour[1] * wgt;
                    b[j] += s.colour[2] * wgt;
                    d[j] += s.depth * wgt;
                    t[j] = if contrib { next_t } else { t[j] };
                    l[j] = if contrib { kk } else { l[j] };
                    dn[j] = if stop { one } else { dn[j] };
                    stops += stop as i64;
                }
                alive -= stops;
                px0 += LANES as u32;
            }
        }
    }
    out.rgb.clear();
    out.alpha.clear();
    out.depth.clear();
    out.final_t.clear();
    out.n_contrib.clear();
    for p in 0..n {
        out.rgb.extend_from_slice(&[
            cr[p] + trans[p] * background[0],
            cg[p] + trans[p] * background[1],
            cb[p] + trans[p] * background[2],
        ]);
    }
    out.alpha.extend(trans[..n].iter().map(|&t| one - t));
    out.depth.extend_from_slice(&dep[..n]);
    out.final_t.extend_from_slice(&trans[..n]);
    out.n_contrib.extend_from_slice(&last[..n]);
    out.evaluations = evaluations;
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
    if std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>()
        && fits_tile(rect)
        && has_avx2_fma()
    {
        // SAFETY: F is f32, so these are the same types; the CPU has AVX2 and FMA.
        unsafe {
            let splats = &*(splats as *const [Splat<F>] as *const [Splat<f32>]);
            let final_t = &*(final_t as *const [F] as *const [f32]);
            let up = &*(up as *const TileUpstream<F> as *const TileUpstream<f32>);
            let grads = &mut *(grads as *mut [SplatGrad<F>] as *mut [SplatGrad<f32>]);
            let background = [
                background[0].f64() as f32,
                background[1].f64() as f32,
                background[2].f64() as f32,
            ];
            return avx2::backward(rect, splats, background, final_t, n_contrib, up, grads);
        }
    }
    blend_tile_backward_impl(rect, splats, background, final_t, n_contrib, up, grads)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn blend_tile_backward_impl<F: Real>(
    rect: PixelRect,
    splats: &[Splat<F>],
    background: [F; 3],
    final_t: &[F],
    n_contrib: &[u32],
    up: &TileUpstream<F>,
    grads: &mut [SplatGrad<F>],
) {
    /// Per pixel: the transmittance in front of the current splat, and
    /// `behind = Σ_{j>k} wⱼ (cⱼ·dL/dC + zⱼ·dL/dD)` of the splats behind it.
    #[derive(Clone, Copy, Default)]
    struct State<F> {
        t: F,
        behind: F,
    }
    let half = F::c(0.5);
    let one = F::one();
    let w = rect.x1 - rect.x0;
    let n = rect.len();
    let mut state: Vec<State<F>> = (0..n)
        .map(|p| State {
            t: final_t[p],
            ..State::default()
        })
        .collect();
    let bg_dot: Vec<F> = (0..n)
        .map(|p| {
            background[0] * up.rgb[3 * p]
                + background[1] * up.rgb[3 * p + 1]
                + background[2] * up.rgb[3 * p + 2]
        })
        .collect();
    let k_max = n_contrib.iter().copied().max().unwrap_or(0) as usize;
    let mut lane_alpha = [F::zero(); LANES];
    let mut lane_g = [F::zero(); LANES];
    let amax = F::c(ALPHA_MAX);
    for k in (0..k_max.min(splats.len())).rev() {
        let s = &splats[k];
        let Some((x0, x1, y0, y1)) = s.clip(rect) else {
            continue;
        };
        let mut gr = SplatGrad::default();
        for py in y0..y1 {
            let fy = F::c(py as f64) + half;
            let row = ((py - rect.y0) * w) as usize;
            let (sx0, sx1) = s.row_span(fy, x0, x1);
            let mut px0 = sx0;
            while px0 < sx1 {
                splat_alpha_lanes(s, px0, fy, &mut lane_alpha, &mut lane_g);
                let m = (sx1 - px0).min(LANES as u32);
                for j in 0..m as usize {
                    let alpha = lane_alpha[j];
                    if alpha == F::zero() {
                        continue;
                    }
                    let p = row + (px0 - rect.x0) as usize + j;
                    if k as u32 >= n_contrib[p] {
                        continue;
                    }
                    let g = lane_g[j];
                    let clamped = s.opacity * g > amax;
                    let fx = F::c((px0 as usize + j) as f64) + half;
                    let dc = [up.rgb[3 * p], up.rgb[3 * p + 1], up.rgb[3 * p + 2]];
                    let dd = up.depth[p];
                    let st = &mut state[p];
                    let inv_one_minus = one / (one - alpha);
                    st.t *= inv_one_minus;
                    let t = st.t;
                    let wgt = alpha * t;
                    gr.colour[0] += wgt * dc[0];
                    gr.colour[1] += wgt * dc[1];
                    gr.colour[2] += wgt * dc[2];
                    gr.depth += wgt * dd;
                    // dL/dαₖ = Tₖ (cₖ·dL/dC + zₖ·dL/dD) + (T_final (dL/dA − bg·dL/dC)
                    // − behind) / (1 − αₖ)
                    let cd = s.colour[0] * dc[0]
                        + s.colour[1] * dc[1]
                        + s.colour[2] * dc[2]
                        + s.depth * dd;
                    let d_alpha = cd * t
                        + (final_t[p] * (up.alpha[p] - bg_dot[p]) - st.behind) * inv_one_minus;
                    st.behind += wgt * cd;
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
                px0 += LANES as u32;
            }
        }
        grads[k].add(&gr);
    }
}

/// Explicit AVX2+FMA blend kernels for `f32`: a 16-pixel tile row is two 8-lane vectors,
/// every splat processes the (aligned) vectors its row span touches, fully masked.
/// Chosen at run time by [`blend_tile_forward`] / [`blend_tile_backward`]; the portable
/// generic loops remain the fallback (and the `f64` path).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::*;
    use std::arch::x86_64::*;

    /// Per-tile state stride: one tile row = two vectors of 8 pixels.
    const ROW_VECS: usize = (crate::tiles::TILE as usize) / 8;
    const VECS: usize = ROW_VECS * crate::tiles::TILE as usize;

    /// `exp` of 8 lanes, the same Cody–Waite + degree-6 polynomial as
    /// [`crate::numerics::exp_f32`], with FMA.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn exp8(x: __m256) -> __m256 {
        let x = _mm256_min_ps(
            _mm256_max_ps(x, _mm256_set1_ps(-87.0)),
            _mm256_set1_ps(88.0),
        );
        let round = _mm256_set1_ps(12_582_912.0);
        let n = _mm256_sub_ps(
            _mm256_fmadd_ps(x, _mm256_set1_ps(std::f32::consts::LOG2_E), round),
            round,
        );
        let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(0.693_145_75), x);
        let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(1.428_606_8e-6), r);
        let mut p = _mm256_set1_ps(1.0 / 720.0);
        for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
            p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(c));
        }
        let bits = _mm256_castps_si256(_mm256_add_ps(n, _mm256_set1_ps(8_388_608.0 + 127.0)));
        let scale = _mm256_castsi256_ps(_mm256_slli_epi32(bits, 23));
        _mm256_mul_ps(p, scale)
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn hsum(v: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
        _mm_cvtss_f32(s)
    }

    /// Per-splat constants broadcast once.
    struct SplatVec {
        mx: __m256,
        my: f32,
        half_a: __m256,
        b: f32,
        c: f32,
        opacity: __m256,
        min_power: __m256,
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn splat_vec(s: &Splat<f32>) -> SplatVec {
        SplatVec {
            mx: _mm256_set1_ps(s.mean[0]),
            my: s.mean[1],
            half_a: _mm256_set1_ps(0.5 * s.conic[0]),
            b: s.conic[1],
            c: s.conic[2],
            opacity: _mm256_set1_ps(s.opacity),
            min_power: _mm256_set1_ps(
                s.min_power
                    .max(-0.5 * (EXTENT_SIGMAS * EXTENT_SIGMAS) as f32),
            ),
        }
    }

    /// `(dx, power)` of one 8-pixel vector of one splat row, with
    /// `power = −½(a dx² + c dy²) − b dx dy = p0 − (½a dx + b dy) dx`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn power8(sv: &SplatVec, fx0: __m256, p0: __m256, q: __m256) -> (__m256, __m256) {
        let dx = _mm256_sub_ps(fx0, sv.mx);
        let u = _mm256_fmadd_ps(sv.half_a, dx, q);
        (dx, _mm256_fnmadd_ps(u, dx, p0))
    }

    /// Lanes of `mask` inside the splat's support (`min_power ≤ power ≤ 0`); tested
    /// before the `exp`, so vectors outside the ellipse cost only this.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn support8(sv: &SplatVec, power: __m256, mask: __m256) -> __m256 {
        _mm256_and_ps(
            mask,
            _mm256_and_ps(
                _mm256_cmp_ps(power, _mm256_setzero_ps(), _CMP_LE_OQ),
                _mm256_cmp_ps(power, sv.min_power, _CMP_GE_OQ),
            ),
        )
    }

    /// `(g = exp(power), opacity·g, keep)` where `keep` is `inside` and `α ≥ 1/255`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn alpha8(sv: &SplatVec, power: __m256, inside: __m256) -> (__m256, __m256, __m256) {
        let g = exp8(power);
        let og = _mm256_mul_ps(sv.opacity, g);
        let a = _mm256_min_ps(og, _mm256_set1_ps(ALPHA_MAX as f32));
        let keep = _mm256_and_ps(
            inside,
            _mm256_cmp_ps(a, _mm256_set1_ps(ALPHA_MIN as f32), _CMP_GE_OQ),
        );
        (g, og, keep)
    }

    const LANE_IDX: [f32; 8] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];

    /// The columns `[x0, x1)` of a splat's clipped box in one tile: the vectors
    /// `v0..v1` of a row it touches, their pixel-centre x and their in-box lane masks.
    /// (No per-row ellipse span: with two vectors per row, testing every lane of the box
    /// against the support is cheaper than a square root and division per row.)
    struct ColumnMasks {
        v0: usize,
        v1: usize,
        fx: [__m256; ROW_VECS],
        mask: [__m256; ROW_VECS],
    }

    impl ColumnMasks {
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        fn new(rect: PixelRect, x0: u32, x1: u32, lane: __m256) -> Self {
            let (lo, hi) = (x0 - rect.x0, x1 - rect.x0);
            let (lo_v, hi_v) = (_mm256_set1_ps(lo as f32), _mm256_set1_ps(hi as f32));
            let mut fx = [_mm256_setzero_ps(); ROW_VECS];
            let mut mask = [_mm256_setzero_ps(); ROW_VECS];
            for v in 0..ROW_VECS {
                let lane_v = _mm256_add_ps(lane, _mm256_set1_ps((v * 8) as f32));
                fx[v] = _mm256_add_ps(lane_v, _mm256_set1_ps(rect.x0 as f32 + 0.5));
                mask[v] = _mm256_and_ps(
                    _mm256_cmp_ps(lane_v, lo_v, _CMP_GE_OQ),
                    _mm256_cmp_ps(lane_v, hi_v, _CMP_LT_OQ),
                );
            }
            Self {
                v0: (lo / 8) as usize,
                v1: (hi as usize).div_ceil(8),
                fx,
                mask,
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    pub(super) fn forward(
        rect: PixelRect,
        splats: &[Splat<f32>],
        background: [f32; 3],
        out: &mut TileOut<f32>,
    ) {
        debug_assert!(rect.x1 - rect.x0 <= crate::tiles::TILE);
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        let mut trans = [one; VECS];
        let mut cr = [zero; VECS];
        let mut cg = [zero; VECS];
        let mut cb = [zero; VECS];
        let mut dep = [zero; VECS];
        let mut last = [_mm256_setzero_si256(); VECS];
        let mut done = [zero; VECS];
        let n = rect.len();
        let mut alive = n as i64;
        let mut evaluations = 0u64;
        let t_min = _mm256_set1_ps(TRANSMITTANCE_MIN as f32);
        // SAFETY: an 8-float array read.
        let lane = unsafe { _mm256_loadu_ps(LANE_IDX.as_ptr()) };
        for (k, s) in splats.iter().enumerate() {
            if alive <= 0 {
                break;
            }
            let Some((x0, x1, y0, y1)) = s.clip(rect) else {
                continue;
            };
            let sv = splat_vec(s);
            let kk = _mm256_set1_epi32(k as i32 + 1);
            let (colr, colg, colb, cdep) = (
                _mm256_set1_ps(s.colour[0]),
                _mm256_set1_ps(s.colour[1]),
                _mm256_set1_ps(s.colour[2]),
                _mm256_set1_ps(s.depth),
            );
            let cols = ColumnMasks::new(rect, x0, x1, lane);
            for py in y0..y1 {
                let fy = py as f32 + 0.5;
                let dy = fy - sv.my;
                let p0 = _mm256_set1_ps(-0.5 * sv.c * dy * dy);
                let q = _mm256_set1_ps(sv.b * dy);
                let row = (py - rect.y0) as usize * ROW_VECS;
                for v in cols.v0..cols.v1 {
                    let i = row + v;
                    let (_, power) = power8(&sv, cols.fx[v], p0, q);
                    let inside = support8(&sv, power, _mm256_andnot_ps(done[i], cols.mask[v]));
                    let bits = _mm256_movemask_ps(inside);
                    if bits == 0 {
                        continue;
                    }
                    evaluations += bits.count_ones() as u64;
                    let (_, og, live) = alpha8(&sv, power, inside);
                    if _mm256_movemask_ps(live) == 0 {
                        continue;
                    }
                    let a = _mm256_min_ps(og, _mm256_set1_ps(ALPHA_MAX as f32));
                    let t = trans[i];
                    let next_t = _mm256_mul_ps(t, _mm256_sub_ps(one, a));
                    let stop = _mm256_and_ps(live, _mm256_cmp_ps(next_t, t_min, _CMP_LT_OQ));
                    let contrib = _mm256_andnot_ps(stop, live);
                    let wgt = _mm256_and_ps(contrib, _mm256_mul_ps(a, t));
                    cr[i] = _mm256_fmadd_ps(colr, wgt, cr[i]);
                    cg[i] = _mm256_fmadd_ps(colg, wgt, cg[i]);
                    cb[i] = _mm256_fmadd_ps(colb, wgt, cb[i]);
                    dep[i] = _mm256_fmadd_ps(cdep, wgt, dep[i]);
                    trans[i] = _mm256_blendv_ps(t, next_t, contrib);
                    last[i] = _mm256_blendv_epi8(last[i], kk, _mm256_castps_si256(contrib));
                    done[i] = _mm256_or_ps(done[i], stop);
                    alive -= _mm256_movemask_ps(stop).count_ones() as i64;
                }
            }
        }
        let w = (rect.x1 - rect.x0) as usize;
        let h = (rect.y1 - rect.y0) as usize;
        let flat = |v: &[__m256; VECS]| -> [f32; 8 * VECS] {
            // SAFETY: same size, plain floats.
            unsafe { std::mem::transmute_copy(v) }
        };
        let (t, r, g, b, d) = (flat(&trans), flat(&cr), flat(&cg), flat(&cb), flat(&dep));
        // SAFETY: same size, plain integers.
        let l: [u32; 8 * VECS] = unsafe { std::mem::transmute_copy(&last) };
        out.rgb.clear();
        out.alpha.clear();
        out.depth.clear();
        out.final_t.clear();
        out.n_contrib.clear();
        let stride = 8 * ROW_VECS;
        for y in 0..h {
            for x in 0..w {
                let p = y * stride + x;
                out.rgb.extend_from_slice(&[
                    r[p] + t[p] * background[0],
                    g[p] + t[p] * background[1],
                    b[p] + t[p] * background[2],
                ]);
                out.alpha.push(1.0 - t[p]);
                out.depth.push(d[p]);
                out.final_t.push(t[p]);
                out.n_contrib.push(l[p]);
            }
        }
        out.evaluations = evaluations;
    }

    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn backward(
        rect: PixelRect,
        splats: &[Splat<f32>],
        background: [f32; 3],
        final_t: &[f32],
        n_contrib: &[u32],
        up: &TileUpstream<f32>,
        grads: &mut [SplatGrad<f32>],
    ) {
        let w = (rect.x1 - rect.x0) as usize;
        let h = (rect.y1 - rect.y0) as usize;
        let stride = 8 * ROW_VECS;
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        // Per-pixel inputs, padded to the full 16×16 tile (padding never passes the masks).
        let mut ft = [0f32; 8 * VECS];
        let mut up_r = [0f32; 8 * VECS];
        let mut up_g = [0f32; 8 * VECS];
        let mut up_b = [0f32; 8 * VECS];
        let mut up_d = [0f32; 8 * VECS];
        let mut ft_term = [0f32; 8 * VECS];
        let mut nc = [0f32; 8 * VECS];
        let mut k_max = 0usize;
        for y in 0..h {
            for x in 0..w {
                let (p, q) = (y * w + x, y * stride + x);
                let (r, g, b) = (up.rgb[3 * p], up.rgb[3 * p + 1], up.rgb[3 * p + 2]);
                let bg_dot = background[0] * r + background[1] * g + background[2] * b;
                ft[q] = final_t[p];
                up_r[q] = r;
                up_g[q] = g;
                up_b[q] = b;
                up_d[q] = up.depth[p];
                ft_term[q] = final_t[p] * (up.alpha[p] - bg_dot);
                nc[q] = n_contrib[p] as f32;
                k_max = k_max.max(n_contrib[p] as usize);
            }
        }
        let vecs = |a: &[f32; 8 * VECS]| -> [__m256; VECS] {
            // SAFETY: same size, plain floats.
            unsafe { std::mem::transmute_copy(a) }
        };
        let (dcr, dcg, dcb, ddv, ftt, ncv) = (
            vecs(&up_r),
            vecs(&up_g),
            vecs(&up_b),
            vecs(&up_d),
            vecs(&ft_term),
            vecs(&nc),
        );
        let mut trans = vecs(&ft);
        // Per pixel, `behind = Σ_{j>k} wⱼ (cⱼ·dL/dC + zⱼ·dL/dD)`: what the splats behind
        // the current one gave to the loss, so `dL/dαₖ = Tₖ (cₖ·dL/dC + zₖ·dL/dD)
        // + (T_final (dL/dA − bg·dL/dC) − behind) / (1 − αₖ)`.
        let mut behind = [zero; VECS];
        let amax = _mm256_set1_ps(ALPHA_MAX as f32);
        let two = _mm256_set1_ps(2.0);
        // SAFETY: an 8-float array read.
        let lane = unsafe { _mm256_loadu_ps(LANE_IDX.as_ptr()) };
        for k in (0..k_max.min(splats.len())).rev() {
            let s = &splats[k];
            let Some((x0, x1, y0, y1)) = s.clip(rect) else {
                continue;
            };
            let sv = splat_vec(s);
            let kf = _mm256_set1_ps(k as f32);
            let (colr, colg, colb, cdep) = (
                _mm256_set1_ps(s.colour[0]),
                _mm256_set1_ps(s.colour[1]),
                _mm256_set1_ps(s.colour[2]),
                _mm256_set1_ps(s.depth),
            );
            let (mut g_r, mut g_g, mut g_b, mut g_d, mut g_o) = (zero, zero, zero, zero, zero);
            let (mut s_x, mut s_y, mut s_xx, mut s_xy, mut s_yy) = (zero, zero, zero, zero, zero);
            let cols = ColumnMasks::new(rect, x0, x1, lane);
            for py in y0..y1 {
                let fy = py as f32 + 0.5;
                let dy_s = fy - sv.my;
                let dy = _mm256_set1_ps(dy_s);
                let p0 = _mm256_set1_ps(-0.5 * sv.c * dy_s * dy_s);
                let q = _mm256_set1_ps(sv.b * dy_s);
                let row = (py - rect.y0) as usize * ROW_VECS;
                for v in cols.v0..cols.v1 {
                    let i = row + v;
                    let (dx, power) = power8(&sv, cols.fx[v], p0, q);
                    let pre = _mm256_and_ps(cols.mask[v], _mm256_cmp_ps(kf, ncv[i], _CMP_LT_OQ));
                    let inside = support8(&sv, power, pre);
                    if _mm256_movemask_ps(inside) == 0 {
                        continue;
                    }
                    let (g, og, m) = alpha8(&sv, power, inside);
                    if _mm256_movemask_ps(m) == 0 {
                        continue;
                    }
                    let alpha = _mm256_and_ps(m, _mm256_min_ps(og, amax));
                    // 1/(1 − α) by `rcp` and one Newton step (1 − α ≥ 0.01: relative error
                    // ≈ 1e-7). Masked-off lanes have α = 0, so inv = 1 and T is unchanged.
                    let d = _mm256_sub_ps(one, alpha);
                    let r0 = _mm256_rcp_ps(d);
                    let inv = _mm256_mul_ps(r0, _mm256_fnmadd_ps(d, r0, two));
                    let t = _mm256_mul_ps(trans[i], inv);
                    trans[i] = t;
                    let wgt = _mm256_mul_ps(alpha, t);
                    g_r = _mm256_fmadd_ps(wgt, dcr[i], g_r);
                    g_g = _mm256_fmadd_ps(wgt, dcg[i], g_g);
                    g_b = _mm256_fmadd_ps(wgt, dcb[i], g_b);
                    g_d = _mm256_fmadd_ps(wgt, ddv[i], g_d);
                    let mut cd = _mm256_mul_ps(colr, dcr[i]);
                    cd = _mm256_fmadd_ps(colg, dcg[i], cd);
                    cd = _mm256_fmadd_ps(colb, dcb[i], cd);
                    cd = _mm256_fmadd_ps(cdep, ddv[i], cd);
                    let d_alpha = _mm256_fmadd_ps(
                        cd,
                        t,
                        _mm256_mul_ps(_mm256_sub_ps(ftt[i], behind[i]), inv),
                    );
                    // Masked-off lanes have w = 0.
                    behind[i] = _mm256_fmadd_ps(wgt, cd, behind[i]);
                    // Clamped lanes (opacity·g > α_max) pass no gradient to opacity/power.
                    let free = _mm256_and_ps(m, _mm256_cmp_ps(og, amax, _CMP_LE_OQ));
                    let da = _mm256_and_ps(free, d_alpha);
                    g_o = _mm256_fmadd_ps(g, da, g_o);
                    let dp = _mm256_mul_ps(og, da);
                    let dxdp = _mm256_mul_ps(dx, dp);
                    let dydp = _mm256_mul_ps(dy, dp);
                    s_x = _mm256_add_ps(s_x, dxdp);
                    s_y = _mm256_add_ps(s_y, dydp);
                    s_xx = _mm256_fmadd_ps(dxdp, dx, s_xx);
                    s_xy = _mm256_fmadd_ps(dxdp, dy, s_xy);
                    s_yy = _mm256_fmadd_ps(dydp, dy, s_yy);
                }
            }
            let (sx, sy) = (hsum(s_x), hsum(s_y));
            let [a, b, c] = s.conic;
            grads[k].add(&SplatGrad {
                mean: [a * sx + b * sy, c * sy + b * sx],
                conic: [-0.5 * hsum(s_xx), -hsum(s_xy), -0.5 * hsum(s_yy)],
                opacity: hsum(g_o),
                colour: [hsum(g_r), hsum(g_g), hsum(g_b)],
                depth: hsum(g_d),
            });
        }
    }
}

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
        blend_tile_forward_impl(rect, &s, bg, &mut b);
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
        blend_tile_backward_impl(rect, &s, bg, &a.final_t, &a.n_contrib, &up, &mut gb);
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
