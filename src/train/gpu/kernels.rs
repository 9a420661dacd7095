//! The training step's compute pipelines (WGSL in `shaders/`): the loss passes, the
//! conversion of a byte target, Adam, the batch sum of gradients, the densification
//! statistics and the pseudo views' comparison. Built with the GPU toolkit (`gpu::compute`) once per device,
//! on first use ([`TrainKernels::of`]).

use crate::gpu::compute::{Kernel, Slot, layout, shader};
use crate::render::gpu::GpuBackend;
use Slot::{Read, ReadWrite, Uniform};
use std::sync::Arc;

/// Every pipeline of the training step.
pub(super) struct TrainKernels {
    /// The loss passes (`shaders/loss.wgsl`), sharing one bind group.
    pub ssim_blur_h: Kernel,
    pub ssim_pixel: Kernel,
    pub ssim_grad: Kernel,
    pub reduce_sums: Kernel,
    pub unpack_bytes: Kernel,
    pub adam_step: Kernel,
    pub add_into: Kernel,
    pub record_stats: Kernel,
    /// The pseudo-view term (`shaders/pseudo.wgsl`), sharing one layout.
    pub pseudo_land: Kernel,
    pub pseudo_resolve: Kernel,
}

impl TrainKernels {
    /// The kernels of `backend`'s device (built on the first call).
    pub fn of(backend: &GpuBackend) -> Arc<Self> {
        backend.gpu.pipelines(Self::new)
    }

    fn new(device: &wgpu::Device) -> Self {
        let loss = shader(device, "loss", &[], include_str!("shaders/loss.wgsl"));
        let unpack = shader(device, "unpack", &[], include_str!("shaders/unpack.wgsl"));
        let adam = shader(device, "adam", &[], include_str!("shaders/adam.wgsl"));
        let add = shader(device, "add", &[], include_str!("shaders/add.wgsl"));
        let stats = shader(device, "stats", &[], include_str!("shaders/stats.wgsl"));
        let pseudo = shader(device, "pseudo", &[], include_str!("shaders/pseudo.wgsl"));
        let k = |m: &wgpu::ShaderModule, entry: &str, slots: &[Slot]| {
            Kernel::alone(device, m, entry, slots)
        };
        let loss_layout = layout(
            device,
            "loss",
            &[
                Uniform, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
            ],
        );
        let pseudo_layout = layout(
            device,
            "pseudo",
            &[
                Uniform, Read, Read, Read, Read, Read, Read, ReadWrite, ReadWrite,
            ],
        );
        Self {
            pseudo_land: Kernel::new(device, &pseudo, "pseudo_land", &pseudo_layout),
            pseudo_resolve: Kernel::new(device, &pseudo, "pseudo_resolve", &pseudo_layout),
            ssim_blur_h: Kernel::new(device, &loss, "ssim_blur_h", &loss_layout),
            ssim_pixel: Kernel::new(device, &loss, "ssim_pixel", &loss_layout),
            ssim_grad: Kernel::new(device, &loss, "ssim_grad", &loss_layout),
            reduce_sums: Kernel::new(device, &loss, "reduce_sums", &loss_layout),
            unpack_bytes: k(&unpack, "unpack_bytes", &[Uniform, Read, ReadWrite]),
            add_into: k(&add, "add_into", &[Uniform, Read, ReadWrite]),
            record_stats: k(
                &stats,
                "record_stats",
                &[Uniform, Read, Read, ReadWrite, ReadWrite, ReadWrite],
            ),
            adam_step: k(
                &adam,
                "adam_step",
                &[Uniform, Read, ReadWrite, ReadWrite, ReadWrite],
            ),
        }
    }
}
