//! LPIPS-alex on a GPU: the CPU network of `alex` as WGSL kernels (`shaders/lpips_*.wgsl`),
//! for evaluation with the GPU renderer. Each kernel has the CPU function it must match:
//! - `conv_relu` (`lpips_conv.wgsl`): [`Conv2d`](super::conv::Conv2d)'s convolution with
//!   bias and ReLU, as an implicit GEMM of 64 × 64 output tiles with the receptive fields
//!   and kernel weights staged in workgroup memory;
//! - `scale_input`, `max_pool` (`lpips_maps.wgsl`): the input shift and scale of `alex`,
//!   and `max_pool_3x3_s2`;
//! - `tap_pixels`, `tap_mean` (`lpips_tap.wgsl`): `alex`'s `tap_distance`, each pair's
//!   mean added to its distance on the device.
//!
//! A batch of same-sized pairs (as [`AlexLpips::distances`] groups them) is one submission:
//! the images go up, every layer and tap of every image runs on the device, and only the
//! pairs' distances (4 bytes a pair) come back. The weights go up once per device and stay
//! there (cached with the device, keyed by the load they come from); the pipelines are
//! built once per device (`Gpu::pipelines`).
//!
//! This module computes LPIPS and nothing else; it uses the GPU kernel toolkit
//! (`crate::gpu`), and knows nothing of rendering.

use std::sync::{Arc, Mutex, PoisonError};

use super::alex::{AlexLpips, BATCH_PIXELS, LAYERS, MIN_SIDE, by_size};
use super::conv::output_side;
use super::{ImagePair, LpipsError};
use crate::gpu::Gpu;
use crate::gpu::compute::{Kernel, Slot, read_buffer, shader, storage, uniform};
use Slot::{Read, ReadWrite, Uniform};

/// Output pixels and channels of one `conv_relu` workgroup (`BM`, `BN` in the shader).
const CONV_TILE: u32 = 64;
/// Workgroups per dispatch dimension (WebGPU's guaranteed minimum of the limit).
const MAX_GROUPS: u32 = 65_535;
/// Weight sets kept per device (the newest): an evaluation uses one.
const KEPT_WEIGHTS: usize = 4;

/// `Conv` in `shaders/lpips_conv.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ConvUniform {
    in_width: u32,
    in_height: u32,
    in_channels: u32,
    out_channels: u32,
    out_width: u32,
    out_height: u32,
    size: u32,
    stride: u32,
    padding: u32,
    rows: u32,
    field: u32,
    tiles_m: u32,
}

/// `Maps` in `shaders/lpips_maps.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MapsUniform {
    count: u32,
    in_width: u32,
    in_height: u32,
    channels: u32,
    out_width: u32,
    out_height: u32,
    pad: [u32; 2],
}

/// `Tap` in `shaders/lpips_tap.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TapUniform {
    pixels: u32,
    channels: u32,
    pairs: u32,
    pad: u32,
}

/// The pipelines of LPIPS-alex on one device.
struct LpipsKernels {
    conv_relu: Kernel,
    scale_input: Kernel,
    max_pool: Kernel,
    tap_pixels: Kernel,
    tap_mean: Kernel,
}

impl LpipsKernels {
    fn new(device: &wgpu::Device) -> Self {
        let conv = shader(
            device,
            "lpips_conv",
            &[BATCH],
            include_str!("shaders/lpips_conv.wgsl"),
        );
        let maps = shader(
            device,
            "lpips_maps",
            &[BATCH],
            include_str!("shaders/lpips_maps.wgsl"),
        );
        let tap = shader(
            device,
            "lpips_tap",
            &[],
            include_str!("shaders/lpips_tap.wgsl"),
        );
        let maps_slots = [Uniform, Read, ReadWrite];
        let tap_slots = [Uniform, Read, Read, ReadWrite, ReadWrite];
        Self {
            conv_relu: Kernel::alone(
                device,
                &conv,
                "conv_relu",
                &[Uniform, Read, Read, Read, ReadWrite],
            ),
            scale_input: Kernel::alone(device, &maps, "scale_input", &maps_slots),
            max_pool: Kernel::alone(device, &maps, "max_pool", &maps_slots),
            tap_pixels: Kernel::alone(device, &tap, "tap_pixels", &tap_slots),
            tap_mean: Kernel::alone(device, &tap, "tap_mean", &tap_slots),
        }
    }
}

