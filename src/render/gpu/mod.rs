//! The wgpu renderer: the CPU path's forward pass as WGSL compute kernels. Per view:
//! `preprocess` (slice in time, opacity, EWA projection, spherindrical colour, support box
//! and tile count per Gaussian) → inclusive scan of the tile counts → `emit` (one
//! (tile, depth) key per touched tile) → stable radix sort → `tile_ranges` →
//! `rasterise` (one 16×16 workgroup per tile, front to back, early termination).
//!
//! A batch of views costs two submissions and two small read-backs: the first pass learns
//! how many (tile, splat) pairs each view has (to size the sort buffers), the second
//! renders every view and copies the images back together. The model is uploaded once per
//! batch.
//!
//! Each frame keeps its forward state on the device (projected splats, tile counts and
//! their scan, sorted entries, tile ranges, final transmittance and last contributor per
//! pixel), and [`RenderBackend::backward`] runs on it in one submission with one read-back
//! ([`backward`]): `rasterise_backward` per tile, back to front, then
//! `preprocess_backward` per Gaussian (colour, projection and slicing backward). The
//! gradients are of the model as uploaded by the render.
//!
//! This module renders and differentiates, nothing else: forward, backward, scan and sort,
//! built on the device and kernel toolkit of [`crate::gpu`]. It imports nothing of the
//! trainer or the decay. The training step
//! on the device (loss, Adam, densification statistics) is `train::gpu`, the neural
//! decay's device side `decay::gpu`; each builds its own pipelines. What they use of the
//! renderer is `pub(crate)`: the device and its error scope and read-back
//! (`GpuBackend::checked`, `GpuBackend::read_back`), the model's upload layout
//! (`pack_params`, `ModelBuffers`), rendering a model already on the device without
//! reading its images back (`GpuBackend::render_uploaded`), and a frame's device buffers
//! and backward (`GpuFrame`, `encode_backward`).

mod backward;
mod kernels;
mod sort;

pub(crate) use backward::{PARAM_FLOATS, encode as encode_backward};

use super::{
    Gradients, ImageGradients, RenderBackend, RenderError, RenderStats, Rendered, ViewRequest,
    checked_pinhole, period_of,
};
use crate::gpu::compute::{read_buffer, storage_init, uniform};
use crate::gpu::{AdapterPolicy, Gpu, GpuError, Pooled};
use crate::math::project::PinholeCamera;
use crate::model::Gaussians;
use kernels::Kernels;
use sort::{Scan, SortBuffers, encode_sort};
use std::sync::Arc;

/// Tile side in pixels (as on the CPU).
const TILE: u32 = 16;
/// Bytes of one projected splat record (`Splat` in `shaders/view.wgsl`).
const SPLAT_BYTES: u64 = 64;

/// The GPU backend: an open device and the compiled kernels.
pub struct GpuBackend {
    pub(crate) gpu: Arc<Gpu>,
    kernels: Kernels,
}

/// The model as uploaded for one batch, shared by its frames.
pub(crate) struct ModelBuffers {
    /// Five vec4 per Gaussian (`params` in `shaders/preprocess.wgsl`).
    pub(crate) params: wgpu::Buffer,
    pub(crate) colours: wgpu::Buffer,
    /// Ones, bound where a view has no opacity factor.
    pub(crate) ones: wgpu::Buffer,
    pub(crate) count: usize,
    pub(crate) colour_len: usize,
}

/// What a GPU frame keeps on the device for its backward pass: the forward's projected
/// splats, tile counts and their scan, the sorted entries, tile ranges and per-pixel
/// final transmittance / last contributor, so the backward neither re-projects for the
/// sort nor sorts again.
pub(crate) struct GpuFrame {
    /// The device that holds these buffers.
    gpu: Arc<Gpu>,
    model: Arc<ModelBuffers>,
    uniform: ViewUniform,
    view: wgpu::Buffer,
    factor: Option<wgpu::Buffer>,
    pub(crate) buffers: ViewBuffers,
    /// (tile, splat) entries of this view.
    pairs: u32,
}

