//! The renderer's compute pipelines (WGSL in `shaders/`): forward, scan, sort, tile
//! ranges, and the two backward kernels. Built with the [`crate::gpu::compute`] toolkit by
//! `GpuBackend::new`; the trainer's and the decay's kernels are built by their owners.

use crate::gpu::Gpu;
use crate::gpu::compute::{Kernel, Slot, layout, shader};
use crate::math::GAUSSIAN_WGSL;
use Slot::{Read, ReadWrite, Uniform};

/// The view constants and the splat record (`shaders/view.wgsl`), for the kernels that read them.
const VIEW: &str = include_str!("shaders/view.wgsl");

/// Every pipeline of the renderer.
pub struct Kernels {
    pub preprocess: Kernel,
    pub emit: Kernel,
    pub scan_blocks: Kernel,
    pub add_block_offsets: Kernel,
    pub histogram: Kernel,
    pub scatter: Kernel,
    pub ranges: Kernel,
    pub rasterise: Kernel,
    pub rasterise_backward: Kernel,
    pub preprocess_backward: Kernel,
    /// `rasterise_backward` sums with subgroup operations (and the sort's `scatter` ranks
    /// with them, where subgroups have one size).
    pub subgroups: bool,
}

impl Kernels {
    /// The pipelines; with `subgroups`, where [`Gpu::subgroups`] allows, the backward sums
    /// over a tile's pixels with subgroup operations.
    pub fn new(gpu: &Gpu, subgroups: bool) -> Self {
        let device = &gpu.device;
        let subgroups = subgroups && gpu.subgroups();
        let preprocess = shader(
            device,
            "preprocess",
            &[VIEW, GAUSSIAN_WGSL],
            include_str!("shaders/preprocess.wgsl"),
        );
        let preprocess_backward = shader(
            device,
            "preprocess_backward",
            &[VIEW, GAUSSIAN_WGSL],
            include_str!("shaders/preprocess_backward.wgsl"),
        );
        // Sums over a tile's pixels with subgroup operations where the device has them.
        let raster_backward = shader(
            device,
            "raster_backward",
            &[VIEW, include_str!("shaders/raster_backward_pixel.wgsl")],
            if subgroups {
                include_str!("shaders/raster_backward_subgroup.wgsl")
            } else {
                include_str!("shaders/raster_backward.wgsl")
            },
        );
        let emit = shader(device, "emit", &[VIEW], include_str!("shaders/emit.wgsl"));
        let scan = shader(device, "scan", &[], include_str!("shaders/scan.wgsl"));
        // Ranks a block's entries with subgroup ballots where subgroups have one size.
        let sort = shader(
            device,
            "sort",
            &[include_str!("shaders/sort.wgsl")],
            if subgroups && gpu.info.subgroup_min_size == gpu.info.subgroup_max_size {
                include_str!("shaders/sort_scatter_subgroup.wgsl")
            } else {
                include_str!("shaders/sort_scatter.wgsl")
            },
        );
        let ranges = shader(device, "ranges", &[], include_str!("shaders/ranges.wgsl"));
        let raster = shader(
            device,
            "raster",
            &[VIEW],
            include_str!("shaders/raster.wgsl"),
        );
        let k = |m: &wgpu::ShaderModule, entry: &str, slots: &[Slot]| {
            Kernel::alone(device, m, entry, slots)
        };
        // Kernels that share bind groups share one layout.
        let scan_layout = layout(device, "scan", &[Uniform, ReadWrite, ReadWrite]);
        let sort_layout = layout(device, "sort", &SORT_SLOTS);
        Self {
            preprocess: k(
                &preprocess,
                "preprocess",
                &[Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite],
            ),
            emit: k(
                &emit,
                "emit",
                &[Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite],
            ),
            scan_blocks: Kernel::new(device, &scan, "scan_blocks", &scan_layout),
            add_block_offsets: Kernel::new(device, &scan, "add_block_offsets", &scan_layout),
            histogram: Kernel::new(device, &sort, "histogram", &sort_layout),
            scatter: Kernel::new(device, &sort, "scatter", &sort_layout),
            ranges: k(&ranges, "tile_ranges", &[Uniform, Read, ReadWrite]),
            rasterise: k(
                &raster,
                "rasterise",
                &[
                    Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
                ],
            ),
            rasterise_backward: k(
                &raster_backward,
                "rasterise_backward",
                &[Uniform, Read, Read, Read, Read, Read, Read, ReadWrite],
            ),
            preprocess_backward: k(
                &preprocess_backward,
                "preprocess_backward",
                &[
                    Uniform, Read, Read, Read, Read, Read, Read, ReadWrite, ReadWrite,
                ],
            ),
            subgroups,
        }
    }
}

const SORT_SLOTS: [Slot; 8] = [
    Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
];
