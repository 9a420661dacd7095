//! Adam on the GPU (`shaders/adam.wgsl`): the model's trainable values and their first
//! and second moments stay in device buffers between steps, laid out as the renderer
//! uploads a model (five vec4 per Gaussian, then the colour coefficients). A step is one
//! submission of two dispatches with the step's scheduled rates as uniforms and no
//! read-back; it computes what `train::optim::Adam::step` does, in the same f32 order.

use super::kernels::TrainKernels;
use crate::gpu::Gpu;
use crate::gpu::compute::{read_buffer, storage, storage_init, uniform};
use crate::model::Gaussians;
use crate::render::gpu::{GpuBackend, PARAM_FLOATS, pack_params};
use crate::render::{Gradients, RenderError};
use crate::train::optim::{Adam, BETA1, BETA2, EPSILON, GroupRates, ParamBuffers};
use std::sync::Arc;

/// The step constants (`AdamParams` in `shaders/adam.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AdamUniform {
    count: u32,
    stride: u32,
    /// Values before this one are frozen (`Adam::frozen` Gaussians × stride).
    first: u32,
    pad0: u32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    bc1: f32,
    bc2: f32,
    epsilon: f32,
    pad1: f32,
    /// Rate per position in the stride (the last one for positions past 19); negative:
    /// not trained.
    rates: [f32; 20],
}

/// One per-Gaussian array set on the device: packed parameters and colours.
pub(super) struct Packed {
    pub params: wgpu::Buffer,
    pub colours: wgpu::Buffer,
}

impl Packed {
    fn zeros(device: &wgpu::Device, count: usize, colour_len: usize, label: &str) -> Self {
        Self {
            params: storage(device, 4 * (PARAM_FLOATS * count) as u64, label),
            colours: storage(device, 4 * colour_len as u64, label),
        }
    }
}

/// Adam with the model and its moments resident on the GPU.
pub struct GpuAdam {
    pub(super) gpu: Arc<Gpu>,
    /// The training step's pipelines on this device.
    pub(super) kernels: Arc<TrainKernels>,
    pub(super) count: usize,
    pub(super) colour_len: usize,
    /// Colour values per Gaussian (`3 × coefficients`).
    colour_stride: usize,
    pub(super) params: Packed,
    /// The gradients of the next step.
    pub(super) grads: Packed,
    m: Packed,
    v: Packed,
    /// Opacity factors of 1, for views the decay does not factor.
    pub(super) ones: wgpu::Buffer,
    step: u64,
    /// The first `frozen` Gaussians are left alone (`Adam::frozen`).
    frozen: usize,
}

impl GpuAdam {
    /// Upload `model` with zero moments (as `Adam::new`).
    pub fn new(backend: &GpuBackend, model: &Gaussians<f32>) -> Result<Self, RenderError> {
        model
            .check_consistent()
            .map_err(RenderError::InconsistentModel)?;
        let count = model.len();
        backend.too_large("the model's parameters", 4 * (PARAM_FLOATS * count) as u64)?;
        backend.too_large(
            "the model's colour coefficients",
            4 * model.colours.len() as u64,
        )?;
        let device = &backend.gpu.device;
        let colour_len = model.colours.len();
        let kernels = TrainKernels::of(backend);
        let adam = backend.checked(|| {
            Ok(Self {
                gpu: backend.gpu.clone(),
                kernels,
                count,
                colour_len,
                colour_stride: 3 * model.coeffs_per_channel(),
                params: Packed::zeros(device, count, colour_len, "trained parameters"),
                grads: Packed::zeros(device, count, colour_len, "Adam gradients"),
                m: Packed::zeros(device, count, colour_len, "Adam first moments"),
                v: Packed::zeros(device, count, colour_len, "Adam second moments"),
                ones: storage_init(device, &vec![1.0f32; count.max(1)], "no opacity factor"),
                step: 0,
                frozen: 0,
            })
        })?;
        adam.write(&adam.params, &pack_params(model), &model.colours);
        Ok(adam)
    }

