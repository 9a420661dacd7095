//! The portable blend loops, generic over the float type: the fallback where AVX2 is
//! missing, and the `f64` path of the checks.

use super::*;

#[inline(always)]
pub(super) fn forward<F: Real>(
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

#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn backward<F: Real>(
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
