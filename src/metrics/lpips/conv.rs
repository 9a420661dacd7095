//! The layers of LPIPS's AlexNet on channels-last (`H×W×C`, row-major) `f32` feature maps:
//! a 2D convolution with bias and ReLU ([`Conv2d`]) and the 3×3 stride-2 max-pool.
//!
//! The convolution is im2col + GEMM: the output positions are cut into tiles; for each
//! tile the receptive fields are copied into rows of `kh·kw·C_in` values (in the kernel's
//! HWIO order, zeros where the padding is) and multiplied by the kernel seen as a
//! `(kh·kw·C_in) × C_out` matrix (`matrixmultiply::sgemm`). Tiles run in parallel on
//! rayon, so one image uses every core and a batch of images shares them. A plain `f64`
//! convolution beside it in the tests is the reference.

use rayon::prelude::*;

/// A channels-last feature map: `data[(y·width + x)·channels + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureMap {
    pub height: usize,
    pub width: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// The `channels` values at pixel `p` (row-major pixel index).
    pub fn pixel(&self, p: usize) -> &[f32] {
        &self.data[p * self.channels..(p + 1) * self.channels]
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.height * self.width
    }
}

/// A square-kernel convolution with symmetric zero padding, bias and ReLU.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv2d {
    /// Kernel side (height = width).
    pub size: usize,
    pub stride: usize,
    pub padding: usize,
    pub in_channels: usize,
    pub out_channels: usize,
    /// HWIO: `kernel[((ky·size + kx)·in + i)·out + o]`, i.e. a `(size²·in) × out` matrix.
    pub kernel: Vec<f32>,
    pub bias: Vec<f32>,
}

/// Output positions per GEMM tile: a tile's im2col rows (≤ 256 × 1728 values for AlexNet)
/// stay within a core's cache, and a 640×360 image still has tiles for every core.
const TILE: usize = 256;

/// Output side of a convolution or pooling window along one axis (`None`: no output).
pub fn output_side(input: usize, size: usize, stride: usize, padding: usize) -> Option<usize> {
    let padded = input + 2 * padding;
    (padded >= size).then(|| (padded - size) / stride + 1)
}

/// `c = a · b` for row-major `a` (`m×k`), `b` (`k×n`) and `c` (`m×n`).
fn matmul(a: &[f32], b: &[f32], c: &mut [f32], m: usize, k: usize, n: usize) {
    assert!(a.len() >= m * k && b.len() >= k * n && c.len() >= m * n);
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        c[..m * n].fill(0.0);
        return;
    }
    // SAFETY: the assert above keeps every index the row-major strides reach
    // (row < m, col < k or n) inside the three slices; `c` is borrowed mutably.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            n as isize,
            1,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

impl Conv2d {
    /// Rows of the kernel matrix: values in one receptive field.
    fn field(&self) -> usize {
        self.size * self.size * self.in_channels
    }

    /// The convolution of `input` followed by ReLU. `None` when the (padded) input is
    /// smaller than the kernel. Panics if `input.channels != self.in_channels`.
    pub fn forward_relu(&self, input: &FeatureMap) -> Option<FeatureMap> {
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

    #[test]
    fn convolution_matches_the_f64_definition() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        // Stride 4 with padding (AlexNet's first layer, smaller), stride 1 with padding,
        // and an image wide enough for several GEMM tiles.
        for (size, stride, padding, ci, co, h, w) in [
            (11, 4, 2, 3, 8, 37, 41),
            (5, 1, 2, 6, 10, 9, 13),
            (3, 1, 1, 4, 5, 20, 30),
            (3, 1, 0, 2, 3, 3, 3),
        ] {
            let conv = Conv2d {
                size,
                stride,
                padding,
                in_channels: ci,
                out_channels: co,
                kernel: random(&mut rng, size * size * ci * co),
                bias: random(&mut rng, co),
            };
            let input = FeatureMap {
                height: h,
                width: w,
                channels: ci,
                data: random(&mut rng, h * w * ci),
            };
            let fast = conv.forward_relu(&input).unwrap();
            let reference = conv_reference(&conv, &input);
            assert_eq!(fast.data.len(), reference.len());
            for (i, (f, r)) in fast.data.iter().zip(&reference).enumerate() {
                assert!(
                    (*f as f64 - r).abs() < 1e-4 * (1.0 + r.abs()),
                    "{size}x{size} s{stride} p{padding}: value {i}: {f} vs {r}"
                );
            }
        }
    }

    #[test]
    fn a_kernel_larger_than_the_padded_input_gives_nothing() {
        let conv = Conv2d {
            size: 11,
            stride: 4,
            padding: 2,
            in_channels: 1,
            out_channels: 1,
            kernel: vec![0.0; 121],
            bias: vec![0.0],
        };
        let tiny = FeatureMap {
            height: 6,
            width: 20,
            channels: 1,
            data: vec![0.0; 120],
        };
        assert!(conv.forward_relu(&tiny).is_none());
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
