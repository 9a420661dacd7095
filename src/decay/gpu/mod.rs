//! The 4C4D decay on the device (`shaders/decay_mlp.wgsl`, `decay_view.wgsl`,
//! `decay_apply.wgsl`, pipelines in [`kernels`]), for the trainer's GPU step: f_θ's
//! weights and Adam moments stay resident, and a step adds to
//! [`GpuAdam::train_step_decayed`](crate::train::gpu::GpuAdam::train_step_decayed)'s
//! submissions:
//!
//! 1. before the render: the inputs' z-scoring statistics (two-pass, workgroup trees then
//!    the partials in a fixed order), τ_g for every Gaussian of the pre-step model, and
//!    per view the visibility, the render-opacity factor (τ or 1) and "seen in the batch";
//! 2. after each view's backward: its dL/dτ added for the Gaussians visible in it;
//! 3. before the Gaussians' Adam: dL/dθ (each row's forward and backward in its own
//!    thread, its layer inputs and deltas kept for a chunk of rows; then one thread per
//!    parameter adds 256 rows in order per workgroup, and the workgroups are added in order:
//!    no float atomics) and f_θ's Adam, skipped when a gradient is not finite;
//! 4. after the Gaussians' Adam: `o ← o·τ` (seen) or `o ← o·β` in logit space, and the
//!    step's statistics.
//!
//! The hand-tuned variants (`constant`, `pow`, `exp`) run the visibility and the
//! write-back only (their factor comes from the opacity, not from f_θ, and does not enter
//! the render).
//!
//! Per step 32 bytes come back (statistics and the skipped flag). The host's f_θ and its
//! Adam state are brought up to date by [`GpuDecay::download`] at host syncs.
//!
//! It renders nothing and trains no Gaussian: the trainer's step (`train::gpu`) calls it
//! between its own passes. It builds its own pipelines with the GPU toolkit
//! (`gpu::compute`) and names nothing of the trainer.

mod kernels;

use crate::decay::config::{DecayConfig, DecayInputs, DecayVariant, VisibilityMode};
use crate::decay::mlp::{Mlp, MlpAdam};
use crate::gpu::Gpu;
use crate::gpu::compute::{Kernel, WG, read_buffer, storage, storage_init, uniform};
use crate::model::Gaussians;
use crate::render::RenderError;
use crate::render::gpu::{GpuBackend, ViewUniform, pack_params};
use kernels::DecayKernels;
use std::sync::Arc;

/// Widest layer the kernels hold (inputs included).
const MAX_WIDTH: usize = 32;
/// Most linear layers (hidden layers + 1).
const MAX_LINEAR: usize = 4;
/// Most parameters (`ADAM_SLOTS × WG` in the shader).
const MAX_PARAMS: usize = 3072;
/// Rows of f_θ's backward per chunk (their layer inputs and deltas are kept between the
/// chunk's two kernels: at most 65536 × (inputs + hidden + deltas) floats, 36 MB by default).
const CHUNK_ROWS: usize = 65536;
/// Bytes of the per-step result: statistics (4 words), the skipped flag and padding.
pub(crate) const RESULT_BYTES: u64 = 32;

/// `MlpParams` in `shaders/decay_mlp.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MlpUniform {
    count: u32,
    in_width: u32,
    layers: u32,
    inputs: u32,
    pass_kind: u32,
    n_params: u32,
    groups: u32,
    row_offset: u32,
    f_min: f32,
    f_max: f32,
    lr: f32,
    weight_decay: f32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    bc1: f32,
    bc2: f32,
    epsilon: f32,
    pad1: f32,
    act_stride: u32,
    del_stride: u32,
    chunk_rows: u32,
    pad2: u32,
    dims: [[u32; 4]; 2],
}

/// `DecayView` in `shaders/decay_view.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ViewDecayUniform {
    rot: [[f32; 4]; 3],
    trans: [f32; 4],
    focal: [f32; 4],
    width: u32,
    height: u32,
    count: u32,
    mode: u32,
    t: f32,
    near: f32,
    pad: [f32; 2],
}

