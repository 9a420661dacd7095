//! Host side of the GPU training loss: `(1 − λ)·L1 + λ·(1 − SSIM)` of a rendered image
//! against its target and `d(loss)/d(rendered)`, as `train::loss::image_loss` computes
//! them (`shaders/loss.wgsl`). Three passes over the image's values — horizontal blur of
//! both images; local means, centred (co)variances over the 11×11 window, SSIM and its
//! partials; the gradient gathered over the window — and one workgroup that adds the
//! per-workgroup sums of 1 − SSIM, |r − t|, (r − t)² and SSIM, so the scalar loss costs 16 bytes of
//! read-back. The centred variances avoid the f32 cancellation of `E[x²] − µ²` that
//! limits the CPU's f32 path on flat images.
//! A target may be uploaded as bytes and converted on the device (`shaders/unpack.wgsl`).

use super::kernels::TrainKernels;
use crate::gpu::compute::{WG, grid, read_buffer, storage, storage_init, uniform};
use crate::gpu::{Gpu, Pooled};
use crate::metrics::ssim::{C1, C2, RADIUS, SIGMA};
use crate::render::RenderError;
use crate::render::gpu::GpuBackend;
use crate::train::loss::LossValue;

/// The loss constants (`LossParams` in `shaders/loss.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LossUniform {
    width: u32,
    height: u32,
    count: u32,
    groups: u32,
    c1: f32,
    c2: f32,
    inv_count: f32,
    wl: f32,
    ws: f32,
    scale: f32,
    pad: [f32; 2],
    window: [[f32; 4]; 3],
}

/// The 11-tap window of `metrics::ssim`, normalised in f64 and rounded to f32.
fn window() -> [[f32; 4]; 3] {
    let taps: Vec<f64> = (0..=2 * RADIUS)
        .map(|k| {
            let d = k as f64 - RADIUS as f64;
            (-d * d / (2.0 * SIGMA * SIGMA)).exp()
        })
        .collect();
    let total: f64 = taps.iter().sum();
    let mut out = [[0.0f32; 4]; 3];
    for (k, t) in taps.iter().enumerate() {
        out[k / 4][k % 4] = (t / total) as f32;
    }
    out
}

/// The device buffers and bind group of the loss of one `width × height` image.
pub(super) struct LossPass {
    count: u32,
    /// Workgroups of the per-value passes, as dispatched (x·y of their grid).
    groups: u32,
    bind: wgpu::BindGroup,
    /// The blurred images and per-value partials, held while `bind` is in use.
    _scratch: [Pooled; 2],
    /// Per-workgroup sums, then the total (Σ 1 − SSIM, Σ |r − t|, Σ (r − t)², Σ SSIM).
    pub sums: wgpu::Buffer,
    /// `d(loss)/d(rendered)` times the scale, interleaved RGB.
    pub grad: wgpu::Buffer,
}

impl LossPass {
    /// Buffers for the loss of `rendered` against `target` (both `3·width·height` f32 on
    /// the device), gradient weighted by `scale` and written into `grad` (a new buffer
    /// when `None`). `width·height > 0`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gpu: &Gpu,
        kernels: &TrainKernels,
        (width, height): (u32, u32),
        rendered: &wgpu::Buffer,
        target: &wgpu::Buffer,
        lambda_ssim: f64,
        scale: f32,
        grad: Option<&wgpu::Buffer>,
    ) -> Self {
        let count = 3 * width * height;
        let (x, y) = grid(count.div_ceil(WG));
        let groups = x * y;
        let n = count as f64;
        let params = LossUniform {
            width,
            height,
            count,
            groups,
            c1: C1 as f32,
            c2: C2 as f32,
            inv_count: (1.0 / n) as f32,
            wl: ((1.0 - lambda_ssim) / n) as f32,
            ws: -lambda_ssim as f32,
            scale,
            pad: [0.0; 2],
            window: window(),
        };
        let device = &gpu.device;
        let params = uniform(device, &params);
        let tmp = gpu.scratch(8 * count as u64, "loss blurred images");
        let partial = gpu.scratch(20 * count as u64, "loss partials");
        let sums = storage(device, 16 * (groups as u64 + 1), "loss sums");
        let grad = match grad {
            Some(g) => g.clone(),
            None => storage(device, 4 * count as u64, "loss gradient"),
        };
        let bind = kernels.ssim_pixel.bind(
            device,
            &[&params, rendered, target, &tmp, &partial, &sums, &grad],
        );
        Self {
            count,
            groups,
            bind,
            _scratch: [tmp, partial],
            sums,
            grad,
        }
    }

    /// Record the passes.
    pub fn encode(&self, kernels: &TrainKernels, pass: &mut wgpu::ComputePass<'_>) {
        for k in [
            &kernels.ssim_blur_h,
            &kernels.ssim_pixel,
            &kernels.ssim_grad,
        ] {
            k.dispatch_items(pass, &self.bind, self.count);
        }
        kernels.reduce_sums.dispatch_groups(pass, &self.bind, 1);
    }

    /// Byte offset of the total in `sums`.
    pub fn total_offset(&self) -> u64 {
        16 * self.groups as u64
    }

    /// The loss from the read-back total (Σ 1 − SSIM, Σ |r − t|, Σ (r − t)², Σ SSIM).
    pub fn value(&self, total: [f32; 4], lambda_ssim: f64) -> LossValue {
        let n = self.count.max(1) as f64;
        let l1 = total[1] as f64 / n;
        let (dssim, ssim) = if lambda_ssim != 0.0 {
            (total[0] as f64 / n, total[3] as f64 / n)
        } else {
            (0.0, 1.0)
        };
        LossValue {
            total: (1.0 - lambda_ssim) * l1 + lambda_ssim * dssim,
            l1,
            ssim,
            mse: total[2] as f64 / n,
        }
    }
}

