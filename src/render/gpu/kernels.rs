//! The compute pipelines of the GPU renderer (WGSL in `shaders/`), their bind-group
//! layouts, and small helpers to bind buffers and dispatch over many workgroups.

use wgpu::util::DeviceExt;

const COMMON: &str = include_str!("shaders/common.wgsl");
/// Per-Gaussian constants and guards of `preprocess` and its backward.
const GAUSSIAN: &str = include_str!("shaders/gaussian.wgsl");

/// Threads per 1D workgroup (`WG` in the shaders).
pub const WG: u32 = 256;
/// Workgroups per dispatch dimension (WebGPU's guaranteed minimum of the limit).
const MAX_GROUPS: u32 = 65_535;

/// How a kernel sees one binding.
#[derive(Clone, Copy)]
enum Slot {
    Uniform,
    Read,
    ReadWrite,
}
use Slot::{Read, ReadWrite, Uniform};

/// One pipeline and its bind-group layout.
pub struct Kernel {
    pub pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

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
    /// The loss passes (`shaders/loss.wgsl`), sharing one bind group.
    pub ssim_blur_h: Kernel,
    pub ssim_pixel: Kernel,
    pub ssim_grad: Kernel,
    pub reduce_sums: Kernel,
    pub unpack_bytes: Kernel,
    pub adam_step: Kernel,
    pub add_into: Kernel,
    pub record_stats: Kernel,
    /// The neural decay (`shaders/decay_*.wgsl`, see `decay.rs`); each file's kernels
    /// share one bind group layout.
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

impl Kernels {
    pub fn new(device: &wgpu::Device) -> Self {
        let module = |name: &str, body: &str| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(format!("{COMMON}\n{body}").into()),
            })
        };
        let with_gaussian = |name: &str, body: &str| module(name, &format!("{GAUSSIAN}\n{body}"));
        let preprocess = with_gaussian("preprocess", include_str!("shaders/preprocess.wgsl"));
        let preprocess_backward = with_gaussian(
            "preprocess_backward",
            include_str!("shaders/preprocess_backward.wgsl"),
        );
        let raster_backward = module(
            "raster_backward",
            include_str!("shaders/raster_backward.wgsl"),
        );
        let emit = module("emit", include_str!("shaders/emit.wgsl"));
        let scan = module("scan", include_str!("shaders/scan.wgsl"));
        let sort = module("sort", include_str!("shaders/sort.wgsl"));
        let ranges = module("ranges", include_str!("shaders/ranges.wgsl"));
        let raster = module("raster", include_str!("shaders/raster.wgsl"));
        let loss = module("loss", include_str!("shaders/loss.wgsl"));
        let unpack = module("unpack", include_str!("shaders/unpack.wgsl"));
        let adam = module("adam", include_str!("shaders/adam.wgsl"));
        let add = module("add", include_str!("shaders/add.wgsl"));
        let stats = module("stats", include_str!("shaders/stats.wgsl"));
        let decay_mlp = with_gaussian("decay_mlp", include_str!("shaders/decay_mlp.wgsl"));
        let decay_view = with_gaussian("decay_view", include_str!("shaders/decay_view.wgsl"));
        let decay_apply = with_gaussian("decay_apply", include_str!("shaders/decay_apply.wgsl"));
        let k = |m: &wgpu::ShaderModule, entry: &str, slots: &[Slot]| {
            kernel(device, m, entry, &layout(device, entry, slots))
        };
        // Kernels that share bind groups share one layout.
        let scan_layout = layout(device, "scan", &[Uniform, ReadWrite, ReadWrite]);
        let sort_layout = layout(device, "sort", &SORT_SLOTS);
        let loss_layout = layout(
            device,
            "loss",
            &[
                Uniform, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
            ],
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
        Self {
            input_moments: kernel(device, &decay_mlp, "input_moments", &mlp_layout),
            input_stats: kernel(device, &decay_mlp, "input_stats", &mlp_layout),
            mlp_forward: kernel(device, &decay_mlp, "mlp_forward", &mlp_layout),
            mlp_rows: kernel(device, &decay_mlp, "mlp_rows", &mlp_layout),
            mlp_outer: kernel(device, &decay_mlp, "mlp_outer", &mlp_layout),
            mlp_adam: kernel(device, &decay_mlp, "mlp_adam", &mlp_layout),
            decay_visibility: kernel(device, &decay_view, "decay_visibility", &view_layout),
            decay_gather: kernel(device, &decay_view, "decay_gather", &view_layout),
            decay_apply: kernel(device, &decay_apply, "decay_apply", &apply_layout),
            decay_summary: kernel(device, &decay_apply, "decay_summary", &apply_layout),
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
            scan_blocks: kernel(device, &scan, "scan_blocks", &scan_layout),
            add_block_offsets: kernel(device, &scan, "add_block_offsets", &scan_layout),
            histogram: kernel(device, &sort, "histogram", &sort_layout),
            scatter: kernel(device, &sort, "scatter", &sort_layout),
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
            ssim_blur_h: kernel(device, &loss, "ssim_blur_h", &loss_layout),
            ssim_pixel: kernel(device, &loss, "ssim_pixel", &loss_layout),
            ssim_grad: kernel(device, &loss, "ssim_grad", &loss_layout),
            reduce_sums: kernel(device, &loss, "reduce_sums", &loss_layout),
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

const SORT_SLOTS: [Slot; 8] = [
    Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
];

fn layout(device: &wgpu::Device, label: &str, slots: &[Slot]) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = slots
        .iter()
        .enumerate()
        .map(|(i, s)| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: match s {
                    Uniform => wgpu::BufferBindingType::Uniform,
                    Read => wgpu::BufferBindingType::Storage { read_only: true },
                    ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    })
}

fn kernel(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    entry: &str,
    layout: &wgpu::BindGroupLayout,
) -> Kernel {
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(entry),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(&pipeline_layout),
        module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    });
    Kernel {
        pipeline,
        layout: layout.clone(),
    }
}

