//! Backward pass of the CPU renderer: blend backward per tile (gradients per (tile, splat)
//! entry), reduced per splat in tile order, then the per-Gaussian chain
//! (colour, projection, slicing) in parallel over Gaussians.

use super::blend::{SplatGrad, TileUpstream, blend_tile_backward};
use super::{Context, colour_input, tile_rect};
use crate::math::numerics::{Real, sigmoid};
use crate::math::project::{project, project_backward};
use crate::math::sh::colour_backward_masked;
use crate::math::slice::{slice, slice_backward};
use crate::model::Gaussians;
use crate::render::{Gradients, ImageGradients, RenderError, Rendered, check_backward_inputs};
use rayon::prelude::*;

fn context<F: Real>(frame: &Rendered<F>) -> Result<&Context<F>, RenderError> {
    frame
        .state
        .downcast_ref::<Context<F>>()
        .ok_or(RenderError::WrongBackend { backend: "cpu" })
}

/// dL/d(image) → dL/d(parameters) of `model` (the model `frame` was rendered from by
/// [`super::render_with`]).
pub fn backward<F: Real>(
    frame: &Rendered<F>,
    model: &Gaussians<F>,
    up: &ImageGradients<F>,
) -> Result<Gradients<F>, RenderError> {
    let with_factor = context(frame)?.factor.is_some();
    let mut out = Gradients::zeros_like(model, with_factor);
    backward_into(frame, model, up, &mut out)?;
    Ok(out)
}

/// [`backward`] into a reused buffer (resized and overwritten, not added to): saves
/// allocating and faulting in the large colour-gradient array every step.
pub fn backward_into<F: Real>(
    frame: &Rendered<F>,
    model: &Gaussians<F>,
    up: &ImageGradients<F>,
    out: &mut Gradients<F>,
) -> Result<(), RenderError> {
    let ctx = context(frame)?;
    check_backward_inputs(frame, model, ctx.factor.as_ref().map(Vec::len), up)?;
    let n = model.len();
    let (width, height) = (frame.width, frame.height);
    let bins = &ctx.bins;

    // Blend backward per tile; gradients per (tile, splat) entry.
    let per_tile: Vec<Vec<SplatGrad<F>>> = (0..bins.tile_count())
        .into_par_iter()
        .map_init(
            || {
                (
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                )
            },
            |(local, ft, nc, ur, ua, ud), tile| {
                let ids = bins.tile(tile);
                let mut grads = vec![SplatGrad::default(); ids.len()];
                if ids.is_empty() {
                    return grads;
                }
                local.clear();
                local.extend(ids.iter().map(|&k| ctx.splats[k as usize]));
                let r = tile_rect(bins, tile, width, height);
                let w = (r.x1 - r.x0) as usize;
                for v in [&mut *ft, &mut *ua, &mut *ud] {
                    v.clear();
                }
                nc.clear();
                ur.clear();
                for y in r.y0..r.y1 {
                    let s = y as usize * width as usize + r.x0 as usize;
                    ft.extend_from_slice(&ctx.final_t[s..s + w]);
                    nc.extend_from_slice(&ctx.n_contrib[s..s + w]);
                    ur.extend_from_slice(&up.rgb[3 * s..3 * (s + w)]);
                    match up.alpha {
                        Some(a) => ua.extend_from_slice(&a[s..s + w]),
                        None => ua.resize(ua.len() + w, F::zero()),
                    }
                    match up.depth {
                        Some(d) => ud.extend_from_slice(&d[s..s + w]),
                        None => ud.resize(ud.len() + w, F::zero()),
                    }
                }
                let upstream = TileUpstream {
                    rgb: ur,
                    alpha: ua,
                    depth: ud,
                };
                blend_tile_backward(r, local, ctx.background, ft, nc, &upstream, &mut grads);
                grads
            },
        )
        .collect();
    let mut splat_grads = vec![SplatGrad::<F>::default(); ctx.splats.len()];
    for (&k, g) in bins.entries.iter().zip(per_tile.iter().flatten()) {
        splat_grads[k as usize].add(g);
    }
    let mut visible_of = vec![u32::MAX; n];
    for (k, &i) in ctx.ids.iter().enumerate() {
        visible_of[i as usize] = k as u32;
    }

    // Per-Gaussian backward.
    out.resize_to(model);
    let kc = 3 * model.coeffs_per_channel();
    let cam = &ctx.camera;
    let (t, period) = (frame.time, ctx.period);
    (
        out.means.par_iter_mut(),
        out.log_scales.par_iter_mut(),
        out.rot_left.par_iter_mut(),
        out.rot_right.par_iter_mut(),
        out.opacity_logits.par_iter_mut(),
        out.colours.par_chunks_mut(kc),
        out.opacity_factor.par_iter_mut(),
        out.mean2d_norm.par_iter_mut(),
    )
        .into_par_iter()
        .enumerate()
        .with_min_len(256)
        .for_each(
            |(i, (g_mean, g_scale, g_ql, g_qr, g_o, g_col, g_f, g_norm))| {
                let z4 = [F::zero(); 4];
                (*g_mean, *g_scale, *g_ql, *g_qr) = (z4, z4, z4, z4);
                (*g_o, *g_f, *g_norm) = (F::zero(), F::zero(), F::zero());
                g_col.fill(F::zero());
                let k = visible_of[i];
                if k == u32::MAX {
                    return;
                }
                let sg = &splat_grads[k as usize];
                let Some((sl, sl_aux)) = slice(
                    model.means[i],
                    model.log_scales[i],
                    model.rot_left[i],
                    model.rot_right[i],
                    t,
                ) else {
                    return;
                };
                let Some((_, pr_aux)) = project(cam, sl.mean, &sl.factor) else {
                    return;
                };
                let factor = ctx.factor.as_ref().map_or(F::one(), |f| f[i]);
                let sig = sigmoid(model.opacity_logits[i]);
                *g_o = sg.opacity * sl.omega * factor * sig * (F::one() - sig);
                *g_f = sg.opacity * sig * sl.omega;
                let d_omega = sg.opacity * sig * factor;
                let input = colour_input(model, i, cam, t, period);
                let d_mean_colour =
                    colour_backward_masked(&input, ctx.colour_mask[k as usize], sg.colour, g_col);
                let (d_mean3, d_b) =
                    project_backward(cam, &pr_aux, &sl.factor, sg.mean, sg.conic, sg.depth);
                let sg4 = slice_backward(&sl, &sl_aux, d_omega, d_mean3, &d_b);
                for c in 0..4 {
                    g_mean[c] = sg4.mean[c] + d_mean_colour[c];
                }
                *g_scale = sg4.log_scales;
                *g_ql = sg4.rot_left;
                *g_qr = sg4.rot_right;
                *g_norm = (sg.mean[0] * sg.mean[0] + sg.mean[1] * sg.mean[1]).sqrt();
            },
        );
    if ctx.factor.is_none() {
        out.opacity_factor.clear();
    }
    Ok(())
}