/// Per-view device buffers the forward fills and the backward reads.
pub(crate) struct ViewBuffers {
    /// The rendered image (interleaved RGB), for a loss on the device.
    pub(crate) rgb: Pooled,
    /// The rendered alpha and `Σ wᵢzᵢ` planes, for a pseudo view's comparison on the device.
    pub(crate) alpha: Pooled,
    pub(crate) depth: Pooled,
    /// One `Splat` per Gaussian.
    splats: Pooled,
    /// Tiles touched per Gaussian (0 when culled).
    counts: Pooled,
    /// Inclusive scan of `counts`: where each Gaussian's entries end in emit order.
    ends: Pooled,
    /// Gaussian index of each entry, sorted by (tile, depth).
    values: Pooled,
    /// Per tile: its run of sorted entries.
    ranges: Pooled,
    /// Per pixel: final transmittance bits and last contributing entry + 1.
    pixels: Pooled,
    /// Screen radius per Gaussian (0 when culled), for densification statistics.
    pub(crate) radii: Pooled,
}

/// The per-view constants (`View` in `shaders/view.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ViewUniform {
    pub(crate) rot: [[f32; 4]; 3],
    pub(crate) trans: [f32; 4],
    centre: [f32; 4],
    pub(crate) focal: [f32; 4],
    background: [f32; 4],
    pub(crate) width: u32,
    pub(crate) height: u32,
    tiles_x: u32,
    tiles_y: u32,
    count: u32,
    ns_active: u32,
    nt_active: u32,
    ns_capacity: u32,
    pub(crate) t: f32,
    period: f32,
    near: f32,
    colour_stride: u32,
}

/// One view, checked and ready to encode.
pub(crate) struct Prepared {
    pub(crate) uniform: ViewUniform,
    pub(crate) factor: Option<wgpu::Buffer>,
}

impl GpuBackend {
    /// Open a device allowed by `policy` and compile the kernels.
    pub fn new(policy: AdapterPolicy) -> Result<Self, GpuError> {
        Self::on_adapter(policy, 0)
    }

    /// As [`GpuBackend::new`], on the `n`th adapter the policy allows ([`Gpu::open_nth`]).
    pub fn on_adapter(policy: AdapterPolicy, n: usize) -> Result<Self, GpuError> {
        let gpu = Gpu::open_nth(policy, n)?;
        let kernels = Kernels::new(&gpu, true);
        Ok(Self { gpu, kernels })
    }

    /// As [`GpuBackend::new`], but with kernels that use no subgroup operations and so
    /// sum in the same order on every adapter (as `SPLAT4D_GPU_SUBGROUPS=0` gives).
    pub fn without_subgroups(policy: AdapterPolicy) -> Result<Self, GpuError> {
        let gpu = Gpu::open(policy)?;
        let kernels = Kernels::new(&gpu, false);
        Ok(Self { gpu, kernels })
    }

    /// Whether the kernels use subgroup operations ([`Gpu::subgroups`]).
    pub fn uses_subgroups(&self) -> bool {
        self.kernels.subgroups
    }

    /// The device this backend renders on (for [`Gpu::profile`]).
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// The adapter this backend renders on.
    pub fn adapter(&self) -> &wgpu::AdapterInfo {
        &self.gpu.info
    }

    /// Bytes of device memory the backend's allocations hold now (buffers still alive),
    /// from wgpu's allocator report; `None` where the backend gives no report (Metal, GL).
    pub fn allocated_bytes(&self) -> Option<u64> {
        self.gpu
            .device
            .generate_allocator_report()
            .map(|r| r.total_allocated_bytes)
    }

