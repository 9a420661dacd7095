//! The trainer's per-iteration step and where the training state lives. [`Stepper`] is
//! the one seam of the training loop: the loop samples the batch, schedules the rates and
//! runs everything else (anisotropy cap, hooks, NaN guard, densification, checkpoints,
//! logging) on the host copy of the model, asking the stepper to bring that copy up to
//! date before it reads it and to take it back after it edits it.
//!
//! [`HostStep`]: every view rendered and differentiated by the backend, the loss and Adam
//! on the host (the CPU path; also the GPU backend's path when hooks want an opacity
//! factor and are not a neural decay the device runs itself). The host state is always current. [`crate::train::device_step::DeviceStep`]:
//! the whole iteration on the GPU with the state resident there.

use crate::metrics::psnr_from_mse;
use crate::model::Gaussians;
use crate::render::{Gradients, ImageGradients, RenderBackend, RenderOptions};
use crate::train::densify::DensifyStats;
use crate::train::loss::{LossValue, image_loss};
use crate::train::optim::{Adam, GroupRates};
use crate::train::pseudo_view::{PseudoPlan, PseudoViews};
use crate::train::{Dataset, TrainConfig, TrainError, TrainHooks};

/// What the hooks do with the model during a step ([`TrainHooks::model_access`]), so a
/// trainer that keeps the model on a device knows when to bring it to the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelAccess {
    /// The hooks neither read nor edit the model (plain 4DGS).
    None,
    /// `opacity_factor` always returns `None`, but the hooks read or edit the model every
    /// step (e.g. a per-step opacity decay in `after_step`).
    EveryStep,
    /// `opacity_factor` may return a factor whose gradient the hooks want.
    OpacityFactor,
}

/// The losses of one iteration's views, in batch order.
pub(crate) struct BatchLoss {
    pub losses: Vec<LossValue>,
}

impl BatchLoss {
    /// (Σ loss, Σ L1, Σ SSIM, Σ PSNR) over the batch, added in batch order.
    pub fn sums(&self) -> (f64, f64, f64, f64) {
        let (mut loss, mut l1, mut ssim, mut psnr) = (0.0, 0.0, 0.0, 0.0);
        for lv in &self.losses {
            loss += lv.total;
            l1 += lv.l1;
            ssim += lv.ssim;
            psnr += psnr_from_mse(lv.mse);
        }
        (loss, l1, ssim, psnr)
    }
}

/// One optimiser step per iteration, and the movement of the training state between the
/// host and wherever the step keeps it.
pub(crate) trait Stepper {
    /// Where the step runs, for logs (e.g. `host`, `gpu`).
    fn placement(&self) -> &'static str;

    /// One iteration on the views `batch` of the dataset with `rates`: render, loss,
    /// backward, densification statistics, Adam. `model.active` is this iteration's colour
    /// degrees; `model`, `adam` and `stats` are the host state.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &mut self,
        iteration: u64,
        batch: &[usize],
        rates: &GroupRates,
        model: &mut Gaussians<f32>,
        adam: &mut Adam,
        stats: &mut DensifyStats,
        hooks: &mut dyn TrainHooks,
    ) -> Result<BatchLoss, TrainError>;

    /// Whether the host model holds the latest trained values.
    fn host_model_current(&self) -> bool;

    /// Bring the model's values to the host.
    fn model_to_host(&mut self, model: &mut Gaussians<f32>) -> Result<(), TrainError>;

    /// The host edited the model's values (same Gaussians): use them from now on.
    fn model_from_host(&mut self, model: &Gaussians<f32>) -> Result<(), TrainError>;

    /// Bring the model, the Adam state and the densification statistics to the host, and
    /// any hook state the step keeps (f_θ of a decay on the device) back into `hooks`.
    fn state_to_host(
        &mut self,
        model: &mut Gaussians<f32>,
        adam: &mut Adam,
        stats: &mut DensifyStats,
        hooks: &mut dyn TrainHooks,
    ) -> Result<(), TrainError>;

    /// The host changed the state (densified, reset opacities): use it from now on.
    fn state_from_host(
        &mut self,
        model: &Gaussians<f32>,
        adam: &Adam,
        stats: &DensifyStats,
    ) -> Result<(), TrainError>;
}

