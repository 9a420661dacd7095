//! The layers of LPIPS's AlexNet on channels-last (`H×W×C`, row-major) `f32` feature maps:
//! a 2D convolution with bias and ReLU ([`Conv2d`]) and the 3×3 stride-2 max-pool.
//!
//! Stride-1 layers with 3×3 and 5×5 kernels run by Winograd's minimal filtering
//! (`winograd`); the others (AlexNet's 11×11 stride-4 first layer) by im2col + GEMM:
//! the output positions are cut into tiles; for each
//! tile the receptive fields are copied into rows of `kh·kw·C_in` values (in the kernel's
//! HWIO order, zeros where the padding is) and multiplied by the kernel seen as a
//! `(kh·kw·C_in) × C_out` matrix (`matrixmultiply::sgemm`). Tiles run in parallel on
//! rayon, so one image uses every core and a batch of images shares them. A plain `f64`
//! convolution beside it in the tests is the reference.

use rayon::prelude::*;

use super::maps::matmul;
pub use super::maps::{FeatureMap, output_side};
use super::winograd::WinogradConv;

/// A square-kernel convolution with symmetric zero padding, bias and ReLU.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv2d {
    /// Kernel side (height = width).
    size: usize,
    stride: usize,
    padding: usize,
    in_channels: usize,
    out_channels: usize,
    /// HWIO: `kernel[((ky·size + kx)·in + i)·out + o]`, i.e. a `(size²·in) × out` matrix.
    kernel: Vec<f32>,
    bias: Vec<f32>,
    /// The kernel in the Winograd domain, for the layers that run that way.
    winograd: Option<WinogradConv>,
}

/// Kernel sides that run by Winograd when the stride is 1.
const WINOGRAD_SIDES: [usize; 2] = [3, 5];

/// Output positions per GEMM tile: a tile's im2col rows (≤ 256 × 1728 values for AlexNet)
/// stay within a core's cache, and a 640×360 image still has tiles for every core.
const TILE: usize = 256;

impl Conv2d {
    /// A layer from its kernel (HWIO, `size × size × in × out`) and bias (`out`). Panics
    /// when their lengths do not match the shape.
    pub fn new(
        size: usize,
        stride: usize,
        padding: usize,
        (in_channels, out_channels): (usize, usize),
        kernel: Vec<f32>,
        bias: Vec<f32>,
    ) -> Self {
        assert_eq!(
            kernel.len(),
            size * size * in_channels * out_channels,
            "kernel size"
        );
        assert_eq!(bias.len(), out_channels, "bias size");
        let winograd = (stride == 1 && WINOGRAD_SIDES.contains(&size))
            .then(|| WinogradConv::new(&kernel, size, padding, in_channels, out_channels));
        Self {
            size,
            stride,
            padding,
            in_channels,
            out_channels,
            kernel,
            bias,
            winograd,
        }
    }

    /// The convolution of `input` followed by ReLU. `None` when the (padded) input is
    /// smaller than the kernel. Panics if `input.channels` is not the layer's.
    #[cfg(test)]
    pub fn forward_relu(&self, input: &FeatureMap) -> Option<FeatureMap> {
        self.forward_relu_batch(std::slice::from_ref(input))?.pop()
    }

    /// [`Self::forward_relu`] of each of `inputs`, which must all be of one size.
    pub fn forward_relu_batch(&self, inputs: &[FeatureMap]) -> Option<Vec<FeatureMap>> {
        match &self.winograd {
            Some(winograd) => winograd.forward_relu_batch(inputs, &self.bias),
            None => inputs.par_iter().map(|x| self.im2col_relu(x)).collect(),
        }
    }

    /// The kernel, HWIO (`size × size × in × out`): a `(size²·in) × out` matrix.
    pub fn kernel(&self) -> &[f32] {
        &self.kernel
    }

    /// One bias per output channel.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }

    /// Rows of the kernel matrix: values in one receptive field.
    fn field(&self) -> usize {
        self.size * self.size * self.in_channels
    }

    /// [`Self::forward_relu`] by im2col + GEMM, whatever the layer.
    fn im2col_relu(&self, input: &FeatureMap) -> Option<FeatureMap> {
        assert_eq!(input.channels, self.in_channels, "channels of a conv input");
        let out_h = output_side(input.height, self.size, self.stride, self.padding)?;
        let out_w = output_side(input.width, self.size, self.stride, self.padding)?;
        let (k, n) = (self.field(), self.out_channels);
        let mut out = vec![0.0f32; out_h * out_w * n];
        out.par_chunks_mut(TILE * n).enumerate().for_each_init(
            Vec::new,
            |cols: &mut Vec<f32>, (tile, c)| {
                let first = tile * TILE;
                let rows = c.len() / n;
                cols.clear();
                cols.resize(rows * k, 0.0);
                for (r, row) in cols.chunks_exact_mut(k).enumerate() {
                    let p = first + r;
                    self.gather(input, p / out_w, p % out_w, row);
                }
                matmul(cols, &self.kernel, c, rows, k, n);
                for px in c.chunks_exact_mut(n) {
                    for (v, b) in px.iter_mut().zip(&self.bias) {
                        *v = (*v + b).max(0.0);
                    }
                }
            },
        );
        Some(FeatureMap {
            height: out_h,
            width: out_w,
            channels: n,
            data: out,
        })
    }

