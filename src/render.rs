//! The public rendering API: `render(model, camera, t)` and its backward pass.
//! Orchestrates slice → colour → project → tiles → blend (forward) and the reverse chain
//! (backward). Per-Gaussian stages run in parallel over Gaussians, blending in parallel
//! over tiles; the backward accumulates per-tile gradients and reduces them per Gaussian
//! without atomics.

use crate::blend::{
    PixelRect, Splat, SplatGrad, TileOut, TileUpstream, blend_tile_backward, blend_tile_forward,
};
use crate::model::Gaussians;
use crate::numerics::{Real, sigmoid};
use crate::project::{PinholeCamera, project, project_backward};
use crate::sh::{ColourInput, colour_and_mask, colour_backward_masked};
use crate::slice::{slice, slice_backward};
use crate::tiles::{TILE, TileBins, bin_tiles, pixel_rect};
use crate::{Camera, blend::ALPHA_MIN};
use rayon::prelude::*;

/// Why a render (or its backward) was refused.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "camera '{camera}' has lens distortion; the renderer only draws pinhole images — undistort the frames and use the undistorted camera"
    )]
    DistortedCamera { camera: String },
    #[error("camera '{camera}' has an empty image ({width}×{height}); give it a positive size")]
    EmptyImage {
        camera: String,
        width: u32,
        height: u32,
    },
    #[error("camera '{camera}' has non-finite or non-positive focal lengths; check its intrinsics")]
    BadIntrinsics { camera: String },
    #[error("the model is inconsistent: {0}")]
    InconsistentModel(String),
    #[error("opacity factor has {got} values but the model has {expected} Gaussians")]
    OpacityFactorLength { expected: usize, got: usize },
    #[error("{what} gradient has {got} values, expected {expected} for this image")]
    GradientLength {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error(
        "backward called with a model of {got} Gaussians, but {expected} were rendered; pass the rendered model"
    )]
    ModelMismatch { expected: usize, got: usize },
}

/// Options of one render.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions<'a, F> {
    /// Colour seen where transmittance remains.
    pub background: [F; 3],
    /// Optional per-Gaussian multiplier on render opacity (the 4C4D neural decay `τ`);
    /// its gradient is returned in [`Gradients::opacity_factor`].
    pub opacity_factor: Option<&'a [F]>,
    /// Gaussians whose sliced mean is closer to the camera than this are culled.
    pub near_plane: F,
}

impl<F: Real> Default for RenderOptions<'_, F> {
    fn default() -> Self {
        Self {
            background: [F::zero(); 3],
            opacity_factor: None,
            near_plane: F::c(0.01),
        }
    }
}

/// A rendered image plus what the backward pass needs.
#[derive(Clone, Debug)]
pub struct Rendered<F: Real = f32> {
    pub width: u32,
    pub height: u32,
    /// RGB, row-major, 3 values per pixel (background composited).
    pub rgb: Vec<F>,
    /// Accumulated opacity `1 − T` per pixel.
    pub alpha: Vec<F>,
    /// `Σ wᵢ zᵢ` per pixel (camera depth weighted by blend weight; divide by alpha for
    /// the expected depth of the covered part).
    pub depth: Vec<F>,
    /// Per Gaussian: half-size of its 3σ box in pixels (max of x and y), 0 if it was not
    /// drawn (culled in time, behind the near plane, off-screen or transparent).
    pub radii: Vec<F>,
    ctx: Context<F>,
}

#[derive(Clone, Debug)]
struct Context<F: Real> {
    camera: PinholeCamera<F>,
    t: F,
    period: F,
    background: [F; 3],
    factor: Option<Vec<F>>,
    /// Model index of each visible splat.
    ids: Vec<u32>,
    splats: Vec<Splat<F>>,
    /// Per visible splat: its positive (unclamped) colour channels, for the backward.
    colour_mask: Vec<u8>,
    bins: TileBins,
    final_t: Vec<F>,
    n_contrib: Vec<u32>,
    evaluations: u64,
}

/// Upstream gradients dL/d(output) of a render; `None` means zero.
#[derive(Clone, Copy, Debug)]
pub struct ImageGradients<'a, F> {
    pub rgb: &'a [F],
    pub alpha: Option<&'a [F]>,
    pub depth: Option<&'a [F]>,
}

/// dL/d(parameters), laid out like [`Gaussians`] so an optimiser can step each group.
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients<F: Real = f32> {
    pub means: Vec<[F; 4]>,
    pub log_scales: Vec<[F; 4]>,
    pub rot_left: Vec<[F; 4]>,
    pub rot_right: Vec<[F; 4]>,
    pub opacity_logits: Vec<F>,
    /// Same layout as [`Gaussians::colours`].
    pub colours: Vec<F>,
    /// dL/d(opacity factor) per Gaussian; empty when no factor was given.
    pub opacity_factor: Vec<F>,
    /// `|dL/d(2D mean)|` per Gaussian in 1/pixel units (densification statistic).
    pub mean2d_norm: Vec<F>,
}

impl<F: Real> Gradients<F> {
    /// Resize to `model` (the opacity-factor gradient gets one entry per Gaussian). Old
    /// values stay: the per-Gaussian backward overwrites every entry, so the large colour
    /// array is written once per step instead of zeroed and then written.
    fn resize_to(&mut self, model: &Gaussians<F>) {
        let n = model.len();
        let z4 = [F::zero(); 4];
        for v in [
            &mut self.means,
            &mut self.log_scales,
            &mut self.rot_left,
            &mut self.rot_right,
        ] {
            v.resize(n, z4);
        }
        for v in [
            &mut self.opacity_logits,
            &mut self.opacity_factor,
            &mut self.mean2d_norm,
        ] {
            v.resize(n, F::zero());
        }
        self.colours.resize(model.colours.len(), F::zero());
    }