    /// Whether the adapter is a software one (lavapipe, SwiftShader): correct, but slower
    /// than the CPU engine.
    pub fn is_software(&self) -> bool {
        self.gpu.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Wait until the device has finished all submitted work (e.g. a training step's,
    /// `train::gpu::GpuAdam::step`, which returns once its work is submitted).
    pub fn wait(&self) -> Result<(), RenderError> {
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| RenderError::Gpu(format!("waiting for the GPU: {e}")))
    }

    /// The largest storage buffer one kernel may bind on this device.
    fn max_binding(&self) -> u64 {
        self.gpu.limits.max_storage_buffer_binding_size
    }

    pub(crate) fn too_large(&self, what: &str, bytes: u64) -> Result<(), RenderError> {
        let limit = self.max_binding();
        if bytes > limit {
            return Err(RenderError::Gpu(format!(
                "{what} needs {:.0} MiB in one buffer, above this GPU's limit of {:.0} MiB; render at a lower resolution or with fewer Gaussians, or use the CPU backend",
                bytes as f64 / 1048576.0,
                limit as f64 / 1048576.0
            )));
        }
        Ok(())
    }

    /// Run `f` inside a validation error scope; a wgpu validation error becomes a
    /// [`RenderError::Gpu`] instead of a panic.
    pub(crate) fn checked<T>(
        &self,
        f: impl FnOnce() -> Result<T, RenderError>,
    ) -> Result<T, RenderError> {
        let scope = self
            .gpu
            .device
            .push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(RenderError::Gpu(e.to_string())),
            None => out,
        }
    }

    /// Submit `encoder` and read `bytes` of `staging` back as `u32` words.
    pub(crate) fn read_back(
        &self,
        encoder: wgpu::CommandEncoder,
        staging: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<Vec<u32>, RenderError> {
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu
            .read_words(staging, bytes)
            .map_err(|e| RenderError::Gpu(e.to_string()))
    }

    pub(crate) fn prepare(
        &self,
        model: &Gaussians<f32>,
        view: &ViewRequest<'_>,
    ) -> Result<Prepared, RenderError> {
        let n = model.len();
        if let Some(f) = view.options.opacity_factor
            && f.len() != n
        {
            return Err(RenderError::OpacityFactorLength {
                expected: n,
                got: f.len(),
            });
        }
        let cam: PinholeCamera<f32> = checked_pinhole(view.camera, view.options.near_plane)?;
        let active = model.active.min(model.capacity);
        let r = cam.rotation;
        let bg = view.options.background;
        let uniform = ViewUniform {
            rot: [0, 1, 2].map(|i| [r[i][0], r[i][1], r[i][2], 0.0]),
            trans: [
                cam.translation[0],
                cam.translation[1],
                cam.translation[2],
                0.0,
            ],
            centre: [cam.centre[0], cam.centre[1], cam.centre[2], 0.0],
            focal: [cam.fx, cam.fy, cam.cx, cam.cy],
            background: [bg[0], bg[1], bg[2], 0.0],
            width: cam.width,
            height: cam.height,
            tiles_x: cam.width.div_ceil(TILE),
            tiles_y: cam.height.div_ceil(TILE),
            count: n as u32,
            ns_active: active.spatial_count() as u32,
            nt_active: active.temporal_count() as u32,
            ns_capacity: model.capacity.spatial_count() as u32,
            t: view.t,
            period: period_of(model),
            near: view.options.near_plane,
            colour_stride: 3 * model.coeffs_per_channel() as u32,
        };
        let factor = view
            .options
            .opacity_factor
            .map(|f| storage_init(&self.gpu.device, f, "opacity factor"));
        Ok(Prepared { uniform, factor })
    }
}

/// Per-Gaussian buffers shared by the views of a batch (each view overwrites them).
struct Scratch {
    ends: Pooled,
    radii: Pooled,
    scan: Option<Scan>,
}

impl RenderBackend for GpuBackend {
    fn describe(&self) -> String {
        format!("gpu: {}", self.gpu.describe())
    }

    fn as_gpu(&self) -> Option<&GpuBackend> {
        Some(self)
    }

    fn preferred_batch(&self) -> usize {
        8
    }

