//! One training iteration on the device, on the parameters a [`GpuAdam`] keeps resident:
//! render the batch's views, then in one submission per view the loss against its target
//! (uploaded once as bytes, converted on the device), the backward from the loss's image
//! gradient (weighted 1/batch), the views' gradients added in batch order, and the Adam
//! step; one 16-byte loss total per view is read back (and the render's count of
//! (tile, splat) pairs, to size its sort). The rendered images stay on the device. With
//! [`GpuStats`] the step also adds each view's densification statistics on the device.
//! A view with a [`VirtualView`] renders it too and adds the pseudo-view term (the host's
//! `train::pseudo_view::consistency`, `shaders/pseudo.wgsl`): into the view's upstream
//! alpha and depth planes, and through the virtual render's backward into the batch's
//! gradients.
//! The anisotropy cap and hooks are not part of the step (the trainer runs them on the
//! host, see `train::device_step`).

use super::adam::GpuAdam;
use super::kernels::TrainKernels;
use super::loss::{LossPass, pack_bytes, unpack};
use super::stats::GpuStats;
use crate::Camera;
use crate::decay::gpu::{DecayOutcome, GpuDecay, RESULT_BYTES};
use crate::gpu::compute::{Kernel, read_buffer, storage, storage_init, uniform};
use crate::gpu::pool::Pooled;
use crate::model::Gaussians;
use crate::render::gpu::{GpuBackend, GpuFrame, ModelBuffers, PARAM_FLOATS, encode_backward};
use crate::render::{RenderError, RenderOptions, Rendered, ViewRequest};
use crate::train::dataset::ImageU8;
use crate::train::loss::LossValue;
use crate::train::optim::GroupRates;
use crate::train::pseudo_view::VirtualView;
use std::sync::Arc;

/// A target image on the device: its bytes, four to a word.
pub struct GpuImage {
    packed: wgpu::Buffer,
    width: u32,
    height: u32,
}

/// One view of a training batch.
pub struct TrainView<'a> {
    /// Pinhole camera of the view, sized like its target.
    pub camera: &'a Camera,
    /// Model time of the view.
    pub t: f32,
    /// The view's image, uploaded with [`GpuTraining::upload_image`](super::GpuTraining).
    pub target: &'a GpuImage,
    /// The view's pseudo view, when it gets one this step.
    pub pseudo: Option<VirtualView>,
}

/// The pseudo-view term's constants (`Pseudo` in `shaders/pseudo.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PseudoUniform {
    size: [u32; 4],
    focal: [f32; 4],
    shift: [f32; 4],
}

/// What one iteration gives back.
pub struct StepResult {
    /// The loss of each view (unweighted by the batch).
    pub losses: Vec<LossValue>,
    /// What the decay did, when the step ran it.
    pub decay: Option<DecayOutcome>,
}

/// Upload a training image once (as bytes): [`GpuTraining::upload_image`](super::GpuTraining).
pub(super) fn upload_image(backend: &GpuBackend, image: &ImageU8) -> Result<GpuImage, RenderError> {
    let expected = 3 * image.width as u64 * image.height as u64;
    if image.data.len() as u64 != expected {
        return Err(RenderError::ImageLength {
            what: "training image",
            expected,
            got: image.data.len(),
        });
    }
    backend.too_large("the training image", image.data.len() as u64)?;
    backend.checked(|| {
        Ok(GpuImage {
            packed: storage_init(&backend.gpu.device, &pack_bytes(&image.data), "target"),
            width: image.width,
            height: image.height,
        })
    })
}

