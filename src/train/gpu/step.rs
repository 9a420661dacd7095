//! One training iteration on the device, on the parameters a [`GpuAdam`] keeps resident:
//! render the batch's views, then in one submission per view the loss against its target
//! (uploaded once as bytes, converted on the device), the backward from the loss's image
//! gradient (weighted 1/batch), the views' gradients added in batch order, and the Adam
//! step; one 16-byte loss total per view is read back (and the render's count of
//! (tile, splat) pairs, to size its sort). The rendered images stay on the device. With
//! [`GpuStats`] the step also adds each view's densification statistics on the device.
//! The anisotropy cap and hooks are not part of the step (the trainer runs them on the
//! host, see `train::device_step`).

use super::adam::GpuAdam;
use super::loss::{LossPass, pack_bytes, unpack};
use super::stats::GpuStats;
use crate::Camera;
use crate::decay::gpu::{DecayOutcome, GpuDecay, RESULT_BYTES};
use crate::gpu::compute::{read_buffer, storage, storage_init, uniform};
use crate::model::Gaussians;
use crate::render::gpu::{GpuBackend, GpuFrame, ModelBuffers, PARAM_FLOATS, encode_backward};
use crate::render::{RenderError, RenderOptions, Rendered, ViewRequest};
use crate::train::dataset::ImageU8;
use crate::train::loss::LossValue;
use crate::train::optim::GroupRates;
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
        let requests: Vec<ViewRequest<'_>> = views
            .iter()
            .map(|v| ViewRequest {
                camera: v.camera,
                t: v.t,
                options: RenderOptions {
                    background,
                    ..Default::default()
                },
            })
            .collect();
        let mut prepared = requests
            .iter()
            .map(|r| backend.prepare(model, r))
            .collect::<Result<Vec<_>, _>>()?;
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
        // Later views' gradients, added into the batch's (none with one view).
        let part_bytes = |words: u32| if views.len() > 1 { 4 * words as u64 } else { 0 };
        let part_params = storage(device, part_bytes(param_words), "view gradients");
        let part_colours = storage(device, part_bytes(colour_words), "view colour gradients");
        let mut passes = Vec::with_capacity(views.len());
        for (v, (frame, view)) in frames.iter().zip(views).enumerate() {
            let state = frame
                .state
                .downcast_ref::<GpuFrame>()
                .ok_or(RenderError::WrongBackend { backend: "gpu" })?;
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
                let mut pass = enc.begin_compute_pass(&Default::default());
                for (words, part, sum) in [
                    (param_words, &part_params, &self.grads.params),
                    (colour_words, &part_colours, &self.grads.colours),
                ] {
                    let len = uniform(device, &[words, 0, 0, 0]);
                    let bind = k.add_into.bind(device, &[&len, part, sum]);
                    k.add_into.dispatch_items(&mut pass, &bind, words);
                }
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