/// `Apply` in `shaders/decay_apply.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ApplyUniform {
    count: u32,
    groups: u32,
    variant: u32,
    pad0: u32,
    beta: f32,
    one_minus_beta: f32,
    ln_beta: f32,
    constant: f32,
    f_min: f32,
    f_max: f32,
    pow_gamma: f32,
    exp_kappa: f32,
}

/// What one decayed step did, from its 32 bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecayOutcome {
    /// Gaussians visible in at least one view of the batch.
    pub visible: usize,
    /// Smallest, largest and summed factor applied to the stored opacities.
    pub min_factor: f32,
    pub max_factor: f32,
    pub factor_sum: f32,
    /// f_θ's Adam step was skipped (a non-finite gradient); false without f_θ.
    pub skipped: bool,
}

/// Per-Gaussian and per-view buffers of one model size.
struct Scratch {
    count: usize,
    groups: u32,
    /// Column means and deviations (16), then the reduced weight gradient, then the
    /// skipped flag.
    stats: wgpu::Buffer,
    partials: wgpu::Buffer,
    tau: wgpu::Buffer,
    d_tau: wgpu::Buffer,
    seen: wgpu::Buffer,
    apply_partials: wgpu::Buffer,
    summary: wgpu::Buffer,
    /// One chunk of rows' layer inputs and output deltas.
    rows: wgpu::Buffer,
    /// Per view of a batch: render factor and visibility.
    views: Vec<(wgpu::Buffer, wgpu::Buffer)>,
}

/// f_θ and its Adam state resident on the GPU.
pub struct GpuDecay {
    gpu: Arc<Gpu>,
    /// The decay's pipelines on this device.
    kernels: Arc<DecayKernels>,
    config: DecayConfig,
    dims: Vec<usize>,
    n_params: usize,
    weights: wgpu::Buffer,
    /// First moments, then second moments.
    moments: wgpu::Buffer,
    lr: f32,
    weight_decay: f32,
    step: u64,
    scratch: Option<Scratch>,
}

impl GpuDecay {
    /// Whether the device kernels cover `config`: `constant`, `pow` and `exp`, and the
    /// neural variant with layers at most 32 wide, at most 3 hidden layers and 3072
    /// parameters (the defaults: 9 → 32 → 32 → 1).
    pub fn supports(config: &DecayConfig) -> bool {
        let dims = config.mlp_dims();
        match config.variant {
            DecayVariant::None => false,
            DecayVariant::Constant | DecayVariant::Pow | DecayVariant::Exp => true,
            DecayVariant::Neural => {
                dims.len() - 1 <= MAX_LINEAR
                    && dims.iter().all(|&d| d <= MAX_WIDTH)
                    && Mlp::<f32>::param_count(&dims) <= MAX_PARAMS
            }
        }
    }

    fn neural(&self) -> bool {
        self.config.variant == DecayVariant::Neural
    }

    /// Upload f_θ (`mlp`) and its optimiser state (`adam`) for `config`.
    pub fn new(
        backend: &GpuBackend,
        config: &DecayConfig,
        mlp: &Mlp<f32>,
        adam: &MlpAdam,
    ) -> Result<Self, RenderError> {
        if !Self::supports(config) {
            return Err(RenderError::Gpu(format!(
                "the device decay runs constant, pow, exp and the neural variant with f_θ layers at most {MAX_WIDTH} wide, at most {} hidden layers and {MAX_PARAMS} parameters; this config asks for {:?}",
                MAX_LINEAR - 1,
                config.mlp_dims()
            )));
        }
        let dims = config.mlp_dims();
        let n = Mlp::<f32>::param_count(&dims);
        if mlp.dims != dims || mlp.params.len() != n || adam.m.len() != n || adam.v.len() != n {
            return Err(RenderError::InconsistentModel(format!(
                "f_θ has layers {:?} and {} parameters ({} and {} moments), the decay config asks for {dims:?}",
                mlp.dims,
                mlp.params.len(),
                adam.m.len(),
                adam.v.len()
            )));
        }
        let kernels = DecayKernels::of(backend);
        backend.checked(|| {
            let mut moments = adam.m.clone();
            moments.extend_from_slice(&adam.v);
            Ok(Self {
                gpu: backend.gpu.clone(),
                kernels,
                config: config.clone(),
                dims,
                n_params: n,
                weights: writable(backend, &mlp.params, "f_θ weights"),
                moments: writable(backend, &moments, "f_θ Adam moments"),
                lr: adam.lr,
                weight_decay: adam.weight_decay,
                step: adam.step,
                scratch: None,
            })
        })
    }