    fn render_batch(
        &self,
        model: &Gaussians<f32>,
        views: &[ViewRequest<'_>],
    ) -> Result<Vec<Rendered<f32>>, RenderError> {
        model
            .check_consistent()
            .map_err(RenderError::InconsistentModel)?;
        if views.is_empty() {
            return Ok(Vec::new());
        }
        let n = model.len();
        let prepared = views
            .iter()
            .map(|v| self.prepare(model, v))
            .collect::<Result<Vec<_>, _>>()?;
        self.too_large("the model's parameters", 80 * n as u64)?;
        self.too_large(
            "the model's colour coefficients",
            4 * model.colours.len() as u64,
        )?;
        self.too_large("the projected splats", SPLAT_BYTES * n as u64)?;
        for p in &prepared {
            let pixels = p.uniform.width as u64 * p.uniform.height as u64;
            self.too_large("the RGB image", 12 * pixels)?;
        }
        self.checked(|| self.render_checked(model, views, prepared))
    }

    fn backward(
        &self,
        model: &Gaussians<f32>,
        frame: &Rendered<f32>,
        up: &ImageGradients<f32>,
        out: &mut Gradients<f32>,
    ) -> Result<(), RenderError> {
        backward::backward(self, model, frame, up, out)
    }
}

impl GpuBackend {
    fn render_checked(
        &self,
        model: &Gaussians<f32>,
        views: &[ViewRequest<'_>],
        prepared: Vec<Prepared>,
    ) -> Result<Vec<Rendered<f32>>, RenderError> {
        let device = &self.gpu.device;
        let n = model.len();
        let params = pack_params(model);
        let uploaded = Arc::new(ModelBuffers {
            params: storage_init(device, &params, "gaussians"),
            colours: storage_init(device, &model.colours, "colours"),
            ones: storage_init(device, &vec![1.0f32; n.max(1)], "no opacity factor"),
            count: n,
            colour_len: model.colours.len(),
        });
        self.render_uploaded(uploaded, views, prepared, true)
    }

    /// Render `views` of a model already on the device. Without `read_images` the frames'
    /// images and radii stay on the device (their host vectors are empty): a training step
    /// reads only its loss.
    pub(crate) fn render_uploaded(
        &self,
        uploaded: Arc<ModelBuffers>,
        views: &[ViewRequest<'_>],
        prepared: Vec<Prepared>,
        read_images: bool,
    ) -> Result<Vec<Rendered<f32>>, RenderError> {
        let device = &self.gpu.device;
        let k = &self.kernels;
        let n = uploaded.count;
        let scratch = Scratch {
            ends: self.gpu.scratch(4 * n as u64, "tile ends"),
            radii: self.gpu.scratch(4 * n as u64, "radii"),
            scan: None,
        };
        let scratch = Scratch {
            scan: (n > 0).then(|| Scan::new(&self.gpu, k, &scratch.ends, n as u32)),
            ..scratch
        };
        let view_uniforms: Vec<wgpu::Buffer> = prepared
            .iter()
            .map(|p| uniform(device, &p.uniform))
            .collect();
        // Per view: its splats and tile counts (kept for the backward).
        let per_view: Vec<(Pooled, Pooled)> = prepared
            .iter()
            .map(|_| {
                (
                    self.gpu.scratch(SPLAT_BYTES * n as u64, "splats"),
                    self.gpu.scratch(4 * n as u64, "tile counts"),
                )
            })
            .collect();
        let preprocess_groups: Vec<wgpu::BindGroup> = prepared
            .iter()
            .zip(&view_uniforms)
            .zip(&per_view)
            .map(|((p, u), (splats, counts))| {
                let factor = p.factor.as_ref().unwrap_or(&uploaded.ones);
                k.preprocess.bind(
                    device,
                    &[
                        u,
                        &uploaded.params,
                        &uploaded.colours,
                        factor,
                        splats,
                        counts,
                        &scratch.radii,
                    ],
                )
            })
            .collect();

        // Pass 1: how many (tile, splat) pairs each view has.
        let totals = {
            let staging = read_buffer(device, 4 * views.len() as u64);
            let mut enc = device.create_command_encoder(&Default::default());
            for (v, group) in preprocess_groups.iter().enumerate() {
                self.encode_counts(&mut enc, group, &per_view[v].1, &scratch, n);
                if n > 0 {
                    enc.copy_buffer_to_buffer(
                        &scratch.ends,
                        4 * (n as u64 - 1),
                        &staging,
                        4 * v as u64,
                        4,
                    );
                }
            }
            let mut totals = self.read_back(enc, &staging, 4 * views.len() as u64)?;
            if n == 0 {
                totals.iter_mut().for_each(|t| *t = 0);
            }
            totals
        };
        let max_pairs = totals.iter().copied().max().unwrap_or(0) as u64;
        self.too_large("the (tile, splat) pairs", 4 * max_pairs)?;

        // Pass 2: render every view and copy its images into one read-back buffer.
        let keys = SortBuffers::new(&self.gpu, max_pairs);
        let layout: Vec<(u64, u64)> = prepared
            .iter()
            .map(|p| (p.uniform.width as u64 * p.uniform.height as u64, n as u64))
            .collect();
        let words_per_view: Vec<u64> = layout.iter().map(|(px, g)| 5 * px + g).collect();
        let total_words: u64 = if read_images {
            words_per_view.iter().sum()
        } else {
            0
        };
        let staging = read_buffer(device, 4 * total_words);
        let mut enc = device.create_command_encoder(&Default::default());
        let mut at = 0u64;
        let mut kept = Vec::with_capacity(views.len());
        for (v, ((p, group), (splats, counts))) in prepared
            .iter()
            .zip(&preprocess_groups)
            .zip(per_view)
            .enumerate()
        {
            let u = &p.uniform;
            let pairs = totals[v];
            let tiles = u.tiles_x * u.tiles_y;
            let (px, g) = layout[v];
            let scratch_of = |bytes, label| self.gpu.scratch(bytes, label);
            let buffers = ViewBuffers {
                rgb: scratch_of(12 * px, "rgb"),
                alpha: scratch_of(4 * px, "alpha"),
                depth: scratch_of(4 * px, "depth"),
                splats,
                counts,
                ends: scratch_of(4 * n as u64, "tile ends of a view"),
                values: scratch_of(4 * pairs as u64, "sorted entries"),
                ranges: scratch_of(8 * tiles as u64, "tile ranges"),
                pixels: scratch_of(8 * px, "pixel state"),
                radii: scratch_of(4 * n as u64, "radii of a view"),
            };
            // Tiles no entry reaches keep an empty range.
            enc.clear_buffer(&buffers.ranges, 0, None);
            self.encode_counts(&mut enc, group, &buffers.counts, &scratch, n);
            if n > 0 {
                enc.copy_buffer_to_buffer(&scratch.ends, 0, &buffers.ends, 0, 4 * n as u64);
            }
            let tile_bits = 32 - tiles.saturating_sub(1).leading_zeros();
            let in_b = {
                let mut pass = enc.begin_compute_pass(&Default::default());
                let emit = k.emit.bind(
                    device,
                    &[
                        &view_uniforms[v],
                        &buffers.splats,
                        &buffers.counts,
                        &scratch.ends,
                        &keys.a[0],
                        &keys.a[1],
                        &keys.a[2],
                    ],
                );
                k.emit.dispatch_items(&mut pass, &emit, n as u32);
                let in_b = encode_sort(&self.gpu, k, &mut pass, &keys, pairs, tile_bits);
                let sorted = if in_b { &keys.b } else { &keys.a };
                let len = uniform(device, &[pairs, 0, 0, 0]);
                let rg = k.ranges.bind(device, &[&len, &sorted[0], &buffers.ranges]);
                k.ranges.dispatch_items(&mut pass, &rg, pairs);
                let raster = k.rasterise.bind(
                    device,
                    &[
                        &view_uniforms[v],
                        &buffers.splats,
                        &sorted[2],
                        &buffers.ranges,
                        &buffers.rgb,
                        &buffers.alpha,
                        &buffers.depth,
                        &buffers.pixels,
                    ],
                );
                k.rasterise
                    .dispatch_grid(&mut pass, &raster, [u.tiles_x, u.tiles_y, 1]);
                in_b
            };
            if pairs > 0 {
                let sorted = if in_b { &keys.b } else { &keys.a };
                enc.copy_buffer_to_buffer(&sorted[2], 0, &buffers.values, 0, 4 * pairs as u64);
            }
            if n > 0 {
                enc.copy_buffer_to_buffer(&scratch.radii, 0, &buffers.radii, 0, 4 * n as u64);
            }
            if read_images {
                for (buf, words) in [
                    (&buffers.rgb, 3 * px),
                    (&buffers.alpha, px),
                    (&buffers.depth, px),
                    (&buffers.radii, g),
                ] {
                    if words > 0 {
                        enc.copy_buffer_to_buffer(buf, 0, &staging, 4 * at, 4 * words);
                    }
                    at += words;
                }
            }
            kept.push(buffers);
        }
        let words = self.read_back(enc, &staging, 4 * total_words)?;
        let floats: &[f32] = bytemuck::cast_slice(&words);

        let mut frames = Vec::with_capacity(views.len());
        let mut at = 0usize;
        for (v, ((view, p), (buffers, view_buffer))) in views
            .iter()
            .zip(prepared)
            .zip(kept.into_iter().zip(view_uniforms))
            .enumerate()
        {
            let (px, g) = if read_images {
                (layout[v].0 as usize, layout[v].1 as usize)
            } else {
                (0, 0)
            };
            let mut take = |len: usize| {
                let s = floats[at..at + len].to_vec();
                at += len;
                s
            };
            let rgb = take(3 * px);
            let alpha = take(px);
            let depth = take(px);
            let radii = take(g);
            let visible = radii.iter().filter(|r| **r > 0.0).count();
            frames.push(Rendered {
                width: p.uniform.width,
                height: p.uniform.height,
                rgb,
                alpha,
                depth,
                radii,
                time: view.t,
                stats: RenderStats {
                    visible,
                    tile_pairs: totals[v] as usize,
                    blend_evaluations: 0,
                },
                state: Arc::new(GpuFrame {
                    gpu: self.gpu.clone(),
                    model: uploaded.clone(),
                    uniform: p.uniform,
                    view: view_buffer,
                    factor: p.factor,
                    buffers,
                    pairs: totals[v],
                }),
            });
        }
        Ok(frames)
    }

    /// Record `preprocess` (tile counts into `counts`) and the scan of the counts for one
    /// view.
    fn encode_counts(
        &self,
        enc: &mut wgpu::CommandEncoder,
        group: &wgpu::BindGroup,
        counts: &wgpu::Buffer,
        scratch: &Scratch,
        n: usize,
    ) {
        if n == 0 {
            return;
        }
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            self.kernels
                .preprocess
                .dispatch_items(&mut pass, group, n as u32);
        }
        enc.copy_buffer_to_buffer(counts, 0, &scratch.ends, 0, 4 * n as u64);
        let mut pass = enc.begin_compute_pass(&Default::default());
        if let Some(scan) = &scratch.scan {
            scan.encode(&self.kernels, &mut pass);
        }
    }
}

/// The model's non-colour parameters as uploaded: five vec4 per Gaussian (mean,
/// log-scales, left and right rotation, opacity logit and padding).
pub(crate) fn pack_params(model: &Gaussians<f32>) -> Vec<[f32; 4]> {
    let n = model.len();
    let mut params: Vec<[f32; 4]> = Vec::with_capacity(5 * n);
    for i in 0..n {
        params.extend_from_slice(&[
            model.means[i],
            model.log_scales[i],
            model.rot_left[i],
            model.rot_right[i],
            [model.opacity_logits[i], 0.0, 0.0, 0.0],
        ]);
    }
    params
}
