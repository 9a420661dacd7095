//! The GPU path of the trainer: the training images uploaded once (as bytes), the model,
//! its Adam moments and the densification statistics resident on the device, and each
//! iteration one [`GpuAdam::train_step_decayed`] (render, loss, backward, batch sum,
//! statistics, Adam, and the pseudo views the run's [`PseudoPlan`] draws) that reads back
//! only the views' loss totals.
//!
//! The host copy of the state is brought up to date only when the loop needs it: every
//! step when the anisotropy cap is on or the hooks touch the model
//! ([`ModelAccess::EveryStep`]: the model's values make a round trip, the moments stay),
//! and for densification, opacity resets, checkpoints, a stop and the end (model, moments
//! and statistics; after a densification or reset the device state is rebuilt from the
//! host's). Hooks that want an opacity factor are not run here (the trainer takes the
//! host path, [`super::step::HostStep`], for them), except the 4C4D decay
//! ([`TrainHooks::device_decay`]): f_θ and its Adam moments are resident too
//! ([`GpuDecay`]; the hand-tuned variants use visibility and write-back only), each step after the warm-up runs the decay inside the device step
//! (32 more bytes read back: the step's statistics, reported to the hooks), and f_θ's
//! state returns to the hooks at the host syncs.

use crate::decay::gpu::GpuDecay;
use crate::model::Gaussians;
use crate::render::RenderError;
use crate::render::gpu::GpuBackend;
use crate::train::densify::DensifyStats;
use crate::train::gpu::{GpuAdam, GpuImage, GpuStats, GpuTraining, TrainView};
use crate::train::optim::{Adam, GroupRates};
use crate::train::pseudo_view::PseudoPlan;
use crate::train::step::{BatchLoss, Stepper};
use crate::train::{Dataset, StepStats, TrainConfig, TrainError, TrainHooks};

/// The whole iteration on the GPU with the training state resident there.
pub(crate) struct DeviceStep<'a> {
    gpu: &'a GpuBackend,
    config: &'a TrainConfig,
    /// `config.background` resolved.
    background: [f32; 3],
    dataset: &'a Dataset,
    /// One uploaded image per view of the dataset.
    targets: Vec<GpuImage>,
    adam: GpuAdam,
    stats: GpuStats,
    pseudo: PseudoPlan,
    /// The decay on the device, and the step it starts after.
    decay: Option<(GpuDecay, u64)>,
    /// The host model holds the device's values.
    model_current: bool,
    /// The host model, Adam state and statistics hold the device's.
    state_current: bool,
}

/// A device error of a step (`index`: the batch's first view) or of an upload.
fn device_error(index: usize) -> impl Fn(RenderError) -> TrainError {
    move |source| TrainError::Render { index, source }
}

impl<'a> DeviceStep<'a> {
    /// Upload the dataset's images and the training state (with f_θ's, when `hooks` lend
    /// a decay the device kernels cover).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gpu: &'a GpuBackend,
        config: &'a TrainConfig,
        background: [f32; 3],
        dataset: &'a Dataset,
        model: &Gaussians<f32>,
        adam: &Adam,
        stats: &DensifyStats,
        hooks: &mut dyn TrainHooks,
    ) -> Result<Self, TrainError> {
        let decay = match hooks.device_decay() {
            Some(d) if GpuDecay::supports(d.config) => Some((
                GpuDecay::new(gpu, d.config, d.mlp, d.adam).map_err(TrainError::Device)?,
                d.config.warmup,
            )),
            _ => None,
        };
        let targets = dataset
            .views
            .iter()
            .enumerate()
            .map(|(i, v)| gpu.upload_image(&v.image).map_err(device_error(i)))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            gpu,
            config,
            background,
            dataset,
            targets,
            adam: GpuAdam::from_state(gpu, model, adam).map_err(TrainError::Device)?,
            stats: GpuStats::upload(gpu, stats).map_err(TrainError::Device)?,
            pseudo: PseudoPlan::new(
                config.pseudo_views,
                config.iterations,
                config.seed,
                &dataset.views,
            ),
            decay,
            model_current: true,
            state_current: true,
        })
    }
}