/// The host path: `backend` renders and differentiates each view; loss, gradient sum and
/// Adam run on the host.
pub(crate) struct HostStep<'a> {
    backend: &'a dyn RenderBackend,
    config: &'a TrainConfig,
    /// `config.background` resolved.
    background: [f32; 3],
    dataset: &'a Dataset,
    target: Vec<f32>,
    d_image: Vec<f32>,
    /// One view's gradients, reused across views and iterations: the backward resizes
    /// and overwrites it, so the large colour array is not faulted in afresh every view.
    g: Gradients<f32>,
    pseudo: PseudoViews,
}

impl<'a> HostStep<'a> {
    pub fn new(
        backend: &'a dyn RenderBackend,
        config: &'a TrainConfig,
        background: [f32; 3],
        dataset: &'a Dataset,
        model: &Gaussians<f32>,
    ) -> Self {
        Self {
            backend,
            config,
            background,
            dataset,
            target: Vec::new(),
            d_image: Vec::new(),
            g: Gradients::zeros_like(model, false),
            pseudo: PseudoViews::new(PseudoPlan::new(
                config.pseudo_views,
                config.iterations,
                config.seed,
                &dataset.views,
            )),
        }
    }
}

impl Stepper for HostStep<'_> {
    fn placement(&self) -> &'static str {
        "host"
    }

    fn step(
        &mut self,
        iteration: u64,
        batch: &[usize],
        rates: &GroupRates,
        model: &mut Gaussians<f32>,
        adam: &mut Adam,
        stats: &mut DensifyStats,
        hooks: &mut dyn TrainHooks,
    ) -> Result<BatchLoss, TrainError> {
        let it = iteration;
        let (config, backend, g) = (self.config, self.backend, &mut self.g);
        let background = self.background;
        let (target, d_image) = (&mut self.target, &mut self.d_image);
        let mut grads = Gradients::zeros_like(model, false);
        let mut losses = Vec::with_capacity(batch.len());
        let scale = 1.0 / batch.len() as f32;
        for (position, &vi) in batch.iter().enumerate() {
            let view = &self.dataset.views[vi];
            let factor = hooks.opacity_factor(it, model, view);
            let options = RenderOptions {
                background,
                opacity_factor: factor.as_deref(),
                ..Default::default()
            };
            let r = backend
                .render(model, &view.camera, view.time, &options)
                .map_err(|source| TrainError::Render { index: vi, source })?;
            view.image.to_f32_into(target);
            d_image.clear();
            d_image.resize(target.len(), 0.0);
            let (w, h) = (r.width as usize, r.height as usize);
            let lv = image_loss(&r.rgb, target, w, h, config.lambda_ssim, Some(d_image));
            d_image.iter_mut().for_each(|g| *g *= scale);
            let pseudo = self.pseudo.apply(
                backend,
                model,
                it,
                (vi, position),
                view,
                &options,
                &r,
                target,
                scale,
                &mut grads,
            )?;
            let up = ImageGradients {
                rgb: d_image,
                alpha: pseudo.as_ref().map(|p| p.alpha.as_slice()),
                depth: pseudo.as_ref().map(|p| p.depth.as_slice()),
            };
            backend
                .backward(model, &r, &up, g)
                .map_err(|source| TrainError::Render { index: vi, source })?;
            if factor.is_some() {
                hooks.factor_gradient(it, model, &g.opacity_factor);
            }
            // The statistic is the gradient of this view's own loss (undo the 1/batch).
            stats.record(
                &g.mean2d_norm,
                &r.radii,
                r.width,
                r.height,
                batch.len() as f32,
            );
            grads.add(g);
            losses.push(lv);
        }
        adam.step(model, &grads, rates);
        Ok(BatchLoss { losses })
    }

    fn host_model_current(&self) -> bool {
        true
    }

    fn model_to_host(&mut self, _model: &mut Gaussians<f32>) -> Result<(), TrainError> {
        Ok(())
    }

    fn model_from_host(&mut self, _model: &Gaussians<f32>) -> Result<(), TrainError> {
        Ok(())
    }

    fn state_to_host(
        &mut self,
        _model: &mut Gaussians<f32>,
        _adam: &mut Adam,
        _stats: &mut DensifyStats,
        _hooks: &mut dyn TrainHooks,
    ) -> Result<(), TrainError> {
        Ok(())
    }

    fn state_from_host(
        &mut self,
        _model: &Gaussians<f32>,
        _adam: &Adam,
        _stats: &DensifyStats,
    ) -> Result<(), TrainError> {
        Ok(())
    }
}