    /// The receptive field of output pixel `(oy, ox)` in HWIO order into `row`
    /// (`size²·in` values, zeros outside the input).
    fn gather(&self, input: &FeatureMap, oy: usize, ox: usize, row: &mut [f32]) {
        let c = self.in_channels;
        let span = self.size * c;
        for ky in 0..self.size {
            let dst = &mut row[ky * span..(ky + 1) * span];
            let Some(iy) = (oy * self.stride + ky)
                .checked_sub(self.padding)
                .filter(|&y| y < input.height)
            else {
                dst.fill(0.0);
                continue;
            };
            // Columns of this kernel row that fall inside the image: one contiguous copy.
            let x0 = (ox * self.stride) as isize - self.padding as isize;
            let kx_start = (-x0).max(0) as usize;
            let kx_end = ((input.width as isize - x0).max(0) as usize).min(self.size);
            if kx_start >= kx_end {
                dst.fill(0.0);
                continue;
            }
            dst[..kx_start * c].fill(0.0);
            dst[kx_end * c..].fill(0.0);
            let src = (iy * input.width + (x0 + kx_start as isize) as usize) * c;
            dst[kx_start * c..kx_end * c]
                .copy_from_slice(&input.data[src..src + (kx_end - kx_start) * c]);
        }
    }
}

