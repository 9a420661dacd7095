//! The CPU renderer: per-Gaussian stages in parallel over Gaussians (slice → colour →
//! project), binning into 16×16 tiles ([`tiles`]), blending in parallel over tiles
//! ([`blend`]); the backward ([`backward`]) accumulates per-tile gradients and reduces
//! them per Gaussian without atomics. Generic over the float type: `f64` for checks.

pub mod backward;
pub mod blend;
pub mod tiles;

pub use backward::{backward, backward_into};

use super::{
    RenderBackend, RenderError, RenderOptions, RenderStats, Rendered, ViewRequest, checked_pinhole,
    period_of,
};
use crate::Camera;
use crate::math::numerics::{Real, sigmoid};
use crate::math::project::{PinholeCamera, project};
use crate::math::sh::{ColourInput, colour_and_mask};
use crate::math::slice::slice;
use crate::model::Gaussians;
use blend::{ALPHA_MIN, PixelRect, Splat, TileOut, blend_tile_forward};
use rayon::prelude::*;
use std::sync::Arc;
use tiles::{TILE, TileBins, bin_tiles, pixel_rect};

/// The CPU backend (rayon's global thread pool).
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuBackend;

impl RenderBackend for CpuBackend {
    fn describe(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }

    fn render_batch(
        &self,
        model: &Gaussians<f32>,
        views: &[ViewRequest<'_>],
    ) -> Result<Vec<Rendered<f32>>, RenderError> {
        views
            .iter()
            .map(|v| render_with(model, v.camera, v.t, &v.options))
            .collect()
    }

    fn backward(
        &self,
        model: &Gaussians<f32>,
        frame: &Rendered<f32>,
        up: &super::ImageGradients<f32>,
        out: &mut super::Gradients<f32>,
    ) -> Result<(), RenderError> {
        backward_into(frame, model, up, out)
    }
}

/// What the CPU backward needs from its forward.
pub(crate) struct Context<F: Real> {
    pub(crate) camera: PinholeCamera<F>,
    pub(crate) period: F,
    pub(crate) background: [F; 3],
    pub(crate) factor: Option<Vec<F>>,
    /// Model index of each visible splat.
    pub(crate) ids: Vec<u32>,
    pub(crate) splats: Vec<Splat<F>>,
    /// Per visible splat: its positive (unclamped) colour channels, for the backward.
    pub(crate) colour_mask: Vec<u8>,
    pub(crate) bins: TileBins,
    pub(crate) final_t: Vec<F>,
    pub(crate) n_contrib: Vec<u32>,
}

/// Render `model` at model time `t` from `camera` with default options (black background).
pub fn render(
    model: &Gaussians<f32>,
    camera: &Camera,
    t: f32,
) -> Result<Rendered<f32>, RenderError> {
    render_with(model, camera, t, &RenderOptions::default())
}
pub(crate) fn tile_rect(bins: &TileBins, tile: usize, width: u32, height: u32) -> PixelRect {
    let tx = tile as u32 % bins.tiles_x;
    let ty = tile as u32 / bins.tiles_x;
    PixelRect {
        x0: tx * TILE,
        y0: ty * TILE,
        x1: ((tx + 1) * TILE).min(width),
        y1: ((ty + 1) * TILE).min(height),
    }
}
/// Render with explicit options. Generic over the float type (`f64` for checks).
pub fn render_with<F: Real>(
    model: &Gaussians<F>,
    camera: &Camera,
    t: F,
    options: &RenderOptions<F>,
) -> Result<Rendered<F>, RenderError> {
    model
        .check_consistent()
        .map_err(RenderError::InconsistentModel)?;
    let n = model.len();
    if let Some(f) = options.opacity_factor
        && f.len() != n
    {
        return Err(RenderError::OpacityFactorLength {
            expected: n,
            got: f.len(),
        });
    }
    let cam = checked_pinhole(camera, options.near_plane)?;
    let (width, height) = (cam.width, cam.height);
    let period = period_of(model);

    // Per-Gaussian stages, in parallel; the visible splats keep the Gaussians' order.
    type Columns<F> = (
        Vec<u32>,
        (Vec<Splat<F>>, (Vec<[u32; 4]>, (Vec<u8>, Vec<F>))),
    );
    let (ids, (splats, (rects, (colour_mask, radius)))): Columns<F> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .filter_map(|i| {
            let (sl, _) = slice(
                model.means[i],
                model.log_scales[i],
                model.rot_left[i],
                model.rot_right[i],
                t,
            )?;
            let factor = options.opacity_factor.map_or(F::one(), |f| f[i]);
            let opacity = sigmoid(model.opacity_logits[i]) * sl.omega * factor;
            if !(opacity >= F::c(ALPHA_MIN)) {
                return None;
            }
            let (pr, _) = project(&cam, sl.mean, &sl.factor)?;
            let input = colour_input(model, i, &cam, t, period);
            let (rgb, mask) = colour_and_mask(&input);
            let splat = Splat::new(pr.mean, pr.conic, opacity, rgb, pr.depth);
            let rect = pixel_rect(splat.rect, width, height)?;
            let radius = pr.extent[0].max(pr.extent[1]);
            Some((i as u32, (splat, (rect, (mask, radius)))))
        })
        .unzip();
    let mut radii = vec![F::zero(); n];
    for (&i, r) in ids.iter().zip(radius) {
        radii[i as usize] = r;
    }
    let depths: Vec<F> = splats.iter().map(|s| s.depth).collect();
    let bins = bin_tiles(&rects, &depths, width, height);

    // Blend tiles.
    let tiles: Vec<TileOut<F>> = (0..bins.tile_count())
        .into_par_iter()
        .map_init(Vec::new, |local: &mut Vec<Splat<F>>, tile| {
            local.clear();
            local.extend(bins.tile(tile).iter().map(|&k| splats[k as usize]));
            let mut out = TileOut::default();
            blend_tile_forward(
                tile_rect(&bins, tile, width, height),
                local,
                options.background,
                &mut out,
            );
            out
        })
        .collect();
    // Copy the tiles into the images, one band of tile rows per task.
    let (w_px, band) = (width as usize, TILE as usize * width as usize);
    let npix = w_px * height as usize;
    let mut rgb = vec![F::zero(); 3 * npix];
    let mut alpha = vec![F::zero(); npix];
    let mut depth = vec![F::zero(); npix];
    let mut final_t = vec![F::one(); npix];
    let mut n_contrib = vec![0u32; npix];
    (
        rgb.par_chunks_mut(3 * band),
        alpha.par_chunks_mut(band),
        depth.par_chunks_mut(band),
        final_t.par_chunks_mut(band),
        n_contrib.par_chunks_mut(band),
    )
        .into_par_iter()
        .enumerate()
        .for_each(|(ty, (rgb, alpha, depth, final_t, n_contrib))| {
            for tx in 0..bins.tiles_x as usize {
                let tile = ty * bins.tiles_x as usize + tx;
                let (r, out) = (tile_rect(&bins, tile, width, height), &tiles[tile]);
                let w = (r.x1 - r.x0) as usize;
                for y in r.y0..r.y1 {
                    let src = (y - r.y0) as usize * w;
                    let dst = (y - r.y0) as usize * w_px + r.x0 as usize;
                    rgb[3 * dst..3 * (dst + w)].copy_from_slice(&out.rgb[3 * src..3 * (src + w)]);
                    alpha[dst..dst + w].copy_from_slice(&out.alpha[src..src + w]);
                    depth[dst..dst + w].copy_from_slice(&out.depth[src..src + w]);
                    final_t[dst..dst + w].copy_from_slice(&out.final_t[src..src + w]);
                    n_contrib[dst..dst + w].copy_from_slice(&out.n_contrib[src..src + w]);
                }
            }
        });
    let evaluations = tiles.iter().map(|o| o.evaluations).sum();
    let stats = RenderStats {
        visible: ids.len(),
        tile_pairs: bins.entries.len(),
        blend_evaluations: evaluations,
    };
    Ok(Rendered {
        width,
        height,
        rgb,
        alpha,
        depth,
        radii,
        time: t,
        stats,
        state: Arc::new(Context {
            camera: cam,
            period,
            background: options.background,
            factor: options.opacity_factor.map(|f| f.to_vec()),
            ids,
            splats,
            colour_mask,
            bins,
            final_t,
            n_contrib,
        }),
    })
}

pub(crate) fn colour_input<'a, F: Real>(
    model: &'a Gaussians<F>,
    i: usize,
    cam: &PinholeCamera<F>,
    t: F,
    period: F,
) -> ColourInput<'a, F> {
    ColourInput {
        mean: model.means[i],
        coeffs: model.colour_of(i),
        capacity: model.capacity,
        active: model.active,
        camera_centre: cam.centre,
        t,
        period,
    }
}
