//! Densification statistics on the device (`shaders/stats.wgsl`): per Gaussian the sum of
//! its view-space gradient norms, how many views drew it, and its largest screen radius,
//! added view by view inside [`GpuAdam::train_step_decayed`](super::GpuAdam) so a
//! training step reads nothing back for them; the host reads them when it densifies.

use super::kernels::TrainKernels;
use crate::gpu::Gpu;
use crate::gpu::compute::{read_buffer, storage, uniform};
use crate::render::RenderError;
use crate::render::gpu::GpuBackend;
use crate::train::densify::DensifyStats;
use std::sync::Arc;

/// The constants of one view's record (`StatsParams` in `shaders/stats.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct StatsUniform {
    count: u32,
    pad: [u32; 2],
    to_ndc: f32,
}

/// [`DensifyStats`] resident on the GPU.
pub struct GpuStats {
    gpu: Arc<Gpu>,
    kernels: Arc<TrainKernels>,
    count: usize,
    grad_sum: wgpu::Buffer,
    seen: wgpu::Buffer,
    max_radius: wgpu::Buffer,
}

impl GpuStats {
    /// Upload `stats` (one entry per Gaussian).
    pub fn upload(backend: &GpuBackend, stats: &DensifyStats) -> Result<Self, RenderError> {
        let n = stats.grad_sum.len();
        if stats.count.len() != n || stats.max_radius.len() != n {
            return Err(RenderError::InconsistentModel(format!(
                "densification statistics of unequal lengths ({}, {}, {})",
                n,
                stats.count.len(),
                stats.max_radius.len()
            )));
        }
        backend.too_large("the densification statistics", 4 * n as u64)?;
        let device = &backend.gpu.device;
        let kernels = TrainKernels::of(backend);
        backend.checked(|| {
            let s = Self {
                gpu: backend.gpu.clone(),
                kernels,
                count: n,
                grad_sum: storage(device, 4 * n as u64, "gradient norm sums"),
                seen: storage(device, 4 * n as u64, "views seen"),
                max_radius: storage(device, 4 * n as u64, "largest radii"),
            };
            if n > 0 {
                let q = &backend.gpu.queue;
                q.write_buffer(&s.grad_sum, 0, bytemuck::cast_slice(&stats.grad_sum));
                q.write_buffer(&s.seen, 0, bytemuck::cast_slice(&stats.count));
                q.write_buffer(&s.max_radius, 0, bytemuck::cast_slice(&stats.max_radius));
            }
            Ok(s)
        })
    }

    /// Gaussians counted.
    pub fn len(&self) -> usize {
        self.count
    }

    /// No Gaussians.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Read the statistics back.
    pub fn download(&self, backend: &GpuBackend) -> Result<DensifyStats, RenderError> {
        if !Arc::ptr_eq(&self.gpu, &backend.gpu) {
            return Err(RenderError::WrongBackend { backend: "gpu" });
        }
        let n = self.count;
        let bytes = 4 * n as u64;
        let device = &backend.gpu.device;
        let words = backend.checked(|| {
            let staging = read_buffer(device, 3 * bytes);
            let mut enc = device.create_command_encoder(&Default::default());
            if n > 0 {
                for (k, b) in [&self.grad_sum, &self.seen, &self.max_radius]
                    .into_iter()
                    .enumerate()
                {
                    enc.copy_buffer_to_buffer(b, 0, &staging, k as u64 * bytes, bytes);
                }
            }
            backend.read_back(enc, &staging, 3 * bytes)
        })?;
        if n == 0 {
            return Ok(DensifyStats::new(0));
        }
        let floats =
            |k: usize| -> Vec<f32> { bytemuck::cast_slice(&words[k * n..(k + 1) * n]).to_vec() };
        Ok(DensifyStats {
            grad_sum: floats(0),
            count: words[n..2 * n].to_vec(),
            max_radius: floats(2),
        })
    }

    /// Record adding one view: `view_grads` (five vec4 per Gaussian, as the backward
    /// writes them), `radii` of its render, `to_ndc` as `DensifyStats::record` computes it.
    pub(super) fn encode_record(
        &self,
        backend: &GpuBackend,
        enc: &mut wgpu::CommandEncoder,
        view_grads: &wgpu::Buffer,
        radii: &wgpu::Buffer,
        to_ndc: f32,
    ) {
        if self.count == 0 {
            return;
        }
        let device = &backend.gpu.device;
        let k = &self.kernels;
        let u = uniform(
            device,
            &StatsUniform {
                count: self.count as u32,
                pad: [0; 2],
                to_ndc,
            },
        );
        let bind = k.record_stats.bind(
            device,
            &[
                &u,
                view_grads,
                radii,
                &self.grad_sum,
                &self.seen,
                &self.max_radius,
            ],
        );
        let mut pass = enc.begin_compute_pass(&Default::default());
        k.record_stats
            .dispatch_items(&mut pass, &bind, self.count as u32);
    }
}