/// 3×3 max-pool with stride 2 and no padding (PyTorch's `MaxPool2d(3, 2)`, flax's
/// `max_pool(x, (3, 3), (2, 2))`). `None` when the input is smaller than 3×3.
pub fn max_pool_3x3_s2(input: &FeatureMap) -> Option<FeatureMap> {
    let out_h = output_side(input.height, 3, 2, 0)?;
    let out_w = output_side(input.width, 3, 2, 0)?;
    let c = input.channels;
    let mut out = vec![f32::NEG_INFINITY; out_h * out_w * c];
    out.par_chunks_mut(out_w * c)
        .enumerate()
        .for_each(|(oy, row)| {
            for (ox, px) in row.chunks_exact_mut(c).enumerate() {
                for y in 2 * oy..2 * oy + 3 {
                    for x in 2 * ox..2 * ox + 3 {
                        for (o, v) in px.iter_mut().zip(input.pixel(y * input.width + x)) {
                            *o = o.max(*v);
                        }
                    }
                }
            }
        });
    Some(FeatureMap {
        height: out_h,
        width: out_w,
        channels: c,
        data: out,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_chacha::ChaCha8Rng;
    use rand_core::{Rng, SeedableRng};

    fn random(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
        (0..n)
            .map(|_| (rng.next_u32() as f64 / u32::MAX as f64 * 2.0 - 1.0) as f32)
            .collect()
    }

    /// The convolution straight from its definition, in `f64`.
    fn conv_reference(conv: &Conv2d, input: &FeatureMap) -> Vec<f64> {
        let oh = output_side(input.height, conv.size, conv.stride, conv.padding).unwrap();
        let ow = output_side(input.width, conv.size, conv.stride, conv.padding).unwrap();
        let (ci, co) = (conv.in_channels, conv.out_channels);
        let mut out = vec![0.0f64; oh * ow * co];
        for oy in 0..oh {
            for ox in 0..ow {
                for o in 0..co {
                    let mut sum = conv.bias[o] as f64;
                    for ky in 0..conv.size {
                        for kx in 0..conv.size {
                            let y = (oy * conv.stride + ky) as isize - conv.padding as isize;
                            let x = (ox * conv.stride + kx) as isize - conv.padding as isize;
                            if y < 0
                                || x < 0
                                || y >= input.height as isize
                                || x >= input.width as isize
                            {
                                continue;
                            }
                            for i in 0..ci {
                                let v = input.data[(y as usize * input.width + x as usize) * ci + i]
                                    as f64;
                                let w = conv.kernel[((ky * conv.size + kx) * ci + i) * co + o];
                                sum += v * w as f64;
                            }
                        }
                    }
                    out[(oy * ow + ox) * co + o] = sum.max(0.0);
                }
            }
        }
        out
    }

    /// Both ways of computing `conv` agree with the `f64` definition: within `tolerance`
    /// of the sum of the absolute terms (what rounding scales with).
    fn check_against_reference(conv: &Conv2d, input: &FeatureMap, tolerance: f64) {
        let reference = conv_reference(conv, input);
        let scale = reference_scale(conv, input);
        for (way, out) in [
            ("forward", conv.forward_relu(input).unwrap()),
            ("im2col", conv.im2col_relu(input).unwrap()),
        ] {
            assert_eq!(out.data.len(), reference.len());
            let worst = out
                .data
                .iter()
                .zip(&reference)
                .map(|(f, r)| (*f as f64 - r).abs() / scale)
                .fold(0.0, f64::max);
            assert!(
                worst < tolerance,
                "{way} {0}x{0} s{1} p{2}, {3}→{4} channels on {5}×{6}: error {worst:e} of the terms",
                conv.size,
                conv.stride,
                conv.padding,
                conv.in_channels,
                conv.out_channels,
                input.height,
                input.width,
            );
        }
    }

    /// The largest sum of absolute terms over the outputs: the bias plus every kernel
    /// weight times the input value it meets (a bound on any partial sum).
    fn reference_scale(conv: &Conv2d, input: &FeatureMap) -> f64 {
        let weights: f64 =
            conv.kernel.iter().map(|w| w.abs() as f64).sum::<f64>() / conv.out_channels as f64;
        let biggest = input.data.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        1.0 + weights * biggest
    }

    fn random_layer(
        rng: &mut ChaCha8Rng,
        (size, stride, padding): (usize, usize, usize),
        (ci, co): (usize, usize),
        (h, w): (usize, usize),
    ) -> (Conv2d, FeatureMap) {
        let conv = Conv2d::new(
            size,
            stride,
            padding,
            (ci, co),
            random(rng, size * size * ci * co),
            random(rng, co),
        );
        let input = FeatureMap {
            height: h,
            width: w,
            channels: ci,
            data: random(rng, h * w * ci),
        };
        (conv, input)
    }

    #[test]
    fn convolution_matches_the_f64_definition() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        // Stride 4 with padding (AlexNet's first layer, smaller); stride 1 with 5×5 and
        // 3×3 kernels (Winograd) on sides that are and are not multiples of the tile,
        // images with several bands of tiles, a 1×1 output, many input channels.
        for (layer, channels, side) in [
            ((11, 4, 2), (3, 8), (37, 41)),
            ((5, 1, 2), (6, 10), (9, 13)),
            ((5, 1, 2), (64, 24), (23, 30)),
            ((3, 1, 1), (4, 5), (20, 30)),
            ((3, 1, 1), (4, 3), (61, 7)),
            ((3, 1, 0), (2, 3), (3, 3)),
            ((3, 1, 1), (384, 16), (9, 11)),
        ] {
            let (conv, input) = random_layer(&mut rng, layer, channels, side);
            check_against_reference(&conv, &input, 2e-6);
        }
    }

    #[test]
    fn a_batch_gives_what_each_input_gives_alone() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for (layer, channels, side) in [
            ((11, 4, 2), (3, 4), (40, 37)),
            ((5, 1, 2), (8, 6), (19, 26)),
            ((3, 1, 1), (5, 7), (9, 70)),
        ] {
            let (conv, first) = random_layer(&mut rng, layer, channels, side);
            let inputs: Vec<FeatureMap> = std::iter::once(first)
                .chain((0..4).map(|_| random_layer(&mut rng, layer, channels, side).1))
                .collect();
            let batch = conv.forward_relu_batch(&inputs).unwrap();
            assert_eq!(batch.len(), inputs.len());
            for (input, out) in inputs.iter().zip(&batch) {
                assert_eq!(out, &conv.forward_relu(input).unwrap());
            }
        }
    }

    #[test]
    fn a_kernel_larger_than_the_padded_input_gives_nothing() {
        let conv = Conv2d::new(11, 4, 2, (1, 1), vec![0.0; 121], vec![0.0]);
        let tiny = FeatureMap {
            height: 6,
            width: 20,
            channels: 1,
            data: vec![0.0; 120],
        };
        assert!(conv.forward_relu(&tiny).is_none());
        let winograd = Conv2d::new(5, 1, 0, (1, 1), vec![0.0; 25], vec![0.0]);
        let thin = FeatureMap {
            height: 4,
            width: 20,
            channels: 1,
            data: vec![0.0; 80],
        };
        assert!(winograd.forward_relu(&thin).is_none());
    }

    #[test]
    fn max_pool_takes_each_window_maximum() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (h, w, c) = (9, 12, 2);
        let input = FeatureMap {
            height: h,
            width: w,
            channels: c,
            data: random(&mut rng, h * w * c),
        };
        let out = max_pool_3x3_s2(&input).unwrap();
        assert_eq!((out.height, out.width, out.channels), (4, 5, 2));
        for oy in 0..4 {
            for ox in 0..5 {
                for ch in 0..c {
                    let mut m = f32::NEG_INFINITY;
                    for y in 2 * oy..2 * oy + 3 {
                        for x in 2 * ox..2 * ox + 3 {
                            m = m.max(input.data[(y * w + x) * c + ch]);
                        }
                    }
                    assert_eq!(out.data[(oy * 5 + ox) * c + ch], m);
                }
            }
        }
        let small = FeatureMap {
            height: 2,
            width: 5,
            channels: 1,
            data: vec![0.0; 10],
        };
        assert!(max_pool_3x3_s2(&small).is_none());
    }
}