    /// Adam steps f_θ has taken.
    pub fn steps(&self) -> u64 {
        self.step
    }

    /// Copy f_θ's weights, moments and step count into `mlp` and `adam`.
    pub fn download(
        &self,
        backend: &GpuBackend,
        mlp: &mut Mlp<f32>,
        adam: &mut MlpAdam,
    ) -> Result<(), RenderError> {
        self.same_device(backend)?;
        let n = self.n_params as u64;
        let device = &backend.gpu.device;
        let words = backend.checked(|| {
            let staging = read_buffer(device, 12 * n);
            let mut enc = device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(&self.weights, 0, &staging, 0, 4 * n);
            enc.copy_buffer_to_buffer(&self.moments, 0, &staging, 4 * n, 8 * n);
            backend.read_back(enc, &staging, 12 * n)
        })?;
        let floats: &[f32] = bytemuck::cast_slice(&words);
        let n = self.n_params;
        mlp.dims = self.dims.clone();
        mlp.params = floats[..n].to_vec();
        adam.m = floats[n..2 * n].to_vec();
        adam.v = floats[2 * n..3 * n].to_vec();
        adam.step = self.step;
        Ok(())
    }

    /// τ of every Gaussian of `model` under the resident f_θ (as `DecayHooks::tau`).
    pub fn tau(
        &mut self,
        backend: &GpuBackend,
        model: &Gaussians<f32>,
    ) -> Result<Vec<f32>, RenderError> {
        let params = self.upload_model(backend, model)?;
        let n = model.len();
        let device = &backend.gpu.device;
        backend.checked(|| {
            self.scratch(device, n, 0);
            let staging = read_buffer(device, 4 * n as u64);
            let mut enc = device.create_command_encoder(&Default::default());
            self.encode_forward(backend, &mut enc, &params);
            let s = self.scratch_ref()?;
            if n > 0 {
                enc.copy_buffer_to_buffer(&s.tau, 0, &staging, 0, 4 * n as u64);
            }
            let words = backend.read_back(enc, &staging, 4 * n as u64)?;
            Ok(bytemuck::cast_slice(&words).to_vec())
        })
    }

    /// dL/dθ of f_θ at `model` for the upstream `d_tau` (one per Gaussian), laid out as
    /// `Mlp::params` (as `Mlp::backward` with dL/dz = dL/dτ·dτ/dz, inputs detached).
    pub fn weight_gradient(
        &mut self,
        backend: &GpuBackend,
        model: &Gaussians<f32>,
        d_tau: &[f32],
    ) -> Result<Vec<f32>, RenderError> {
        if d_tau.len() != model.len() {
            return Err(RenderError::OpacityFactorLength {
                expected: model.len(),
                got: d_tau.len(),
            });
        }
        let params = self.upload_model(backend, model)?;
        let n = model.len();
        let np = self.n_params as u64;
        let device = &backend.gpu.device;
        backend.checked(|| {
            self.scratch(device, n, 0);
            let s = self.scratch_ref()?;
            if n > 0 {
                self.gpu
                    .queue
                    .write_buffer(&s.d_tau, 0, bytemuck::cast_slice(d_tau));
            }
            let staging = read_buffer(device, 4 * np);
            let mut enc = device.create_command_encoder(&Default::default());
            self.encode_forward(backend, &mut enc, &params);
            self.encode_weight_step(backend, &mut enc, &params, false);
            let s = self.scratch_ref()?;
            enc.copy_buffer_to_buffer(&s.stats, 64, &staging, 0, 4 * np);
            let words = backend.read_back(enc, &staging, 4 * np)?;
            Ok(bytemuck::cast_slice(&words).to_vec())
        })
    }