    /// Upload `model` with the moments and step count of `adam` (its state for this
    /// model): training continues exactly where the host's `Adam` left off.
    pub fn from_state(
        backend: &GpuBackend,
        model: &Gaussians<f32>,
        adam: &Adam,
    ) -> Result<Self, RenderError> {
        let mut a = Self::new(backend, model)?;
        for (what, b) in [("first", &adam.m), ("second", &adam.v)] {
            if b.len() != a.count || b.colours.len() != a.colour_len {
                return Err(RenderError::InconsistentModel(format!(
                    "Adam's {what} moments are for {} Gaussians and {} colour values, the model has {} and {}",
                    b.len(),
                    b.colours.len(),
                    a.count,
                    a.colour_len
                )));
            }
        }
        a.write(&a.m, &pack_buffers(&adam.m), &adam.m.colours);
        a.write(&a.v, &pack_buffers(&adam.v), &adam.v.colours);
        a.step = adam.step;
        a.frozen = adam.frozen.min(a.count);
        Ok(a)
    }

    /// Replace the trained values with `model`'s (the same size; moments kept), e.g.
    /// after the host edited the model between steps.
    pub fn upload_values(
        &self,
        backend: &GpuBackend,
        model: &Gaussians<f32>,
    ) -> Result<(), RenderError> {
        self.same_device(backend)?;
        self.check_count(model.len())?;
        self.check_colours(model)?;
        self.write(&self.params, &pack_params(model), &model.colours);
        Ok(())
    }

    /// Copy the trained values, the moments and the step count back into `model` and
    /// `adam` (the model uploaded, same size).
    pub fn download_state(
        &self,
        backend: &GpuBackend,
        model: &mut Gaussians<f32>,
        adam: &mut Adam,
    ) -> Result<(), RenderError> {
        self.download(backend, model)?;
        let (m, v) = self.moments(backend)?;
        adam.m = m;
        adam.v = v;
        adam.step = self.step;
        Ok(())
    }

    /// Write packed values and colours into `set`.
    fn write(&self, set: &Packed, params: &[[f32; 4]], colours: &[f32]) {
        let queue = &self.gpu.queue;
        if !params.is_empty() {
            queue.write_buffer(&set.params, 0, bytemuck::cast_slice(params));
        }
        if !colours.is_empty() {
            queue.write_buffer(&set.colours, 0, bytemuck::cast_slice(colours));
        }
    }

    fn check_colours(&self, model: &Gaussians<f32>) -> Result<(), RenderError> {
        if model.colours.len() == self.colour_len {
            Ok(())
        } else {
            Err(RenderError::InconsistentModel(format!(
                "{} colour values, {} uploaded",
                model.colours.len(),
                self.colour_len
            )))
        }
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.step
    }

    pub(super) fn same_device(&self, backend: &GpuBackend) -> Result<(), RenderError> {
        if Arc::ptr_eq(&self.gpu, &backend.gpu) {
            Ok(())
        } else {
            Err(RenderError::WrongBackend { backend: "gpu" })
        }
    }

    pub(super) fn check_count(&self, got: usize) -> Result<(), RenderError> {
        if got == self.count {
            Ok(())
        } else {
            Err(RenderError::ModelMismatch {
                expected: self.count,
                got,
            })
        }
    }