impl Kernel {
    /// A bind group of `buffers`, bound in order.
    pub fn bind(&self, device: &wgpu::Device, buffers: &[&wgpu::Buffer]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// Run over `items` items, `WG` per workgroup (2D grid past 65 535 workgroups).
    pub fn dispatch_items(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        group: &wgpu::BindGroup,
        items: u32,
    ) {
        self.dispatch_groups(pass, group, items.div_ceil(WG));
    }

    /// Run `groups` 1D workgroups (as [`grid`] lays them out).
    pub fn dispatch_groups(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        group: &wgpu::BindGroup,
        groups: u32,
    ) {
        if groups == 0 {
            return;
        }
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, group, &[]);
        let (x, y) = grid(groups);
        pass.dispatch_workgroups(x, y, 1);
    }
}

/// The (x, y) workgroup grid that runs at least `groups` workgroups (x·y may be more).
pub fn grid(groups: u32) -> (u32, u32) {
    let x = groups.clamp(1, MAX_GROUPS);
    (x, groups.div_ceil(x))
}

/// A uniform buffer holding `value`.
pub fn uniform<T: bytemuck::Pod>(device: &wgpu::Device, value: &T) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::bytes_of(value),
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// A storage buffer of `bytes` bytes (at least 64, one splat record, so empty arrays still bind).
pub fn storage(device: &wgpu::Device, bytes: u64, label: &str) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(64).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A storage buffer filled with `data`.
pub fn storage_init<T: bytemuck::Pod>(
    device: &wgpu::Device,
    data: &[T],
    label: &str,
) -> wgpu::Buffer {
    if data.is_empty() {
        return storage(device, 64, label);
    }
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytemuck::cast_slice(data),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
    })
}
