//! Host side of the GPU prefix sum and radix sort: which kernels run, over which buffers,
//! in what order. The work itself is in `shaders/scan.wgsl` and `shaders/sort.wgsl`.

use super::kernels::Kernels;
use crate::gpu::compute::{WG, uniform};
use crate::gpu::{Gpu, Pooled};

/// An inclusive prefix sum of `len` u32 in a buffer, prepared once: one level per factor
/// of 256 (each level scans the block totals of the one before).
pub struct Scan {
    levels: Vec<(wgpu::BindGroup, u32)>,
    /// The levels' block sums, held while the bind groups are in use.
    _sums: Vec<Pooled>,
}

impl Scan {
    pub fn new(gpu: &Gpu, kernels: &Kernels, data: &wgpu::Buffer, len: u32) -> Self {
        let device = &gpu.device;
        let mut levels = Vec::new();
        let mut sums: Vec<Pooled> = Vec::new();
        let mut n = len;
        while n > 0 {
            let blocks = n.div_ceil(WG);
            let level_sums = gpu.scratch(4 * blocks as u64, "scan block sums");
            let params = uniform(device, &[n, 0, 0, 0]);
            let current = sums.last().map_or(data, |s| s);
            let group = kernels
                .scan_blocks
                .bind(device, &[&params, current, &level_sums]);
            levels.push((group, blocks));
            sums.push(level_sums);
            if blocks == 1 {
                break;
            }
            n = blocks;
        }
        Self {
            levels,
            _sums: sums,
        }
    }

    /// Record the scan: every level's block scans, then the block offsets top-down.
    pub fn encode(&self, kernels: &Kernels, pass: &mut wgpu::ComputePass<'_>) {
        for (group, blocks) in &self.levels {
            kernels.scan_blocks.dispatch_groups(pass, group, *blocks);
        }
        for (group, blocks) in self.levels.iter().rev().skip(1) {
            kernels
                .add_block_offsets
                .dispatch_groups(pass, group, *blocks);
        }
    }
}

/// (tile, depth, value) entries in two sets of buffers the sort ping-pongs between.
pub struct SortBuffers {
    pub a: [Pooled; 3],
    pub b: [Pooled; 3],
}

impl SortBuffers {
    pub fn new(gpu: &Gpu, entries: u64) -> Self {
        let make = |name| gpu.scratch(4 * entries, name);
        Self {
            a: [make("keys tile"), make("keys depth"), make("keys value")],
            b: [
                make("keys tile 2"),
                make("keys depth 2"),
                make("keys value 2"),
            ],
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Pass {
    count: u32,
    shift: u32,
    blocks: u32,
    by_tile: u32,
}

/// Record a stable sort of the first `count` entries of `buffers.a` by (tile, depth):
/// eight 4-bit passes over the depth bits, then enough passes over the `tile_bits` low
/// bits of the tile. Returns whether the sorted entries ended in `b` (else in `a`).
pub fn encode_sort(
    gpu: &Gpu,
    kernels: &Kernels,
    pass: &mut wgpu::ComputePass<'_>,
    buffers: &SortBuffers,
    count: u32,
    tile_bits: u32,
) -> bool {
    if count == 0 {
        return false;
    }
    let device = &gpu.device;
    let blocks = count.div_ceil(WG);
    let table = gpu.scratch(4 * 16 * blocks as u64, "sort digit table");
    let scan = Scan::new(gpu, kernels, &table, 16 * blocks);
    let passes = (0..8)
        .map(|p| (0u32, 4 * p))
        .chain((0..tile_bits.div_ceil(4)).map(|p| (1u32, 4 * p)));
    let mut in_b = false;
    for (by_tile, shift) in passes {
        let (src, dst) = if in_b {
            (&buffers.b, &buffers.a)
        } else {
            (&buffers.a, &buffers.b)
        };
        let params = uniform(
            device,
            &Pass {
                count,
                shift,
                blocks,
                by_tile,
            },
        );
        let group = kernels.histogram.bind(
            device,
            &[
                &params, &src[0], &src[1], &src[2], &dst[0], &dst[1], &dst[2], &table,
            ],
        );
        kernels.histogram.dispatch_groups(pass, &group, blocks);
        scan.encode(kernels, pass);
        kernels.scatter.dispatch_groups(pass, &group, blocks);
        in_b = !in_b;
    }
    in_b
}