    /// Upload the gradients of the next step (laid out like the model).
    pub fn set_gradients(
        &self,
        backend: &GpuBackend,
        grads: &Gradients<f32>,
    ) -> Result<(), RenderError> {
        self.same_device(backend)?;
        self.check_count(grads.means.len())?;
        let n = self.count;
        let lengths = [
            ("log-scale", grads.log_scales.len(), n),
            ("left rotation", grads.rot_left.len(), n),
            ("right rotation", grads.rot_right.len(), n),
            ("opacity", grads.opacity_logits.len(), n),
            ("colour", grads.colours.len(), self.colour_len),
        ];
        for (what, got, expected) in lengths {
            if got != expected {
                return Err(RenderError::GradientLength {
                    what,
                    expected,
                    got,
                });
            }
        }
        let mut packed: Vec<[f32; 4]> = Vec::with_capacity(5 * n);
        for i in 0..n {
            packed.extend_from_slice(&[
                grads.means[i],
                grads.log_scales[i],
                grads.rot_left[i],
                grads.rot_right[i],
                [grads.opacity_logits[i], 0.0, 0.0, 0.0],
            ]);
        }
        let queue = &self.gpu.queue;
        if n > 0 {
            queue.write_buffer(&self.grads.params, 0, bytemuck::cast_slice(&packed));
        }
        if self.colour_len > 0 {
            queue.write_buffer(&self.grads.colours, 0, bytemuck::cast_slice(&grads.colours));
        }
        Ok(())
    }

    /// One Adam step with the uploaded gradients and this step's `rates`.
    pub fn step(&mut self, backend: &GpuBackend, rates: &GroupRates) -> Result<(), RenderError> {
        self.same_device(backend)?;
        backend.checked(|| {
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            self.encode_step(rates, &mut enc);
            self.gpu.queue.submit([enc.finish()]);
            Ok(())
        })?;
        self.stepped();
        Ok(())
    }

    /// Record the next step (the caller counts it with `stepped` once submitted).
    pub(super) fn encode_step(&self, rates: &GroupRates, enc: &mut wgpu::CommandEncoder) {
        let device = &self.gpu.device;
        let k = &self.kernels;
        let t = (self.step + 1).min(i32::MAX as u64) as i32;
        let base = AdamUniform {
            count: 0,
            stride: 1,
            first: 0,
            pad0: 0,
            beta1: BETA1,
            beta2: BETA2,
            one_minus_beta1: 1.0 - BETA1,
            one_minus_beta2: 1.0 - BETA2,
            bc1: 1.0 - BETA1.powi(t),
            bc2: 1.0 - BETA2.powi(t),
            epsilon: EPSILON,
            pad1: 0.0,
            rates: [0.0; 20],
        };
        let r = rates;
        let mut param_rates = [-1.0f32; 20];
        param_rates[..4].copy_from_slice(&[r.position, r.position, r.position, r.time]);
        param_rates[4..8].fill(r.scale);
        param_rates[8..16].fill(r.rotation);
        param_rates[16] = r.opacity;
        let mut colour_rates = [r.colour_rest; 20];
        colour_rates[..3].fill(r.colour_dc);
        let groups = [
            (
                PARAM_FLOATS * self.count,
                PARAM_FLOATS,
                PARAM_FLOATS * self.frozen,
                param_rates,
                &self.grads.params,
                &self.params.params,
                &self.m.params,
                &self.v.params,
            ),
            (
                self.colour_len,
                self.colour_stride.max(1),
                self.colour_stride * self.frozen,
                colour_rates,
                &self.grads.colours,
                &self.params.colours,
                &self.m.colours,
                &self.v.colours,
            ),
        ];
        let mut pass = enc.begin_compute_pass(&Default::default());
        for (count, stride, first, rates, g, p, m, v) in groups {
            if count == 0 {
                continue;
            }
            let u = uniform(
                device,
                &AdamUniform {
                    count: count as u32,
                    stride: stride as u32,
                    first: first as u32,
                    rates,
                    ..base
                },
            );
            let bind = k.adam_step.bind(device, &[&u, g, p, m, v]);
            k.adam_step.dispatch_items(&mut pass, &bind, count as u32);
        }
    }

    /// Count a step recorded with `encode_step` and submitted.
    pub(super) fn stepped(&mut self) {
        self.step += 1;
    }

