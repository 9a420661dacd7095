//! Training on top of frozen Gaussians: a static scene trained once and shared by later
//! time chunks sits at the front of the model and never changes. Adam and densification
//! skip it (`Adam::frozen`); what else edits the host model during a step (the anisotropy
//! cap, a decay's `after_step`) is undone here, and a decay's opacity factor leaves it
//! alone, so it renders during training exactly as it will beside the chunk afterwards.

use crate::model::Gaussians;
use crate::train::{DeviceDecay, ModelAccess, TrainHooks, View};

/// Put `source`'s first `count` Gaussians back at the front of `model`.
pub(crate) fn restore_prefix(model: &mut Gaussians<f32>, source: &Gaussians<f32>, count: usize) {
    let k = 3 * model.coeffs_per_channel();
    model.means[..count].copy_from_slice(&source.means[..count]);
    model.log_scales[..count].copy_from_slice(&source.log_scales[..count]);
    model.rot_left[..count].copy_from_slice(&source.rot_left[..count]);
    model.rot_right[..count].copy_from_slice(&source.rot_right[..count]);
    model.opacity_logits[..count].copy_from_slice(&source.opacity_logits[..count]);
    model.colours[..k * count].copy_from_slice(&source.colours[..k * count]);
}

/// Whether `model` starts with `source`'s first `count` Gaussians, bit for bit.
pub(crate) fn has_prefix(model: &Gaussians<f32>, source: &Gaussians<f32>, count: usize) -> bool {
    let k = 3 * model.coeffs_per_channel();
    let bits = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    model.len() >= count
        && source.len() >= count
        && model.capacity == source.capacity
        && bits(
            model.means[..count].as_flattened(),
            source.means[..count].as_flattened(),
        )
        && bits(
            model.log_scales[..count].as_flattened(),
            source.log_scales[..count].as_flattened(),
        )
        && bits(
            &model.opacity_logits[..count],
            &source.opacity_logits[..count],
        )
        && bits(&model.colours[..k * count], &source.colours[..k * count])
}

/// The caller's hooks with the first `frozen` Gaussians kept out of their reach: an opacity
/// factor of 1 for them, and no decay on the device (its opacity write-back would reach
/// them; the host decay's edits are undone by [`restore_prefix`]).
pub(crate) struct KeepFrozen<'h> {
    pub inner: &'h mut dyn TrainHooks,
    pub frozen: usize,
}

impl TrainHooks for KeepFrozen<'_> {
    fn opacity_factor(
        &mut self,
        iteration: u64,
        model: &Gaussians<f32>,
        view: &View,
    ) -> Option<Vec<f32>> {
        let mut factor = self.inner.opacity_factor(iteration, model, view)?;
        let n = self.frozen.min(factor.len());
        factor[..n].fill(1.0);
        Some(factor)
    }
    fn factor_gradient(&mut self, iteration: u64, model: &Gaussians<f32>, gradient: &[f32]) {
        self.inner.factor_gradient(iteration, model, gradient)
    }
    fn after_step(&mut self, iteration: u64, model: &mut Gaussians<f32>) {
        self.inner.after_step(iteration, model)
    }
    fn save_state(&self) -> Vec<u8> {
        self.inner.save_state()
    }
    fn load_state(&mut self, state: &[u8]) {
        self.inner.load_state(state)
    }
    fn stop_requested(&mut self, iteration: u64) -> bool {
        self.inner.stop_requested(iteration)
    }
    fn model_access(&self) -> ModelAccess {
        self.inner.model_access()
    }
    fn device_decay(&mut self) -> Option<DeviceDecay<'_>> {
        if self.frozen > 0 {
            None
        } else {
            self.inner.device_decay()
        }
    }
}