    /// One write-back on `model` as a decayed step ends: the variant's factor (τ of the
    /// current f_θ, the constant, `pow` or `exp`) for the Gaussians `seen` in the batch, β
    /// for the others, multiplied into the stored opacities in logit space (as
    /// `variants::decayed_logit`). Returns the step's statistics (`skipped` is meaningless
    /// here: f_θ does not step).
    pub fn decay_opacities(
        &mut self,
        backend: &GpuBackend,
        model: &mut Gaussians<f32>,
        seen: &[bool],
    ) -> Result<DecayOutcome, RenderError> {
        let n = model.len();
        if seen.len() != n {
            return Err(RenderError::OpacityFactorLength {
                expected: n,
                got: seen.len(),
            });
        }
        let params = self.upload_model(backend, model)?;
        let device = &backend.gpu.device;
        let words = backend.checked(|| {
            self.scratch(device, n, 0);
            let s = self.scratch_ref()?;
            let seen: Vec<u32> = seen.iter().map(|&v| u32::from(v)).collect();
            if n > 0 {
                self.gpu
                    .queue
                    .write_buffer(&s.seen, 0, bytemuck::cast_slice(&seen));
            }
            let param_bytes = 80 * n as u64;
            let staging = read_buffer(device, RESULT_BYTES + param_bytes);
            let mut enc = device.create_command_encoder(&Default::default());
            if self.neural() {
                self.encode_forward(backend, &mut enc, &params);
            }
            self.encode_apply(backend, &mut enc, &params, &staging, 0);
            if n > 0 {
                enc.copy_buffer_to_buffer(&params, 0, &staging, RESULT_BYTES, param_bytes);
            }
            backend.read_back(enc, &staging, RESULT_BYTES + param_bytes)
        })?;
        let (result, values) = words.split_at(RESULT_BYTES as usize / 4);
        for (i, logit) in model.opacity_logits.iter_mut().enumerate() {
            *logit = f32::from_bits(values[20 * i + 16]);
        }
        Ok(outcome(result))
    }

    fn upload_model(
        &self,
        backend: &GpuBackend,
        model: &Gaussians<f32>,
    ) -> Result<wgpu::Buffer, RenderError> {
        self.same_device(backend)?;
        model
            .check_consistent()
            .map_err(RenderError::InconsistentModel)?;
        backend.too_large("the model's parameters", 80 * model.len() as u64)?;
        Ok(storage_init(
            &backend.gpu.device,
            &pack_params(model),
            "gaussians",
        ))
    }

    fn same_device(&self, backend: &GpuBackend) -> Result<(), RenderError> {
        if Arc::ptr_eq(&self.gpu, &backend.gpu) {
            Ok(())
        } else {
            Err(RenderError::WrongBackend { backend: "gpu" })
        }
    }

    /// The scratch buffers for `count` Gaussians and at least `views` views.
    fn scratch(&mut self, device: &wgpu::Device, count: usize, views: usize) {
        let s = match self.scratch.take() {
            Some(s) if s.count == count => s,
            _ => Scratch::new(device, count, self.n_params, self.row_floats()),
        };
        let s = self.scratch.insert(s);
        while s.views.len() < views {
            s.views.push((
                storage(device, 4 * count as u64, "decay factor"),
                storage(device, 4 * count as u64, "decay visibility"),
            ));
        }
    }

    fn scratch_ref(&self) -> Result<&Scratch, RenderError> {
        self.scratch
            .as_ref()
            .ok_or_else(|| RenderError::Gpu("the decay's buffers were not set up".into()))
    }

    /// Floats per row of the backward's chunk: the layers' inputs, then their outputs.
    fn strides(&self) -> (usize, usize) {
        let layers = self.dims.len() - 1;
        (
            self.dims[..layers].iter().sum(),
            self.dims[1..].iter().sum(),
        )
    }

    fn row_floats(&self) -> usize {
        let (a, d) = self.strides();
        a + d
    }