/// One layer's weights on the device.
struct LayerBuffers {
    kernel: wgpu::Buffer,
    bias: wgpu::Buffer,
    linear: wgpu::Buffer,
}

/// The weight sets uploaded to one device, newest last, by [`AlexLpips::load_id`].
#[derive(Default)]
struct UploadedWeights(Mutex<Vec<(u64, Arc<Vec<LayerBuffers>>)>>);

/// `shaders/lpips_batch.wgsl`: the pixel of a batch's flat index, for the conv and map kernels.
const BATCH: &str = include_str!("shaders/lpips_batch.wgsl");

/// A storage buffer holding `data` (which is never empty here).
fn upload(gpu: &Gpu, data: &[f32], label: &str) -> wgpu::Buffer {
    let buffer = storage(&gpu.device, 4 * data.len() as u64, label);
    gpu.queue
        .write_buffer(&buffer, 0, bytemuck::cast_slice(data));
    buffer
}

impl AlexLpips {
    /// This network's weights on `gpu`: uploaded on the first call, shared afterwards.
    fn weights_on(&self, gpu: &Gpu) -> Arc<Vec<LayerBuffers>> {
        let uploaded = gpu.pipelines(|_| UploadedWeights::default());
        let mut sets = uploaded.0.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((_, set)) = sets.iter().find(|(id, _)| *id == self.load_id) {
            return set.clone();
        }
        let set: Arc<Vec<LayerBuffers>> = Arc::new(
            self.convs
                .iter()
                .zip(&self.linear)
                .map(|(conv, linear)| LayerBuffers {
                    kernel: upload(gpu, conv.kernel(), "lpips kernel"),
                    bias: upload(gpu, conv.bias(), "lpips bias"),
                    linear: upload(gpu, linear, "lpips linear"),
                })
                .collect(),
        );
        if sets.len() >= KEPT_WEIGHTS {
            sets.remove(0);
        }
        sets.push((self.load_id, set.clone()));
        set
    }

    /// [`Self::distances`] on `gpu`: pairs of one size go through the kernels together,
    /// in batches of up to [`BATCH_PIXELS`] (fewer where one of the batch's buffers would
    /// pass the device's storage-buffer limit; a pair whose maps alone would pass it is
    /// computed on the CPU). A device failure is an error for each pair of its batch.
    pub fn distances_on_gpu(&self, gpu: &Gpu, pairs: &[ImagePair]) -> Vec<Result<f64, LpipsError>> {
        let kernels = gpu.pipelines(LpipsKernels::new);
        let weights = self.weights_on(gpu);
        let limit = gpu
            .limits
            .max_storage_buffer_binding_size
            .min(gpu.limits.max_buffer_size);
        by_size(
            pairs,
            |width, height| {
                let by_pixels = BATCH_PIXELS / (2 * width * height);
                let by_limit = Shapes::new(width, height).map_or(1, |s| {
                    (limit / (2 * s.largest_image_bytes()).max(1)) as usize
                });
                by_pixels.min(by_limit)
            },
            |images, width, height| match self
                .same_size_on_gpu(gpu, &kernels, &weights, images, width, height)
            {
                Ok(distances) => distances.into_iter().map(Ok).collect(),
                Err(Failure::TooLarge) => {
                    let on_cpu: Vec<ImagePair> = images
                        .iter()
                        .map(|&[a, b]| ImagePair {
                            a,
                            b,
                            width,
                            height,
                        })
                        .collect();
                    self.distances(&on_cpu)
                }
                Err(Failure::TooSmall) => images
                    .iter()
                    .map(|_| {
                        Err(LpipsError::TooSmall {
                            width,
                            height,
                            min: MIN_SIDE,
                        })
                    })
                    .collect(),
                Err(Failure::Device(message)) => images
                    .iter()
                    .map(|_| {
                        Err(LpipsError::Gpu {
                            adapter: gpu.describe(),
                            message: message.clone(),
                        })
                    })
                    .collect(),
            },
        )
    }

