//! The small toolkit every owner of WGSL kernels builds with — the renderer
//! (`render::gpu`), the trainer's device step (`train::gpu`), the neural decay's device
//! side (`decay::gpu`) and LPIPS (`metrics::lpips::gpu`): shader modules with the shared
//! WGSL prepended, pipelines and their bind-group layouts ([`Kernel`]), binding buffers and
//! dispatching over many workgroups, and the buffers kernels read and write. It builds no
//! pipeline itself and knows nothing of Gaussians: each owner builds its own pipelines (the
//! renderer in `GpuBackend::new`, the others once per device through
//! [`super::Gpu::pipelines`]) and keeps its kernels in its own `shaders/` folder.
//!
//! Every module starts with `shaders/kernel.wgsl` (`WG` and `flat_index`), then the
//! preludes its owner names ([`shader`]): the renderer's view and splat records, the
//! per-Gaussian math of `math` (`math::GAUSSIAN_WGSL`).

use wgpu::util::DeviceExt;

const KERNEL: &str = include_str!("shaders/kernel.wgsl");

/// Threads per 1D workgroup (`WG` in the shaders).
pub const WG: u32 = 256;
/// Workgroups per dispatch dimension (WebGPU's guaranteed minimum of the limit).
const MAX_GROUPS: u32 = 65_535;

/// How a kernel sees one binding.
#[derive(Clone, Copy)]
pub enum Slot {
    Uniform,
    Read,
    ReadWrite,
}
use Slot::{Read, ReadWrite, Uniform};

/// One pipeline and its bind-group layout. Its pipeline is dispatched only through
/// [`Kernel::dispatch_grid`] (and the helpers on it), so a profile sees every dispatch.
pub struct Kernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    /// The entry point, which names the kernel in a profile.
    name: String,
}

/// A shader module of `body` with `shaders/kernel.wgsl` and then `preludes` prepended.
pub fn shader(
    device: &wgpu::Device,
    name: &str,
    preludes: &[&str],
    body: &str,
) -> wgpu::ShaderModule {
    let mut source = String::from(KERNEL);
    for part in preludes.iter().chain([&body]) {
        source.push('\n');
        source.push_str(part);
    }
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    })
}

/// A bind-group layout of `slots`, bound in order.
pub fn layout(device: &wgpu::Device, label: &str, slots: &[Slot]) -> wgpu::BindGroupLayout {
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

impl Kernel {
    /// The pipeline of `entry` in `module` with `layout` (kernels that share bind groups
    /// share one layout).
    pub fn new(
        device: &wgpu::Device,
        module: &wgpu::ShaderModule,
        entry: &str,
        layout: &wgpu::BindGroupLayout,
    ) -> Self {
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
        Self {
            pipeline,
            layout: layout.clone(),
            name: entry.to_owned(),
        }
    }

    /// The pipeline of `entry` in `module` with a layout of its own, of `slots`.
    pub fn alone(
        device: &wgpu::Device,
        module: &wgpu::ShaderModule,
        entry: &str,
        slots: &[Slot],
    ) -> Self {
        Self::new(device, module, entry, &layout(device, entry, slots))
    }

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
        let (x, y) = grid(groups);
        self.dispatch_grid(pass, group, [x, y, 1]);
    }

    /// Run a grid of `[x, y, z]` workgroups.
    pub fn dispatch_grid(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        group: &wgpu::BindGroup,
        [x, y, z]: [u32; 3],
    ) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, group, &[]);
        super::profile::timed(pass, &self.name, |pass| pass.dispatch_workgroups(x, y, z));
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

/// A storage buffer of `bytes` bytes (at least 64, so empty arrays still bind).
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

/// A buffer the host can map and read, of at least 4 bytes.
pub fn read_buffer(device: &wgpu::Device, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read-back"),
        size: bytes.max(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}