/// Bytes four to a word, little-endian (zero padded), as `shaders/unpack.wgsl` reads them.
pub(super) fn pack_bytes(bytes: &[u8]) -> Vec<u32> {
    let mut words = vec![0u32; bytes.len().div_ceil(4)];
    for (i, b) in bytes.iter().enumerate() {
        words[i / 4] |= (*b as u32) << (8 * (i % 4));
    }
    words
}

/// Record the conversion of `count` packed bytes to floats in [0, 1]; the float buffer.
pub(super) fn unpack(
    device: &wgpu::Device,
    k: &TrainKernels,
    enc: &mut wgpu::CommandEncoder,
    packed: &wgpu::Buffer,
    count: u32,
) -> wgpu::Buffer {
    let out = storage(device, 4 * count as u64, "target image");
    let len = uniform(device, &[count, 0, 0, 0]);
    let bind = k.unpack_bytes.bind(device, &[&len, packed, &out]);
    let mut pass = enc.begin_compute_pass(&Default::default());
    k.unpack_bytes.dispatch_items(&mut pass, &bind, count);
    out
}

/// A target image as the host has it.
pub(super) enum Target<'a> {
    Floats(&'a [f32]),
    Bytes(&'a [u8]),
}

/// [`super::GpuTraining::image_loss`] of either kind of target.
pub(super) fn loss(
    backend: &GpuBackend,
    rendered: &[f32],
    target: Target<'_>,
    (width, height): (u32, u32),
    lambda_ssim: f64,
    grad: Option<&mut [f32]>,
) -> Result<LossValue, RenderError> {
    let count = 3 * width as u64 * height as u64;
    let length = |what, got: usize| {
        if got as u64 == count {
            Ok(())
        } else {
            Err(RenderError::ImageLength {
                what,
                expected: count,
                got,
            })
        }
    };
    length("rendered image", rendered.len())?;
    match target {
        Target::Floats(t) => length("target image", t.len())?,
        Target::Bytes(t) => length("target image", t.len())?,
    }
    if let Some(g) = grad.as_deref() {
        length("loss gradient", g.len())?;
    }
    if count == 0 {
        // As on the CPU: nothing to compare, SSIM 1.
        return Ok(LossValue {
            total: 0.0,
            l1: 0.0,
            ssim: 1.0,
            mse: 0.0,
        });
    }
    // The largest buffer: five partials per value.
    backend.too_large("the loss's partials", 20 * count)?;
    let kernels = TrainKernels::of(backend);
    let out = backend.checked(|| {
        loss_checked(
            backend,
            &kernels,
            rendered,
            target,
            (width, height),
            lambda_ssim,
            grad.is_some(),
        )
    })?;
    let (value, g) = out;
    if let Some(dst) = grad {
        dst.copy_from_slice(&g);
    }
    Ok(value)
}

fn loss_checked(
    backend: &GpuBackend,
    k: &TrainKernels,
    rendered: &[f32],
    target: Target<'_>,
    size: (u32, u32),
    lambda_ssim: f64,
    want_grad: bool,
) -> Result<(LossValue, Vec<f32>), RenderError> {
    let device = &backend.gpu.device;
    let rendered_buf = storage_init(device, rendered, "rendered image");
    let count = rendered.len() as u32;
    let mut enc = device.create_command_encoder(&Default::default());
    let target_buf = match target {
        Target::Floats(t) => storage_init(device, t, "target image"),
        Target::Bytes(t) => {
            let packed = storage_init(device, &pack_bytes(t), "target bytes");
            unpack(device, k, &mut enc, &packed, count)
        }
    };
    let loss = LossPass::new(
        &backend.gpu,
        k,
        size,
        &rendered_buf,
        &target_buf,
        lambda_ssim,
        1.0,
        None,
    );
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        loss.encode(k, &mut pass);
    }
    let grad_bytes = if want_grad { 4 * count as u64 } else { 0 };
    let staging = read_buffer(device, 16 + grad_bytes);
    enc.copy_buffer_to_buffer(&loss.sums, loss.total_offset(), &staging, 0, 16);
    if want_grad {
        enc.copy_buffer_to_buffer(&loss.grad, 0, &staging, 16, grad_bytes);
    }
    let words = backend.read_back(enc, &staging, 16 + grad_bytes)?;
    let floats: &[f32] = bytemuck::cast_slice(&words);
    let total = [floats[0], floats[1], floats[2], floats[3]];
    Ok((loss.value(total, lambda_ssim), floats[4..].to_vec()))
}