    /// Read `set` (packed parameters and colours) back as flat floats.
    fn read(&self, backend: &GpuBackend, set: &Packed) -> Result<Vec<f32>, RenderError> {
        let device = &self.gpu.device;
        let param_bytes = 4 * (PARAM_FLOATS * self.count) as u64;
        let colour_bytes = 4 * self.colour_len as u64;
        let staging = read_buffer(device, param_bytes + colour_bytes);
        let mut enc = device.create_command_encoder(&Default::default());
        if param_bytes > 0 {
            enc.copy_buffer_to_buffer(&set.params, 0, &staging, 0, param_bytes);
        }
        if colour_bytes > 0 {
            enc.copy_buffer_to_buffer(&set.colours, 0, &staging, param_bytes, colour_bytes);
        }
        let words = backend.read_back(enc, &staging, param_bytes + colour_bytes)?;
        Ok(bytemuck::cast_slice(&words).to_vec())
    }

    /// Copy the trained values into `model` (the model uploaded, same size).
    pub fn download(
        &self,
        backend: &GpuBackend,
        model: &mut Gaussians<f32>,
    ) -> Result<(), RenderError> {
        self.same_device(backend)?;
        self.check_count(model.len())?;
        self.check_colours(model)?;
        let values = backend.checked(|| self.read(backend, &self.params))?;
        let b = self.unpack(&values);
        model.means = b.means;
        model.log_scales = b.log_scales;
        model.rot_left = b.rot_left;
        model.rot_right = b.rot_right;
        model.opacity_logits = b.opacity_logits;
        model.colours = b.colours;
        Ok(())
    }

    /// The first and second moments, laid out as `Adam::m` and `Adam::v`.
    pub fn moments(
        &self,
        backend: &GpuBackend,
    ) -> Result<(ParamBuffers, ParamBuffers), RenderError> {
        self.same_device(backend)?;
        let m = backend.checked(|| self.read(backend, &self.m))?;
        let v = backend.checked(|| self.read(backend, &self.v))?;
        Ok((self.unpack(&m), self.unpack(&v)))
    }

    /// The gradients of the last step (summed over its batch by
    /// [`GpuAdam::train_step`], or as set by [`GpuAdam::set_gradients`]).
    pub fn gradients(&self, backend: &GpuBackend) -> Result<ParamBuffers, RenderError> {
        self.same_device(backend)?;
        let g = backend.checked(|| self.read(backend, &self.grads))?;
        Ok(self.unpack(&g))
    }

    /// Flat packed values (parameters, then colours) to per-group arrays.
    fn unpack(&self, values: &[f32]) -> ParamBuffers {
        let n = self.count;
        let (params, colours) = values.split_at(PARAM_FLOATS * n);
        let vec4 = |i: usize, k: usize| -> [f32; 4] {
            let at = PARAM_FLOATS * i + 4 * k;
            [params[at], params[at + 1], params[at + 2], params[at + 3]]
        };
        ParamBuffers {
            means: (0..n).map(|i| vec4(i, 0)).collect(),
            log_scales: (0..n).map(|i| vec4(i, 1)).collect(),
            rot_left: (0..n).map(|i| vec4(i, 2)).collect(),
            rot_right: (0..n).map(|i| vec4(i, 3)).collect(),
            opacity_logits: (0..n).map(|i| params[PARAM_FLOATS * i + 16]).collect(),
            colours: colours.to_vec(),
        }
    }
}

/// Adam-shaped buffers packed as the model is uploaded (five vec4 per Gaussian; the
/// padding after the opacity is zero).
fn pack_buffers(b: &ParamBuffers) -> Vec<[f32; 4]> {
    let mut packed: Vec<[f32; 4]> = Vec::with_capacity(5 * b.len());
    for i in 0..b.len() {
        packed.extend_from_slice(&[
            b.means[i],
            b.log_scales[i],
            b.rot_left[i],
            b.rot_right[i],
            [b.opacity_logits[i], 0.0, 0.0, 0.0],
        ]);
    }
    packed
}