    /// LPIPS of pairs of `width × height` images in one submission with one read-back.
    fn same_size_on_gpu(
        &self,
        gpu: &Gpu,
        kernels: &LpipsKernels,
        weights: &[LayerBuffers],
        pairs: &[[&[f32]; 2]],
        width: usize,
        height: usize,
    ) -> Result<Vec<f64>, Failure> {
        let shapes = Shapes::new(width, height).ok_or(Failure::TooSmall)?;
        let images = 2 * pairs.len();
        let limit = gpu
            .limits
            .max_storage_buffer_binding_size
            .min(gpu.limits.max_buffer_size);
        let largest = images as u64 * shapes.largest_image_bytes();
        if largest > limit {
            return Err(Failure::TooLarge);
        }
        let device = &gpu.device;
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);

        let rgb_values = 3 * width * height;
        let rgb = storage(device, (4 * images * rgb_values) as u64, "lpips images");
        for (k, image) in pairs.iter().flatten().enumerate() {
            gpu.queue.write_buffer(
                &rgb,
                (4 * k * rgb_values) as u64,
                bytemuck::cast_slice(image),
            );
        }
        let tap_pixels = shapes.taps.iter().map(|t| t.0 * t.1).max().unwrap_or(0);
        let terms = storage(device, (4 * pairs.len() * tap_pixels) as u64, "lpips terms");
        let totals = storage(device, 4 * pairs.len() as u64, "lpips distances");
        let staging = read_buffer(device, 4 * pairs.len() as u64);

        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            let count = (images * rgb_values) as u32;
            let mut x = storage(device, 4 * count as u64, "lpips input");
            let params = uniform(
                device,
                &MapsUniform {
                    count,
                    in_width: width as u32,
                    in_height: height as u32,
                    channels: 3,
                    out_width: width as u32,
                    out_height: height as u32,
                    pad: [0; 2],
                },
            );
            let group = kernels.scale_input.bind(device, &[&params, &rgb, &x]);
            kernels.scale_input.dispatch_items(&mut pass, &group, count);