    fn mlp_uniform(
        &self,
        count: usize,
        groups: u32,
        pass_kind: u32,
        chunk: (usize, usize),
    ) -> MlpUniform {
        let (act_stride, del_stride) = self.strides();
        let t = (self.step + 1).min(i32::MAX as u64) as i32;
        let mut dims = [[0u32; 4]; 2];
        for (l, &d) in self.dims.iter().enumerate() {
            dims[l / 4][l % 4] = d as u32;
        }
        MlpUniform {
            count: count as u32,
            in_width: self.dims[0] as u32,
            layers: (self.dims.len() - 1) as u32,
            inputs: match self.config.inputs {
                DecayInputs::Official => 0,
                DecayInputs::Paper => 1,
            },
            pass_kind,
            n_params: self.n_params as u32,
            groups,
            row_offset: chunk.0 as u32,
            f_min: self.config.f_min as f32,
            f_max: self.config.f_max as f32,
            lr: self.lr,
            weight_decay: self.weight_decay,
            beta1: MlpAdam::BETA1,
            beta2: MlpAdam::BETA2,
            one_minus_beta1: 1.0 - MlpAdam::BETA1,
            one_minus_beta2: 1.0 - MlpAdam::BETA2,
            bc1: 1.0 - MlpAdam::BETA1.powi(t),
            bc2: 1.0 - MlpAdam::BETA2.powi(t),
            epsilon: MlpAdam::EPSILON,
            pad1: 0.0,
            act_stride: act_stride as u32,
            del_stride: del_stride as u32,
            chunk_rows: chunk.1 as u32,
            pad2: 0,
            dims,
        }
    }

    /// Bind f_θ's kernels for one pass kind and chunk of rows (first row, rows).
    fn mlp_bind(
        &self,
        backend: &GpuBackend,
        params: &wgpu::Buffer,
        kernel: &Kernel,
        pass_kind: u32,
        chunk: (usize, usize),
    ) -> Option<wgpu::BindGroup> {
        let s = self.scratch.as_ref()?;
        let device = &backend.gpu.device;
        let u = uniform(
            device,
            &self.mlp_uniform(s.count, s.groups, pass_kind, chunk),
        );
        Some(kernel.bind(
            device,
            &[
                &u,
                params,
                &self.weights,
                &self.moments,
                &s.stats,
                &s.partials,
                &s.tau,
                &s.d_tau,
                &s.rows,
            ],
        ))
    }

    /// Record the inputs' statistics and τ of every Gaussian of `params`.
    fn encode_forward(
        &self,
        backend: &GpuBackend,
        enc: &mut wgpu::CommandEncoder,
        params: &wgpu::Buffer,
    ) {
        let k = &self.kernels;
        let Some(s) = self.scratch.as_ref() else {
            return;
        };
        if s.count == 0 {
            return;
        }
        let binds: Vec<Option<wgpu::BindGroup>> = (0..2)
            .map(|p| self.mlp_bind(backend, params, &k.input_moments, p, (0, 0)))
            .collect();
        let mut pass = enc.begin_compute_pass(&Default::default());
        for b in binds.iter().flatten() {
            k.input_moments.dispatch_groups(&mut pass, b, s.groups);
            k.input_stats.dispatch_groups(&mut pass, b, 1);
        }
        if let Some(b) = &binds[0] {
            k.mlp_forward.dispatch_items(&mut pass, b, s.count as u32);
        }
    }

    /// Record dL/dθ from the accumulated dL/dτ and (with `step`) f_θ's Adam step: per
    /// chunk of rows, each row's forward and backward (`mlp_rows`), then per 256 rows the
    /// weight gradient (`mlp_outer`); then the partials in order and Adam (`mlp_adam`).
    fn encode_weight_step(
        &self,
        backend: &GpuBackend,
        enc: &mut wgpu::CommandEncoder,
        params: &wgpu::Buffer,
        step: bool,
    ) {
        let k = &self.kernels;
        let Some(s) = self.scratch.as_ref() else {
            return;
        };
        let kind = u32::from(step);
        // (bind group, rows) per chunk.
        let chunks: Vec<(wgpu::BindGroup, u32)> = (0..s.count)
            .step_by(CHUNK_ROWS)
            .filter_map(|start| {
                let rows = CHUNK_ROWS.min(s.count - start);
                self.mlp_bind(backend, params, &k.mlp_rows, kind, (start, rows))
                    .map(|b| (b, rows as u32))
            })
            .collect();
        let Some(last) = self.mlp_bind(backend, params, &k.mlp_adam, kind, (0, 0)) else {
            return;
        };
        if s.count == 0 {
            // No rows: a zero gradient.
            enc.clear_buffer(&s.partials, 0, None);
        }
        let mut pass = enc.begin_compute_pass(&Default::default());
        for (b, rows) in &chunks {
            k.mlp_rows.dispatch_items(&mut pass, b, *rows);
            k.mlp_outer.dispatch_groups(&mut pass, b, rows.div_ceil(WG));
        }
        k.mlp_adam.dispatch_groups(&mut pass, &last, 1);
    }

