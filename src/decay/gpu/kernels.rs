//! The neural decay's compute pipelines (WGSL in `shaders/decay_*.wgsl`; each file's
//! kernels share one bind-group layout). Built with the GPU toolkit
//! (`gpu::compute`) once per device, on first use ([`DecayKernels::of`]).

use crate::gpu::compute::{Kernel, Slot, layout, shader};
use crate::math::GAUSSIAN_WGSL;
use crate::render::gpu::GpuBackend;
use Slot::{Read, ReadWrite, Uniform};
use std::sync::Arc;

/// Every pipeline of the decay's device side.
pub(super) struct DecayKernels {
    pub input_moments: Kernel,
    pub input_stats: Kernel,
    pub mlp_forward: Kernel,
    pub mlp_rows: Kernel,
    pub mlp_outer: Kernel,
    pub mlp_adam: Kernel,
    pub decay_visibility: Kernel,
    pub decay_gather: Kernel,
    pub decay_apply: Kernel,
    pub decay_summary: Kernel,
}

impl DecayKernels {
    /// The kernels of `backend`'s device (built on the first call).
    pub fn of(backend: &GpuBackend) -> Arc<Self> {
        backend.gpu.pipelines(Self::new)
    }

    fn new(device: &wgpu::Device) -> Self {
        let decay_mlp = shader(
            device,
            "decay_mlp",
            &[GAUSSIAN_WGSL],
            include_str!("shaders/decay_mlp.wgsl"),
        );
        let decay_view = shader(
            device,
            "decay_view",
            &[GAUSSIAN_WGSL],
            include_str!("shaders/decay_view.wgsl"),
        );
        let decay_apply = shader(
            device,
            "decay_apply",
            &[GAUSSIAN_WGSL],
            include_str!("shaders/decay_apply.wgsl"),
        );
        let mlp_layout = layout(
            device,
            "decay_mlp",
            &[
                Uniform, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
                ReadWrite,
            ],
        );
        let view_layout = layout(
            device,
            "decay_view",
            &[
                Uniform, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite, Read,
            ],
        );
        let apply_layout = layout(
            device,
            "decay_apply",
            &[Uniform, ReadWrite, Read, Read, ReadWrite, ReadWrite],
        );
        let k = Kernel::new;
        Self {
            input_moments: k(device, &decay_mlp, "input_moments", &mlp_layout),
            input_stats: k(device, &decay_mlp, "input_stats", &mlp_layout),
            mlp_forward: k(device, &decay_mlp, "mlp_forward", &mlp_layout),
            mlp_rows: k(device, &decay_mlp, "mlp_rows", &mlp_layout),
            mlp_outer: k(device, &decay_mlp, "mlp_outer", &mlp_layout),
            mlp_adam: k(device, &decay_mlp, "mlp_adam", &mlp_layout),
            decay_visibility: k(device, &decay_view, "decay_visibility", &view_layout),
            decay_gather: k(device, &decay_view, "decay_gather", &view_layout),
            decay_apply: k(device, &decay_apply, "decay_apply", &apply_layout),
            decay_summary: k(device, &decay_apply, "decay_summary", &apply_layout),
        }
    }
}