impl GpuAdam {
    /// One training iteration of `views` (one batch) on the resident parameters: render,
    /// loss `(1 − λ)·L1 + λ·(1 − SSIM)`, backward, gradients summed over the batch with
    /// weight 1/batch, one Adam step with `rates`. `model` gives the layout and schedule
    /// (active colour degrees, time mapping); its values are not read.
    pub fn train_step(
        &mut self,
        backend: &GpuBackend,
        model: &Gaussians<f32>,
        views: &[TrainView<'_>],
        background: [f32; 3],
        lambda_ssim: f64,
        rates: &GroupRates,
    ) -> Result<StepResult, RenderError> {
        self.train_step_decayed(
            backend,
            model,
            views,
            background,
            lambda_ssim,
            rates,
            None,
            None,
        )
    }

    /// [`GpuAdam::train_step`], adding every view's densification statistics into
    /// `stats` on the device (as `DensifyStats::record` does with the view's own
    /// gradient: the 1/batch weight undone), and, with `decay`, the 4C4D decay: for the
    /// neural variant (f_θ resident on the device) every view renders its visible
    /// Gaussians with opacity factor τ and f_θ is trained on the summed dL/dτ; after the
    /// Adam step the stored opacities are decayed (the variant's factor where seen in the
    /// batch, β elsewhere); see [`GpuDecay`]. 32 more bytes come back.
    #[allow(clippy::too_many_arguments)]
    pub fn train_step_decayed(
        &mut self,
        backend: &GpuBackend,
        model: &Gaussians<f32>,
        views: &[TrainView<'_>],
        background: [f32; 3],
        lambda_ssim: f64,
        rates: &GroupRates,
        stats: Option<&GpuStats>,
        mut decay: Option<&mut GpuDecay>,
    ) -> Result<StepResult, RenderError> {
        self.same_device(backend)?;
        self.check_count(model.len())?;
        if let Some(s) = stats
            && s.len() != self.count
        {
            return Err(RenderError::ModelMismatch {
                expected: self.count,
                got: s.len(),
            });
        }
        if model.colours.len() != self.colour_len {
            return Err(RenderError::InconsistentModel(format!(
                "{} colour values, {} uploaded",
                model.colours.len(),
                self.colour_len
            )));
        }
        let request = |camera, t| ViewRequest {
            camera,
            t,
            options: RenderOptions {
                background,
                ..Default::default()
            },
        };
        // The training views, then the virtual views of those that have one.
        let mut requests: Vec<ViewRequest<'_>> =
            views.iter().map(|v| request(v.camera, v.t)).collect();
        for v in views {
            if let Some(p) = &v.pseudo {
                requests.push(request(&p.camera, v.t));
            }
        }
        let mut prepared = requests
            .iter()
            .map(|r| backend.prepare(model, r))
            .collect::<Result<Vec<_>, _>>()?;
        let virtual_prepared = prepared.split_off(views.len());
        for (p, v) in prepared.iter().zip(views) {
            let (w, h) = (p.uniform.width, p.uniform.height);
            if (w, h) != (v.target.width, v.target.height) {
                return Err(RenderError::ImageLength {
                    what: "target image",
                    expected: 3 * w as u64 * h as u64,
                    got: 3 * v.target.width as usize * v.target.height as usize,
                });
            }
            backend.too_large("the loss's partials", 60 * w as u64 * h as u64)?;
        }
        if views.is_empty() {
            return Ok(StepResult {
                losses: Vec::new(),
                decay: None,
            });
        }
        let n = self.count;
        if let Some(d) = decay.as_deref_mut() {
            let uniforms: Vec<_> = prepared.iter().map(|p| p.uniform).collect();
            if let Some(factors) = d.begin_step(backend, &self.params.params, n, &uniforms)? {
                for (p, f) in prepared.iter_mut().zip(factors) {
                    p.factor = Some(f);
                }
            }
        }
        // A virtual view renders with its training view's opacity factor, as on the host.
        let owners = views.iter().enumerate().filter(|(_, v)| v.pseudo.is_some());
        for ((owner, _), mut p) in owners.zip(virtual_prepared) {
            p.factor = prepared[owner].factor.clone();
            prepared.push(p);
        }
        let frames = backend.checked(|| {
            let uploaded = Arc::new(ModelBuffers {
                params: self.params.params.clone(),
                colours: self.params.colours.clone(),
                ones: self.ones.clone(),
                count: n,
                colour_len: self.colour_len,
            });
            backend.render_uploaded(uploaded, &requests, prepared, false)
        })?;
        let (losses, words) = backend.checked(|| {
            self.encode_and_run(
                backend,
                &frames,
                views,
                lambda_ssim,
                rates,
                stats,
                decay.as_deref(),
            )
        })?;
        self.stepped();
        let decay = decay.map(|d| d.finish_step(&words));
        Ok(StepResult { losses, decay })
    }

    /// Loss, backward and gradient sums of every view, then Adam (and the decay's parts):
    /// one submission. Returns the losses and the decay's result words.
    #[allow(clippy::too_many_arguments)]
    fn encode_and_run(
        &self,
        backend: &GpuBackend,
        frames: &[Rendered<f32>],
        views: &[TrainView<'_>],
        lambda_ssim: f64,
        rates: &GroupRates,
        stats: Option<&GpuStats>,
        decay: Option<&GpuDecay>,
    ) -> Result<(Vec<LossValue>, Vec<u32>), RenderError> {
        let device = &backend.gpu.device;
        let k = &self.kernels;
        let scale = 1.0 / views.len() as f32;
        let loss_bytes = 16 * views.len() as u64;
        let decay_bytes = if decay.is_some() { RESULT_BYTES } else { 0 };
        let staging = read_buffer(device, loss_bytes + decay_bytes);
        let mut enc = device.create_command_encoder(&Default::default());
        let param_words = (PARAM_FLOATS * self.count) as u32;
        let colour_words = self.colour_len as u32;
        // Later views' and virtual views' gradients, added into the batch's (none with one
        // view and no virtual one).
        let (training, virtual_frames) = frames.split_at(views.len());
        let parts = views.len() > 1 || !virtual_frames.is_empty();
        let mut virtual_frames = virtual_frames.iter();
        let virtual_of: Vec<Option<&Rendered<f32>>> = views
            .iter()
            .map(|v| v.pseudo.as_ref().and_then(|_| virtual_frames.next()))
            .collect();
        let part_bytes = |words: u32| if parts { 4 * words as u64 } else { 0 };
        let part_params = storage(device, part_bytes(param_words), "view gradients");
        let part_colours = storage(device, part_bytes(colour_words), "view colour gradients");
        let mut passes = Vec::with_capacity(views.len());
        let add_part = |enc: &mut wgpu::CommandEncoder| {
            let mut pass = enc.begin_compute_pass(&Default::default());
            for (words, part, sum) in [
                (param_words, &part_params, &self.grads.params),
                (colour_words, &part_colours, &self.grads.colours),
            ] {
                let len = uniform(device, &[words, 0, 0, 0]);
                let bind = k.add_into.bind(device, &[&len, part, sum]);
                k.add_into.dispatch_items(&mut pass, &bind, words);
            }
        };
        for (v, ((frame, view), virtual_frame)) in
            training.iter().zip(views).zip(virtual_of).enumerate()
        {
            let state = gpu_frame(frame)?;
            let (w, h) = (frame.width, frame.height);
            let npix = w as u64 * h as u64;
            let target = unpack(device, k, &mut enc, &view.target.packed, 3 * npix as u32);
            // RGB, alpha and depth planes; the loss writes RGB, the rest stay zero.
            let upstream = backend.gpu.scratch(20 * npix, "upstream gradients");
            enc.clear_buffer(&upstream, 0, None);
            let loss = LossPass::new(
                &backend.gpu,
                k,
                (w, h),
                &state.buffers.rgb,
                &target,
                lambda_ssim,
                scale,
                Some(&upstream),
            );
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                loss.encode(k, &mut pass);
            }
            enc.copy_buffer_to_buffer(&loss.sums, loss.total_offset(), &staging, 16 * v as u64, 16);
            // The pseudo view: the training view's alpha and depth gradients into
            // `upstream`, the virtual view's into its own upstream.
            let pseudo = match (&view.pseudo, virtual_frame) {
                (Some(p), Some(virtual_frame)) => {
                    let virtual_state = gpu_frame(virtual_frame)?;
                    let virtual_upstream = encode_pseudo(
                        backend,
                        k,
                        &mut enc,
                        (view.camera, p, (w, h)),
                        (state, &target, &upstream),
                        virtual_state,
                    );
                    Some((virtual_state, virtual_upstream))
                }
                _ => None,
            };
            let (out_params, out_colours) = if v == 0 {
                (&self.grads.params, &self.grads.colours)
            } else {
                (&part_params, &part_colours)
            };
            // Culled Gaussians get no record: start from zeros.
            enc.clear_buffer(out_params, 0, None);
            enc.clear_buffer(out_colours, 0, None);
            encode_backward(backend, state, &upstream, out_params, out_colours, &mut enc);
            if let Some(d) = decay {
                d.encode_gather(backend, &mut enc, v, &self.params.params, out_params);
            }
            if let Some(s) = stats {
                // As `DensifyStats::record` with gain = batch size.
                let to_ndc = 0.5 * w.max(h) as f32 * views.len() as f32;
                s.encode_record(backend, &mut enc, out_params, &state.buffers.radii, to_ndc);
            }
            if v > 0 {
                add_part(&mut enc);
            }
            // As on the host: the virtual view's gradient joins the batch's, not the
            // view's statistics or its decay factor's gradient.
            if let Some((virtual_state, virtual_upstream)) = pseudo {
                enc.clear_buffer(&part_params, 0, None);
                enc.clear_buffer(&part_colours, 0, None);
                encode_backward(
                    backend,
                    virtual_state,
                    &virtual_upstream,
                    &part_params,
                    &part_colours,
                    &mut enc,
                );
                add_part(&mut enc);
            }
            passes.push(loss);
        }
        if let Some(d) = decay {
            // f_θ's step reads the pre-step model: before the Gaussians' Adam.
            d.encode_mlp_step(backend, &mut enc, &self.params.params);
        }
        self.encode_step(rates, &mut enc);
        if let Some(d) = decay {
            d.encode_apply(backend, &mut enc, &self.params.params, &staging, loss_bytes);
        }
        let words = backend.read_back(enc, &staging, loss_bytes + decay_bytes)?;
        let (loss_words, decay_words) = words.split_at(4 * views.len());
        let floats: &[f32] = bytemuck::cast_slice(loss_words);
        let losses = passes
            .iter()
            .zip(floats.chunks_exact(4))
            .map(|(p, t)| p.value([t[0], t[1], t[2], t[3]], lambda_ssim))
            .collect();
        Ok((losses, decay_words.to_vec()))
    }
}

/// The device state of a frame the GPU backend rendered.
fn gpu_frame(frame: &Rendered<f32>) -> Result<&GpuFrame, RenderError> {
    frame
        .state
        .downcast_ref::<GpuFrame>()
        .ok_or(RenderError::WrongBackend { backend: "gpu" })
}

/// Record the pseudo-view term of one training view (`state`, its unpacked `target` and
/// its `upstream` planes, whose alpha and depth planes it writes) against its virtual
/// view's render (`virtual_state`); returns the virtual view's upstream planes.
fn encode_pseudo(
    backend: &GpuBackend,
    k: &TrainKernels,
    enc: &mut wgpu::CommandEncoder,
    (camera, view, (w, h)): (&Camera, &VirtualView, (u32, u32)),
    (state, target, upstream): (&GpuFrame, &wgpu::Buffer, &wgpu::Buffer),
    virtual_state: &GpuFrame,
) -> Pooled {
    let device = &backend.gpu.device;
    let npix = w * h;
    let i = &camera.intrinsics;
    let constants = PseudoUniform {
        size: [w, h, npix, 0],
        focal: [i.fx, i.fy, i.cx, i.cy].map(|v| v as f32),
        shift: [
            view.shift[0] as f32,
            view.shift[1] as f32,
            view.weight / (3 * npix) as f32,
            0.0,
        ],
    };
    let constants = uniform(device, &constants);
    let virtual_upstream = backend.gpu.scratch(20 * npix as u64, "virtual upstream");
    let sums = backend.gpu.scratch(12 * npix as u64, "pseudo-view sums");
    enc.clear_buffer(&virtual_upstream, 0, None);
    enc.clear_buffer(&sums, 0, None);
    let (b, vb) = (&state.buffers, &virtual_state.buffers);
    let reads = [
        &constants, target, &b.alpha, &b.depth, &vb.rgb, &vb.alpha, &vb.depth,
    ];
    let bind = |out: &wgpu::Buffer, kernel: &Kernel| {
        let mut slots: Vec<&wgpu::Buffer> = reads.to_vec();
        slots.extend([out, &sums]);
        kernel.bind(device, &slots)
    };
    let land = bind(upstream, &k.pseudo_land);
    let resolve = bind(&virtual_upstream, &k.pseudo_resolve);
    let mut pass = enc.begin_compute_pass(&Default::default());
    k.pseudo_land.dispatch_items(&mut pass, &land, npix);
    k.pseudo_resolve
        .dispatch_items(&mut pass, &resolve, 3 * npix);
    drop(pass);
    virtual_upstream
}