impl Stepper for DeviceStep<'_> {
    fn placement(&self) -> &'static str {
        "gpu"
    }

    fn step(
        &mut self,
        iteration: u64,
        batch: &[usize],
        rates: &GroupRates,
        model: &mut Gaussians<f32>,
        _adam: &mut Adam,
        _stats: &mut DensifyStats,
        hooks: &mut dyn TrainHooks,
    ) -> Result<BatchLoss, TrainError> {
        let first = batch.first().copied().unwrap_or(0);
        let scale = 1.0 / batch.len() as f32;
        let mut views = Vec::with_capacity(batch.len());
        for (position, &vi) in batch.iter().enumerate() {
            let view = &self.dataset.views[vi];
            if self.decay.is_none() && hooks.opacity_factor(iteration, model, view).is_some() {
                return Err(TrainError::Config(
                    "the hooks returned an opacity factor, but declared none (TrainHooks::model_access); the GPU step trains without opacity factors".into(),
                ));
            }
            views.push(TrainView {
                camera: &view.camera,
                t: view.time,
                target: &self.targets[vi],
                pseudo: self
                    .pseudo
                    .virtual_view(iteration, (vi, position), &view.camera, scale),
            });
        }
        // The decay is active from 0-based iteration `warmup` on (`DecayHooks::active`).
        let decay = match &mut self.decay {
            Some((d, warmup)) if iteration >= *warmup => Some(d),
            _ => None,
        };
        let result = self
            .adam
            .train_step_decayed(
                self.gpu,
                model,
                &views,
                self.background,
                self.config.lambda_ssim,
                rates,
                Some(&self.stats),
                decay,
            )
            .map_err(device_error(first))?;
        self.model_current = false;
        self.state_current = false;
        if let Some(o) = result.decay
            && let Some(h) = hooks.device_decay()
        {
            let n = model.len();
            *h.last = Some(StepStats {
                iteration: iteration + 1,
                visible: o.visible,
                invisible: n.saturating_sub(o.visible),
                min_factor: o.min_factor as f64,
                mean_factor: o.factor_sum as f64 / n.max(1) as f64,
                max_factor: o.max_factor as f64,
            });
            if o.skipped {
                *h.skipped_updates += 1;
            }
        }
        Ok(BatchLoss {
            losses: result.losses,
        })
    }

    fn host_model_current(&self) -> bool {
        self.model_current
    }

    fn model_to_host(&mut self, model: &mut Gaussians<f32>) -> Result<(), TrainError> {
        if !self.model_current {
            self.adam
                .download(self.gpu, model)
                .map_err(TrainError::Device)?;
            self.model_current = true;
        }
        Ok(())
    }

    fn model_from_host(&mut self, model: &Gaussians<f32>) -> Result<(), TrainError> {
        self.adam
            .upload_values(self.gpu, model)
            .map_err(TrainError::Device)?;
        self.model_current = true;
        Ok(())
    }

    fn state_to_host(
        &mut self,
        model: &mut Gaussians<f32>,
        adam: &mut Adam,
        stats: &mut DensifyStats,
        hooks: &mut dyn TrainHooks,
    ) -> Result<(), TrainError> {
        if !self.state_current {
            self.adam
                .download_state(self.gpu, model, adam)
                .map_err(TrainError::Device)?;
            *stats = self.stats.download(self.gpu).map_err(TrainError::Device)?;
            if let Some((d, _)) = &self.decay
                && let Some(h) = hooks.device_decay()
            {
                d.download(self.gpu, h.mlp, h.adam)
                    .map_err(TrainError::Device)?;
            }
            self.model_current = true;
            self.state_current = true;
        }
        Ok(())
    }

    fn state_from_host(
        &mut self,
        model: &Gaussians<f32>,
        adam: &Adam,
        stats: &DensifyStats,
    ) -> Result<(), TrainError> {
        self.adam = GpuAdam::from_state(self.gpu, model, adam).map_err(TrainError::Device)?;
        self.stats = GpuStats::upload(self.gpu, stats).map_err(TrainError::Device)?;
        self.model_current = true;
        self.state_current = true;
        Ok(())
    }
}
