//! Explicit AVX2+FMA blend kernels for `f32`: a 16-pixel tile row is two 8-lane vectors,
//! every splat processes the (aligned) vectors its row span touches, fully masked.
//! Chosen at run time by [`super::blend_tile_forward`] / [`super::blend_tile_backward`];
//! the portable loops ([`super::scalar`]) remain the fallback (and the `f64` path).

use super::*;
use std::arch::x86_64::*;

/// Per-tile state stride: one tile row = two vectors of 8 pixels.
const ROW_VECS: usize = (super::super::tiles::TILE as usize) / 8;
const VECS: usize = ROW_VECS * super::super::tiles::TILE as usize;

/// `exp` of 8 lanes, the same Cody–Waite + degree-6 polynomial as
/// [`crate::math::numerics::exp_f32`], with FMA.
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
    debug_assert!(rect.x1 - rect.x0 <= super::super::tiles::TILE);
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
                let d_alpha =
                    _mm256_fmadd_ps(cd, t, _mm256_mul_ps(_mm256_sub_ps(ftt[i], behind[i]), inv));
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