    /// Before a decayed step's render: the inputs' statistics, τ, and per view (`views`,
    /// the renderer's view constants) visibility, factor and "seen". Submitted at once;
    /// returns the views' factor buffers to render with (neural only: the hand-tuned
    /// variants render without a factor).
    pub(crate) fn begin_step(
        &mut self,
        backend: &GpuBackend,
        params: &wgpu::Buffer,
        count: usize,
        views: &[ViewUniform],
    ) -> Result<Option<Vec<wgpu::Buffer>>, RenderError> {
        self.same_device(backend)?;
        let device = &backend.gpu.device;
        let k = self.kernels.clone();
        let mode = match self.config.visibility {
            VisibilityMode::Off => 0,
            VisibilityMode::NearPlane => 1,
            VisibilityMode::Frustum => 2,
        };
        let near = self.config.near as f32;
        backend.checked(|| {
            self.scratch(device, count, views.len());
            let mut enc = device.create_command_encoder(&Default::default());
            if self.neural() {
                self.encode_forward(backend, &mut enc, params);
            }
            let s = self.scratch_ref()?;
            enc.clear_buffer(&s.seen, 0, None);
            enc.clear_buffer(&s.d_tau, 0, None);
            let binds: Vec<wgpu::BindGroup> = views
                .iter()
                .zip(&s.views)
                .map(|(v, (factor, vis))| {
                    let u = uniform(
                        device,
                        &ViewDecayUniform {
                            rot: v.rot,
                            trans: v.trans,
                            focal: v.focal,
                            width: v.width,
                            height: v.height,
                            count: count as u32,
                            mode,
                            t: v.t,
                            near,
                            pad: [0.0; 2],
                        },
                    );
                    k.decay_visibility.bind(
                        device,
                        &[&u, params, &s.tau, factor, vis, &s.seen, &s.d_tau, &s.tau],
                    )
                })
                .collect();
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                for b in &binds {
                    k.decay_visibility
                        .dispatch_items(&mut pass, b, count as u32);
                }
            }
            self.gpu.queue.submit([enc.finish()]);
            Ok(self.neural().then(|| {
                s.views[..views.len()]
                    .iter()
                    .map(|(f, _)| f.clone())
                    .collect()
            }))
        })
    }

    /// After view `v`'s backward into `view_grads`: add its dL/dτ where it was visible.
    pub(crate) fn encode_gather(
        &self,
        backend: &GpuBackend,
        enc: &mut wgpu::CommandEncoder,
        v: usize,
        params: &wgpu::Buffer,
        view_grads: &wgpu::Buffer,
    ) {
        let Some(s) = self.scratch.as_ref().filter(|_| self.neural()) else {
            return;
        };
        let Some((factor, vis)) = s.views.get(v) else {
            return;
        };
        let device = &backend.gpu.device;
        let k = &self.kernels;
        let u = uniform(
            device,
            &ViewDecayUniform {
                rot: [[0.0; 4]; 3],
                trans: [0.0; 4],
                focal: [0.0; 4],
                width: 0,
                height: 0,
                count: s.count as u32,
                mode: 0,
                t: 0.0,
                near: 0.0,
                pad: [0.0; 2],
            },
        );
        let b = k.decay_gather.bind(
            device,
            &[
                &u, params, &s.tau, factor, vis, &s.seen, &s.d_tau, view_grads,
            ],
        );
        let mut pass = enc.begin_compute_pass(&Default::default());
        k.decay_gather.dispatch_items(&mut pass, &b, s.count as u32);
    }

    /// After the last view's gather and before the Gaussians' Adam: f_θ's gradient and
    /// Adam step (on the pre-step model in `params`).
    pub(crate) fn encode_mlp_step(
        &self,
        backend: &GpuBackend,
        enc: &mut wgpu::CommandEncoder,
        params: &wgpu::Buffer,
    ) {
        if self.neural() {
            self.encode_weight_step(backend, enc, params, true);
        }
    }

    /// After the Gaussians' Adam: the write-back into `params` and the step's statistics,
    /// copied with the skipped flag into `staging` at `offset` ([`RESULT_BYTES`]).
    pub(crate) fn encode_apply(
        &self,
        backend: &GpuBackend,
        enc: &mut wgpu::CommandEncoder,
        params: &wgpu::Buffer,
        staging: &wgpu::Buffer,
        offset: u64,
    ) {
        let Some(s) = self.scratch.as_ref() else {
            return;
        };
        let device = &backend.gpu.device;
        let k = &self.kernels;
        let c = &self.config;
        let u = uniform(
            device,
            &ApplyUniform {
                count: s.count as u32,
                groups: s.groups,
                variant: match c.variant {
                    DecayVariant::Constant => 1,
                    DecayVariant::Pow => 2,
                    DecayVariant::Exp => 3,
                    DecayVariant::Neural | DecayVariant::None => 0,
                },
                pad0: 0,
                beta: c.beta as f32,
                one_minus_beta: (1.0 - c.beta) as f32,
                ln_beta: c.beta.ln() as f32,
                constant: c.constant as f32,
                f_min: c.f_min as f32,
                f_max: c.f_max as f32,
                pow_gamma: c.pow_gamma as f32,
                exp_kappa: c.exp_kappa as f32,
            },
        );
        let b = k.decay_apply.bind(
            device,
            &[&u, params, &s.tau, &s.seen, &s.apply_partials, &s.summary],
        );
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            k.decay_apply.dispatch_groups(&mut pass, &b, s.groups);
            k.decay_summary.dispatch_groups(&mut pass, &b, 1);
        }
        enc.copy_buffer_to_buffer(&s.summary, 0, staging, offset, 16);
        if self.neural() {
            let flag = 4 * (16 + self.n_params) as u64;
            enc.copy_buffer_to_buffer(&s.stats, flag, staging, offset + 16, 4);
        }
    }

    /// Read a step's [`RESULT_BYTES`] and count f_θ's step.
    pub(crate) fn finish_step(&mut self, words: &[u32]) -> DecayOutcome {
        let o = outcome(words);
        if self.neural() && !o.skipped {
            self.step += 1;
        }
        o
    }
}