            let (mut in_w, mut in_h) = (width, height);
            for (i, (&(size, stride, padding, cin, cout), layer)) in
                LAYERS.iter().zip(weights).enumerate()
            {
                let (out_w, out_h) = shapes.taps[i];
                let rows = (images * out_w * out_h) as u32;
                let tiles_m = rows.div_ceil(CONV_TILE);
                let params = uniform(
                    device,
                    &ConvUniform {
                        in_width: in_w as u32,
                        in_height: in_h as u32,
                        in_channels: cin as u32,
                        out_channels: cout as u32,
                        out_width: out_w as u32,
                        out_height: out_h as u32,
                        size: size as u32,
                        stride: stride as u32,
                        padding: padding as u32,
                        rows,
                        field: (size * size * cin) as u32,
                        tiles_m,
                    },
                );
                let tap = storage(device, 4 * rows as u64 * cout as u64, "lpips tap");
                let group = kernels
                    .conv_relu
                    .bind(device, &[&params, &x, &layer.kernel, &layer.bias, &tap]);
                let across = tiles_m.clamp(1, MAX_GROUPS);
                kernels.conv_relu.dispatch_grid(
                    &mut pass,
                    &group,
                    [
                        across,
                        (cout as u32).div_ceil(CONV_TILE),
                        tiles_m.div_ceil(across),
                    ],
                );

                let pixels = out_w * out_h;
                let params = uniform(
                    device,
                    &TapUniform {
                        pixels: pixels as u32,
                        channels: cout as u32,
                        pairs: pairs.len() as u32,
                        pad: 0,
                    },
                );
                let group = kernels
                    .tap_pixels
                    .bind(device, &[&params, &tap, &layer.linear, &terms, &totals]);
                kernels
                    .tap_pixels
                    .dispatch_items(&mut pass, &group, (pairs.len() * pixels) as u32);
                kernels
                    .tap_mean
                    .dispatch_groups(&mut pass, &group, pairs.len() as u32);

                (x, in_w, in_h) = match shapes.pools.get(i) {
                    Some(&(pool_w, pool_h)) => {
                        let count = (images * pool_w * pool_h * cout) as u32;
                        let pooled = storage(device, 4 * count as u64, "lpips pooled");
                        let params = uniform(
                            device,
                            &MapsUniform {
                                count,
                                in_width: out_w as u32,
                                in_height: out_h as u32,
                                channels: cout as u32,
                                out_width: pool_w as u32,
                                out_height: pool_h as u32,
                                pad: [0; 2],
                            },
                        );
                        let group = kernels.max_pool.bind(device, &[&params, &tap, &pooled]);
                        kernels.max_pool.dispatch_items(&mut pass, &group, count);
                        (pooled, pool_w, pool_h)
                    }
                    None => (tap, out_w, out_h),
                };
            }
        }
        encoder.copy_buffer_to_buffer(&totals, 0, &staging, 0, 4 * pairs.len() as u64);
        gpu.queue.submit([encoder.finish()]);
        let words = gpu
            .read_words(&staging, 4 * pairs.len() as u64)
            .map_err(|e| Failure::Device(e.to_string()));
        if let Some(e) = pollster::block_on(memory.pop()) {
            return Err(Failure::Device(e.to_string()));
        }
        if let Some(e) = pollster::block_on(validation.pop()) {
            return Err(Failure::Device(e.to_string()));
        }
        Ok(words?
            .into_iter()
            .map(|w| f32::from_bits(w) as f64)
            .collect())
    }
}

/// Why a batch has no distances.
enum Failure {
    /// The images are too small for the network (the callers check this first).
    TooSmall,
    /// One pair's maps do not fit in the device's largest storage buffer.
    TooLarge,
    /// The device failed; what it said.
    Device(String),
}

/// The map sizes (width, height) of one image through the network.
struct Shapes {
    /// Values of the RGB input.
    input: usize,
    /// The output of each convolution (and its tap).
    taps: [(usize, usize); 5],
    /// The output of the max-pools after the first two convolutions.
    pools: [(usize, usize); 2],
}

impl Shapes {
    /// `None` when the image is too small for the network.
    fn new(width: usize, height: usize) -> Option<Self> {
        let (mut w, mut h) = (width, height);
        let mut taps = [(0, 0); 5];
        let mut pools = [(0, 0); 2];
        for (i, &(size, stride, padding, _, _)) in LAYERS.iter().enumerate() {
            w = output_side(w, size, stride, padding)?;
            h = output_side(h, size, stride, padding)?;
            taps[i] = (w, h);
            if let Some(pool) = pools.get_mut(i) {
                w = output_side(w, 3, 2, 0)?;
                h = output_side(h, 3, 2, 0)?;
                *pool = (w, h);
            }
        }
        Some(Self {
            input: 3 * width * height,
            taps,
            pools,
        })
    }

    /// Bytes of the largest map of one image (the input, a tap or a pooled map).
    fn largest_image_bytes(&self) -> u64 {
        let taps = self
            .taps
            .iter()
            .zip(LAYERS)
            .map(|(&(w, h), layer)| w * h * layer.4);
        let pools = self
            .pools
            .iter()
            .zip(LAYERS)
            .map(|(&(w, h), layer)| w * h * layer.4);
        4 * taps.chain(pools).fold(self.input, usize::max) as u64
    }
}
