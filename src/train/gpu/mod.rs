//! The training step on the device, beside the host's (`super::step`, `super::loss`,
//! `super::optim`, `super::densify`): the L1 + D-SSIM image loss and its image gradient
//! ([`GpuTraining::image_loss`], [`loss`]) and [`GpuAdam`] (Adam with the model and its
//! moments resident, [`adam`]), chained with the renderer's forward and backward into one
//! iteration by [`GpuAdam::train_step`] ([`step`]), which can also gather the
//! densification statistics on the device ([`GpuStats`], [`stats`]), add the views'
//! pseudo views (`shaders/pseudo.wgsl`, [`TrainView::pseudo`]) and run the 4C4D
//! decay there (`decay::gpu::GpuDecay`: visibility and the opacity write-back, and for the
//! neural variant f_θ's forward, factor gradient and Adam; [`GpuAdam::train_step_decayed`]).
//! `train::train` runs its iterations this way when given a GPU backend (see
//! `super::device_step`).
//!
//! It renders and differentiates through `render::gpu` and builds its own pipelines
//! ([`kernels`]: WGSL in `shaders/`, built once per device on first use); the renderer
//! knows nothing of it.

mod adam;
mod kernels;
mod loss;
mod stats;
mod step;

pub use adam::GpuAdam;
pub use stats::GpuStats;
pub use step::{GpuImage, StepResult, TrainView};

use crate::render::RenderError;
use crate::render::gpu::GpuBackend;
use crate::train::dataset::ImageU8;
use crate::train::loss::LossValue;

/// The trainer's operations on a [`GpuBackend`]'s device besides the step itself:
/// uploading a target image and the image loss.
pub trait GpuTraining {
    /// Upload a training image once (as bytes).
    fn upload_image(&self, image: &ImageU8) -> Result<GpuImage, RenderError>;

    /// [`crate::train::loss::image_loss`] on the GPU for `rendered` against `target`
    /// (interleaved RGB, `width × height`, values in `[0, 1]`): the loss, and
    /// `d(total)/d(rendered)` written into `grad` when given.
    fn image_loss(
        &self,
        rendered: &[f32],
        target: &[f32],
        size: (u32, u32),
        lambda_ssim: f64,
        grad: Option<&mut [f32]>,
    ) -> Result<LossValue, RenderError>;

    /// [`GpuTraining::image_loss`] of a target given as bytes (`value / 255`, as
    /// `ImageU8::to_f32_into` converts), uploaded as bytes and converted on the device.
    fn image_loss_bytes(
        &self,
        rendered: &[f32],
        target: &[u8],
        size: (u32, u32),
        lambda_ssim: f64,
        grad: Option<&mut [f32]>,
    ) -> Result<LossValue, RenderError>;
}

impl GpuTraining for GpuBackend {
    fn upload_image(&self, image: &ImageU8) -> Result<GpuImage, RenderError> {
        step::upload_image(self, image)
    }

    fn image_loss(
        &self,
        rendered: &[f32],
        target: &[f32],
        size: (u32, u32),
        lambda_ssim: f64,
        grad: Option<&mut [f32]>,
    ) -> Result<LossValue, RenderError> {
        loss::loss(
            self,
            rendered,
            loss::Target::Floats(target),
            size,
            lambda_ssim,
            grad,
        )
    }

    fn image_loss_bytes(
        &self,
        rendered: &[f32],
        target: &[u8],
        size: (u32, u32),
        lambda_ssim: f64,
        grad: Option<&mut [f32]>,
    ) -> Result<LossValue, RenderError> {
        loss::loss(
            self,
            rendered,
            loss::Target::Bytes(target),
            size,
            lambda_ssim,
            grad,
        )
    }
}