/// A step's outcome from its [`RESULT_BYTES`] (statistics, then the skipped flag).
fn outcome(words: &[u32]) -> DecayOutcome {
    let word = |k: usize| words.get(k).copied().unwrap_or(0);
    DecayOutcome {
        visible: word(0) as usize,
        min_factor: f32::from_bits(word(1)),
        max_factor: f32::from_bits(word(2)),
        factor_sum: f32::from_bits(word(3)),
        skipped: words.get(4).is_some_and(|&flag| flag != 0),
    }
}

/// A storage buffer holding `data` that kernels may also write.
fn writable(backend: &GpuBackend, data: &[f32], label: &str) -> wgpu::Buffer {
    let b = storage(&backend.gpu.device, 4 * data.len() as u64, label);
    if !data.is_empty() {
        backend
            .gpu
            .queue
            .write_buffer(&b, 0, bytemuck::cast_slice(data));
    }
    b
}

impl Scratch {
    fn new(device: &wgpu::Device, count: usize, n_params: usize, row_floats: usize) -> Self {
        let groups = count.div_ceil(WG as usize).max(1);
        let f = |words: usize, label: &str| storage(device, 4 * words as u64, label);
        Self {
            count,
            groups: groups as u32,
            stats: f(16 + n_params + 1, "decay input statistics"),
            partials: f(groups * n_params.max(8), "decay partials"),
            tau: f(count, "decay τ"),
            d_tau: f(count, "decay dL/dτ"),
            seen: f(count, "decay seen"),
            apply_partials: f(4 * groups, "decay step partials"),
            summary: f(4, "decay step statistics"),
            rows: f(count.min(CHUNK_ROWS) * row_floats, "decay rows"),
            views: Vec::new(),
        }
    }
}
