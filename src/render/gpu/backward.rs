//! Host side of the GPU backward pass: from dL/d(image) to dL/d(parameters) of a frame the
//! GPU rendered, in one submission and one read-back.
//!
//! `rasterise_backward` (`shaders/raster_backward.wgsl`, one workgroup per 16×16 tile,
//! back to front over the forward's sorted entries) writes one gradient record per
//! (tile, Gaussian) entry, at the slot `emit` gave that entry, reduced over the tile's
//! pixels in workgroup memory; `preprocess_backward` (`shaders/preprocess_backward.wgsl`,
//! one thread per Gaussian) adds a Gaussian's records in tile order — its slots are
//! contiguous — and chains them through colour, projection and slicing. No atomics on
//! floats anywhere, so the result is the same on every run, and it adds the per-tile
//! terms in the order the CPU backward does.

use super::{GpuBackend, GpuFrame};
use crate::gpu::compute::{read_buffer, storage, storage_init};
use crate::model::Gaussians;
use crate::render::{Gradients, ImageGradients, RenderError, Rendered, check_backward_inputs};
use std::sync::Arc;

/// Bytes of one (tile, Gaussian) gradient record: three vec4 (`partials` in the shaders).
const PARTIAL_BYTES: u64 = 48;
/// Floats of one Gaussian's non-colour gradients (five vec4, like the uploaded params).
pub(crate) const PARAM_FLOATS: usize = 20;

/// [`crate::render::RenderBackend::backward`] of the GPU backend.
pub(super) fn backward(
    backend: &GpuBackend,
    model: &Gaussians<f32>,
    frame: &Rendered<f32>,
    up: &ImageGradients<f32>,
    out: &mut Gradients<f32>,
) -> Result<(), RenderError> {
    let wrong = RenderError::WrongBackend { backend: "gpu" };
    let state = frame.state.downcast_ref::<GpuFrame>().ok_or(wrong)?;
    if !Arc::ptr_eq(&state.gpu, &backend.gpu) {
        return Err(RenderError::WrongBackend { backend: "gpu" });
    }
    let n = model.len();
    check_backward_inputs(frame, model, state.factor.as_ref().map(|_| n), up)?;
    if state.model.count != n || state.model.colour_len != model.colours.len() {
        return Err(RenderError::ModelMismatch {
            expected: state.model.count,
            got: n,
        });
    }
    backend.too_large(
        "the backward's (tile, splat) gradients",
        PARTIAL_BYTES * state.pairs as u64,
    )?;
    backend.too_large("the gradients", 4 * (PARAM_FLOATS * n) as u64)?;
    let (params, colours) = backend.checked(|| run(backend, state, frame, up))?;
    unpack(model, &params, &colours, state.factor.is_some(), out);
    Ok(())
}

/// Record both kernels, submit once, read the gradient buffers back once.
fn run(
    backend: &GpuBackend,
    state: &GpuFrame,
    frame: &Rendered<f32>,
    up: &ImageGradients<f32>,
) -> Result<(Vec<f32>, Vec<f32>), RenderError> {
    let device = &backend.gpu.device;
    let n = state.model.count;
    let colour_len = state.model.colour_len;
    let npix = frame.width as usize * frame.height as usize;

    // Upstream gradients as planes: RGB, alpha, depth (zeros where not given).
    let mut upstream = Vec::with_capacity(5 * npix);
    upstream.extend_from_slice(up.rgb);
    for plane in [up.alpha, up.depth] {
        match plane {
            Some(p) => upstream.extend_from_slice(p),
            None => upstream.resize(upstream.len() + npix, 0.0),
        }
    }
    let upstream = storage_init(device, &upstream, "upstream gradients");
    let out_params = storage(device, 4 * (PARAM_FLOATS * n) as u64, "gradients");
    let out_colours = storage(device, 4 * colour_len as u64, "colour gradients");
    let param_words = (PARAM_FLOATS * n) as u64;
    let total_words = param_words + colour_len as u64;
    let staging = read_buffer(device, 4 * total_words);

    let mut enc = device.create_command_encoder(&Default::default());
    encode(
        backend,
        state,
        &upstream,
        &out_params,
        &out_colours,
        &mut enc,
    );
    if param_words > 0 {
        enc.copy_buffer_to_buffer(&out_params, 0, &staging, 0, 4 * param_words);
    }
    if colour_len > 0 {
        enc.copy_buffer_to_buffer(
            &out_colours,
            0,
            &staging,
            4 * param_words,
            4 * colour_len as u64,
        );
    }
    let words = backend.read_back(enc, &staging, 4 * total_words)?;
    let floats: &[f32] = bytemuck::cast_slice(&words);
    let (params, colours) = floats.split_at(param_words as usize);
    Ok((params.to_vec(), colours.to_vec()))
}

/// Record both kernels of `state`'s backward from `upstream` (RGB, alpha and depth planes
/// of the image gradient) into `out_params` (five vec4 per Gaussian) and `out_colours`.
pub(crate) fn encode(
    backend: &GpuBackend,
    state: &GpuFrame,
    upstream: &wgpu::Buffer,
    out_params: &wgpu::Buffer,
    out_colours: &wgpu::Buffer,
    enc: &mut wgpu::CommandEncoder,
) {
    let device = &backend.gpu.device;
    let k = &backend.kernels;
    let b = &state.buffers;
    let n = state.model.count;
    let partials = backend
        .gpu
        .scratch(PARTIAL_BYTES * state.pairs as u64, "per-tile gradients");
    // Entries no pixel reached keep a zero record.
    enc.clear_buffer(&partials, 0, None);
    if n == 0 {
        return;
    }
    let factor = state.factor.as_ref().unwrap_or(&state.model.ones);
    let raster = k.rasterise_backward.bind(
        device,
        &[
            &state.view,
            &b.splats,
            &b.values,
            &b.ranges,
            &b.pixels,
            upstream,
            &b.ends,
            &partials,
        ],
    );
    let per_gaussian = k.preprocess_backward.bind(
        device,
        &[
            &state.view,
            &state.model.params,
            &state.model.colours,
            factor,
            &b.counts,
            &b.ends,
            &partials,
            out_params,
            out_colours,
        ],
    );
    let mut pass = enc.begin_compute_pass(&Default::default());
    if state.pairs > 0 {
        let u = &state.uniform;
        k.rasterise_backward
            .dispatch_grid(&mut pass, &raster, [u.tiles_x, u.tiles_y, 1]);
    }
    k.preprocess_backward
        .dispatch_items(&mut pass, &per_gaussian, n as u32);
}

/// Scatter the read-back gradient records into `out`, laid out like the model.
fn unpack(
    model: &Gaussians<f32>,
    params: &[f32],
    colours: &[f32],
    with_factor: bool,
    out: &mut Gradients<f32>,
) {
    out.resize_to(model);
    let vec4 = |i: usize, k: usize| -> [f32; 4] {
        let at = PARAM_FLOATS * i + 4 * k;
        [params[at], params[at + 1], params[at + 2], params[at + 3]]
    };
    for i in 0..model.len() {
        out.means[i] = vec4(i, 0);
        out.log_scales[i] = vec4(i, 1);
        out.rot_left[i] = vec4(i, 2);
        out.rot_right[i] = vec4(i, 3);
        let [logit, factor, norm, _] = vec4(i, 4);
        out.opacity_logits[i] = logit;
        out.opacity_factor[i] = factor;
        out.mean2d_norm[i] = norm;
    }
    out.colours.copy_from_slice(colours);
    if !with_factor {
        out.opacity_factor.clear();
    }
}