    /// All-zero gradients for `model`.
    pub fn zeros_like(model: &Gaussians<F>, with_factor: bool) -> Self {
        let n = model.len();
        Self {
            means: vec![[F::zero(); 4]; n],
            log_scales: vec![[F::zero(); 4]; n],
            rot_left: vec![[F::zero(); 4]; n],
            rot_right: vec![[F::zero(); 4]; n],
            opacity_logits: vec![F::zero(); n],
            colours: vec![F::zero(); model.colours.len()],
            opacity_factor: if with_factor {
                vec![F::zero(); n]
            } else {
                Vec::new()
            },
            mean2d_norm: vec![F::zero(); n],
        }
    }
}

/// Render `model` at model time `t` from `camera` with default options (black background).
pub fn render(
    model: &Gaussians<f32>,
    camera: &Camera,
    t: f32,
) -> Result<Rendered<f32>, RenderError> {
    render_with(model, camera, t, &RenderOptions::default())
}

fn pinhole<F: Real>(camera: &Camera, near: F) -> Result<PinholeCamera<F>, RenderError> {
    if !camera.distortion.is_none() {
        return Err(RenderError::DistortedCamera {
            camera: camera.name.clone(),
        });
    }
    let i = &camera.intrinsics;
    if i.width == 0 || i.height == 0 {
        return Err(RenderError::EmptyImage {
            camera: camera.name.clone(),
            width: i.width,
            height: i.height,
        });
    }
    if !(i.fx.is_finite()
        && i.fy.is_finite()
        && i.fx > 0.0
        && i.fy > 0.0
        && i.cx.is_finite()
        && i.cy.is_finite())
    {
        return Err(RenderError::BadIntrinsics {
            camera: camera.name.clone(),
        });
    }
    Ok(PinholeCamera::from_camera(camera, near))
}

fn period_of<F: Real>(model: &Gaussians<F>) -> F {
    let d = model.time.duration;
    F::c(if d.is_finite() && d > 0.0 { d } else { 1.0 })
}

fn tile_rect(bins: &TileBins, tile: usize, width: u32, height: u32) -> PixelRect {
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
    let cam = pinhole(camera, options.near_plane)?;
    let (width, height) = (cam.width, cam.height);
    let period = period_of(model);

    // Per-Gaussian stages, in parallel; the visible splats keep the Gaussians' order.
    let (ids, (splats, (rects, (colour_mask, radius)))): (
        Vec<u32>,
        (Vec<Splat<F>>, (Vec<[u32; 4]>, (Vec<u8>, Vec<F>))),
    ) = (0..n)
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
    Ok(Rendered {
        width,
        height,
        rgb,
        alpha,
        depth,
        radii,
        ctx: Context {
            camera: cam,
            t,
            period,
            background: options.background,
            factor: options.opacity_factor.map(|f| f.to_vec()),
            ids,
            splats,
            colour_mask,
            bins,
            final_t,
            n_contrib,
            evaluations,
        },
    })
}

fn colour_input<'a, F: Real>(
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

impl<F: Real> Rendered<F> {
    /// Number of Gaussians that were drawn.
    pub fn visible_count(&self) -> usize {
        self.ctx.ids.len()
    }

    /// Number of (tile, Gaussian) pairs blended.
    pub fn tile_pairs(&self) -> usize {
        self.ctx.bins.entries.len()
    }

    /// Splat-pixel evaluations of the forward blend (for throughput figures).
    pub fn blend_evaluations(&self) -> u64 {
        self.ctx.evaluations
    }

    /// The model time this image was rendered at.
    pub fn time(&self) -> F {
        self.ctx.t
    }

    /// Backward pass: dL/d(image) → dL/d(parameters) of `model` (the model that was rendered).
    pub fn backward(
        &self,
        model: &Gaussians<F>,
        up: &ImageGradients<F>,
    ) -> Result<Gradients<F>, RenderError> {
        let mut out = Gradients::zeros_like(model, self.ctx.factor.is_some());
        self.backward_into(model, up, &mut out)?;
        Ok(out)
    }

    /// [`Rendered::backward`] into a reused buffer (resized and overwritten, not added to):
    /// saves allocating and faulting in the large colour-gradient array every step.
    pub fn backward_into(
        &self,
        model: &Gaussians<F>,
        up: &ImageGradients<F>,
        out: &mut Gradients<F>,
    ) -> Result<(), RenderError> {
        let n = model.len();
        let expected = self
            .ctx
            .factor
            .as_ref()
            .map_or(self.radii.len(), |f| f.len());
        if n != self.radii.len() || n != expected {
            return Err(RenderError::ModelMismatch {
                expected: self.radii.len(),
                got: n,
            });
        }
        model
            .check_consistent()
            .map_err(RenderError::InconsistentModel)?;
        let (width, height) = (self.width, self.height);
        let npix = width as usize * height as usize;
        let check = |what, got: usize, want| {
            if got == want {
                Ok(())
            } else {
                Err(RenderError::GradientLength {
                    what,
                    expected: want,
                    got,
                })
            }
        };
        check("rgb", up.rgb.len(), 3 * npix)?;
        if let Some(a) = up.alpha {
            check("alpha", a.len(), npix)?;
        }
        if let Some(d) = up.depth {
            check("depth", d.len(), npix)?;
        }
        let ctx = &self.ctx;
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
        let (t, period) = (ctx.t, ctx.period);
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
                    let d_mean_colour = colour_backward_masked(
                        &input,
                        ctx.colour_mask[k as usize],
                        sg.colour,
                        g_col,
                    );
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
}
