//! Stride-1 convolutions by Winograd's minimal filtering (Lavin & Gray, "Fast Algorithms
//! for Convolutional Neural Networks", CVPR 2016): AlexNet's 5×5 and three 3×3 layers,
//! 55 % + 34 % of LPIPS's multiply-adds, in 4–6× fewer of them than im2col.
//!
//! `F(m×m, r×r)` computes an `m×m` block of outputs of an `r×r` kernel from an `α×α`
//! input tile (`α = m + r − 1`): `Y = Aᵀ [(G g Gᵀ) ⊙ (Bᵀ d B)] A`. Over channels the
//! element-wise product becomes `α²` matrix products — tiles × `C_in` by `C_in` × `C_out`
//! — which run on `matrixmultiply::sgemm` like the im2col path.
//!
//! The matrices come from Toom–Cook polynomial multiplication at the points
//! `0, ±1, ±2, ±½, …` and `∞` ([`Transform::new`]), computed in `f64`: correlation is the
//! transpose of multiplying a degree `m − 1` polynomial by the kernel's, so `A` and `G`
//! evaluate at the points and `B` is the inverse of the evaluation of the product.
//!
//! A batch of same-sized inputs is cut into units of whole tile rows (across inputs, so
//! that each transformed kernel matrix serves hundreds of tiles); units run in parallel
//! on rayon.

use nalgebra::DMatrix;
use rayon::prelude::*;

use super::maps::{FeatureMap, matmul, output_side};

/// The finite interpolation points, in the order they are taken: small magnitudes first
/// keep the transforms' entries, and so the `f32` rounding, small.
const POINTS: [f64; 9] = [0.0, 1.0, -1.0, 2.0, -2.0, 0.5, -0.5, 3.0, -3.0];

/// Output tile side: 4×4 outputs per tile, so `α` = 6 for 3×3 kernels and 8 for 5×5.
pub const TILE_OUT: usize = 4;

/// The three transforms of `F(m×m, r×r)`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Transform {
    /// Output tile side `m`.
    pub m: usize,
    /// Kernel side `r`.
    pub r: usize,
    /// Input tile side `α = m + r − 1`.
    pub alpha: usize,
    /// `Aᵀ`, `m × α`: the output transform.
    pub at: Vec<f32>,
    /// `Bᵀ`, `α × α`: the input transform.
    pub bt: Vec<f32>,
    /// `G`, `α × r`: the kernel transform, in `f64` (it runs once per kernel).
    pub g: Vec<f64>,
}

impl Transform {
    /// `F(m×m, r×r)`. Panics when `α − 1` exceeds the points there are (α ≤ 10).
    pub fn new(m: usize, r: usize) -> Self {
        assert!(
            m >= 1 && r >= 1,
            "Winograd tile and kernel sides are at least 1"
        );
        let alpha = m + r - 1;
        assert!(alpha - 1 <= POINTS.len(), "F({m}, {r}) needs more points");
        let points = &POINTS[..alpha - 1];
        // Row j evaluates a polynomial of `n` coefficients at point j; the last row (∞)
        // takes its leading coefficient.
        let evaluation = |n: usize| {
            DMatrix::from_fn(alpha, n, |j, i| match points.get(j) {
                Some(p) => p.powi(i as i32),
                None => f64::from(u8::from(i == n - 1)),
            })
        };
        let a = evaluation(m);
        let b = evaluation(alpha)
            .try_inverse()
            .expect("distinct points give an invertible evaluation matrix");
        Self {
            m,
            r,
            alpha,
            at: to_f32(row_major(&a.transpose())),
            bt: to_f32(row_major(&b.transpose())),
            g: row_major(&evaluation(r)),
        }
    }
}

fn row_major(mat: &DMatrix<f64>) -> Vec<f64> {
    (0..mat.nrows())
        .flat_map(|i| (0..mat.ncols()).map(move |j| mat[(i, j)]))
        .collect()
}

/// `f32` copies; values within rounding of zero (the inverse's) become exactly zero, so
/// the sparse products below skip them.
fn to_f32(values: Vec<f64>) -> Vec<f32> {
    values
        .into_iter()
        .map(|v| if v.abs() < 1e-12 { 0.0 } else { v as f32 })
        .collect()
}

/// The non-zero entries of each row of a row-major `rows × cols` matrix: `(column, value)`.
fn sparse_rows(matrix: &[f32], cols: usize) -> Vec<Vec<(usize, f32)>> {
    matrix
        .chunks_exact(cols)
        .map(|row| {
            row.iter()
                .enumerate()
                .filter(|(_, v)| **v != 0.0)
                .map(|(j, v)| (j, *v))
                .collect()
        })
        .collect()
}

/// A stride-1 convolution with zero padding, its kernel taken into the Winograd domain.
#[derive(Clone, Debug, PartialEq)]
pub struct WinogradConv {
    transform: Transform,
    padding: usize,
    in_channels: usize,
    out_channels: usize,
    /// `α²` matrices `C_in × C_out`, `u[(e·C_in + i)·C_out + o]` with `e = ξ·α + ν`:
    /// `(G g Gᵀ)[ξ][ν]` of the kernel from input channel `i` to output `o`.
    u: Vec<f32>,
    /// Rows of `Bᵀ` and `Aᵀ` without their zeros.
    bt_rows: Vec<Vec<(usize, f32)>>,
    at_rows: Vec<Vec<(usize, f32)>>,
}

/// Per-thread scratch of one unit of tiles.
#[derive(Default)]
struct Scratch {
    patch: Vec<f32>,
    half: Vec<f32>,
    v: Vec<f32>,
    product: Vec<f32>,
}

/// `buffer[..len]`, grown as needed; what it held is left for the caller to overwrite.
fn grown(buffer: &mut Vec<f32>, len: usize) -> &mut [f32] {
    if buffer.len() < len {
        buffer.resize(len, 0.0);
    }
    &mut buffer[..len]
}

/// `dst = Σ coef · src` over `terms` (zeros when there are none).
#[inline(always)]
fn combine<'a>(dst: &mut [f32], mut terms: impl Iterator<Item = (f32, &'a [f32])>) {
    match terms.next() {
        Some((coef, src)) => {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = coef * s;
            }
        }
        None => dst.fill(0.0),
    }
    for (coef, src) in terms {
        for (d, s) in dst.iter_mut().zip(src) {
            *d += coef * s;
        }
    }
}

/// Tiles a unit of work aims for: enough rows for `sgemm` to run at speed and to share
/// each transformed kernel matrix, which is `α²/r²` times the kernel's size, over many
/// tiles.
const UNIT_TILES: usize = 64;

impl WinogradConv {
    /// The kernel `kernel` (HWIO, `size × size × in × out`) for `F(TILE_OUT, size)`.
    pub fn new(
        kernel: &[f32],
        size: usize,
        padding: usize,
        in_channels: usize,
        out_channels: usize,
    ) -> Self {
        assert_eq!(kernel.len(), size * size * in_channels * out_channels);
        let transform = Transform::new(TILE_OUT, size);
        let (alpha, r) = (transform.alpha, size);
        let g = &transform.g;
        let pairs = in_channels * out_channels;
        let mut u = vec![0.0f32; alpha * alpha * pairs];
        // (G g Gᵀ) per (i, o), through the separable half product `G g`.
        let mut half = vec![0.0f64; alpha * r];
        for pair in 0..pairs {
            let tap = |ky: usize, kx: usize| f64::from(kernel[(ky * size + kx) * pairs + pair]);
            for xi in 0..alpha {
                for kx in 0..r {
                    half[xi * r + kx] = (0..r).map(|ky| g[xi * r + ky] * tap(ky, kx)).sum();
                }
            }
            for xi in 0..alpha {
                for nu in 0..alpha {
                    let value: f64 = (0..r).map(|kx| half[xi * r + kx] * g[nu * r + kx]).sum();
                    u[(xi * alpha + nu) * pairs + pair] = value as f32;
                }
            }
        }
        Self {
            bt_rows: sparse_rows(&transform.bt, alpha),
            at_rows: sparse_rows(&transform.at, alpha),
            transform,
            padding,
            in_channels,
            out_channels,
            u,
        }
    }

    /// The convolution of each of `inputs` (all of one size) plus `bias`, then ReLU.
    /// `None` when the padded inputs are smaller than the kernel.
    ///
    /// The tiles of all inputs are cut into units of whole tile rows, so that one unit
    /// writes one contiguous band of output rows per input it touches; units run in
    /// parallel.
    pub fn forward_relu_batch(
        &self,
        inputs: &[FeatureMap],
        bias: &[f32],
    ) -> Option<Vec<FeatureMap>> {
        let first = inputs.first()?;
        for input in inputs {
            assert_eq!(input.channels, self.in_channels, "channels of a conv input");
            assert_eq!(
                (input.height, input.width),
                (first.height, first.width),
                "a batch of one size"
            );
        }
        let Transform { m, r, .. } = self.transform;
        let out_h = output_side(first.height, r, 1, self.padding)?;
        let out_w = output_side(first.width, r, 1, self.padding)?;
        let n = self.out_channels;
        let (tiles_y, tiles_x) = (out_h.div_ceil(m), out_w.div_ceil(m));
        let mut outputs: Vec<Vec<f32>> = inputs
            .iter()
            .map(|_| vec![0.0; out_h * out_w * n])
            .collect();
        // One slice per tile row of every input, in order: `tiles_y` per input.
        let mut tile_rows: Vec<&mut [f32]> = outputs
            .iter_mut()
            .flat_map(|out| out.chunks_mut(m * out_w * n))
            .collect();
        let threads = rayon::current_num_threads().max(1);
        let unit_rows = UNIT_TILES
            .div_ceil(tiles_x)
            .min(tile_rows.len().div_ceil(threads))
            .max(1);
        tile_rows
            .par_chunks_mut(unit_rows)
            .enumerate()
            .for_each_init(Scratch::default, |scratch, (unit, rows)| {
                let tiles: Vec<(&FeatureMap, usize, usize)> = (0..rows.len() * tiles_x)
                    .map(|t| {
                        let row = unit * unit_rows + t / tiles_x;
                        (&inputs[row / tiles_y], row % tiles_y, t % tiles_x)
                    })
                    .collect();
                self.unit(&tiles, bias, out_w, rows, scratch);
            });
        Some(
            outputs
                .into_iter()
                .map(|data| FeatureMap {
                    height: out_h,
                    width: out_w,
                    channels: n,
                    data,
                })
                .collect(),
        )
    }

    /// The outputs of `tiles` (input, tile row, tile column; whole tile rows in order)
    /// into `rows`, the output bands of their tile rows. The transforms' loops are
    /// compiled twice: for AVX2 (8 lanes), taken when the CPU has it, and for the
    /// target's baseline.
    fn unit(
        &self,
        tiles: &[(&FeatureMap, usize, usize)],
        bias: &[f32],
        out_w: usize,
        rows: &mut [&mut [f32]],
        scratch: &mut Scratch,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, the only feature `unit_avx2` is compiled for.
            return unsafe { self.unit_avx2(tiles, bias, out_w, rows, scratch) };
        }
        self.unit_any(tiles, bias, out_w, rows, scratch)
    }

    /// [`Self::unit`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn unit_avx2(
        &self,
        tiles: &[(&FeatureMap, usize, usize)],
        bias: &[f32],
        out_w: usize,
        rows: &mut [&mut [f32]],
        scratch: &mut Scratch,
    ) {
        self.unit_any(tiles, bias, out_w, rows, scratch)
    }

    /// [`Self::unit`] for whatever the caller is compiled for.
    #[inline(always)]
    fn unit_any(
        &self,
        tiles: &[(&FeatureMap, usize, usize)],
        bias: &[f32],
        out_w: usize,
        rows: &mut [&mut [f32]],
        scratch: &mut Scratch,
    ) {
        let Transform { m, alpha, .. } = self.transform;
        let (c, n) = (self.in_channels, self.out_channels);
        let elements = alpha * alpha;
        let count = tiles.len();
        let tiles_x = count / rows.len();
        for (t, &(input, ty, tx)) in tiles.iter().enumerate() {
            self.input_tile(input, ty * m, tx * m, t, count, scratch);
        }
        let v = &scratch.v[..elements * count * c];
        let product = grown(&mut scratch.product, elements * count * n);
        for e in 0..elements {
            matmul(
                &v[e * count * c..(e + 1) * count * c],
                &self.u[e * c * n..(e + 1) * c * n],
                &mut product[e * count * n..(e + 1) * count * n],
                count,
                c,
                n,
            );
        }
        let product = &scratch.product[..elements * count * n];
        let half = grown(&mut scratch.half, m * alpha * n);
        let mut px = vec![0.0f32; n];
        for t in 0..count {
            let band = &mut *rows[t / tiles_x];
            let (band_h, tx) = (band.len() / (out_w * n), t % tiles_x);
            // Aᵀ M: half[u][b] = Σ_a Aᵀ[u][a] M[a][b].
            for (uu, row) in self.at_rows.iter().enumerate() {
                for b in 0..alpha {
                    combine(
                        &mut half[(uu * alpha + b) * n..][..n],
                        row.iter().map(|&(a, coef)| {
                            (coef, &product[((a * alpha + b) * count + t) * n..][..n])
                        }),
                    );
                }
            }
            // (Aᵀ M) A, plus bias, ReLU, where the output exists.
            for uu in 0..m.min(band_h) {
                for (vv, row) in self.at_rows.iter().enumerate() {
                    let x = tx * m + vv;
                    if x >= out_w {
                        break;
                    }
                    combine(
                        &mut px,
                        row.iter()
                            .map(|&(b, coef)| (coef, &half[(uu * alpha + b) * n..][..n])),
                    );
                    let dst = &mut band[(uu * out_w + x) * n..][..n];
                    for ((d, v), b) in dst.iter_mut().zip(&px).zip(bias) {
                        *d = (v + b).max(0.0);
                    }
                }
            }
        }
    }

    /// `Bᵀ d B` of the `α×α` input tile whose first output is `(oy, ox)`, into tile `t`
    /// of the unit's `α²` matrices (`count × C_in` each).
    #[inline(always)]
    fn input_tile(
        &self,
        input: &FeatureMap,
        oy: usize,
        ox: usize,
        t: usize,
        count: usize,
        scratch: &mut Scratch,
    ) {
        let alpha = self.transform.alpha;
        let c = self.in_channels;
        let patch = grown(&mut scratch.patch, alpha * alpha * c);
        let p = self.padding;
        let inside =
            oy >= p && ox >= p && oy + alpha <= input.height + p && ox + alpha <= input.width + p;
        if !inside {
            patch.fill(0.0);
        }
        for dy in 0..alpha {
            let Some(iy) = (oy + dy)
                .checked_sub(self.padding)
                .filter(|&y| y < input.height)
            else {
                continue;
            };
            let x0 = ox as isize - self.padding as isize;
            let first = (-x0).max(0) as usize;
            let end = ((input.width as isize - x0).max(0) as usize).min(alpha);
            if first >= end {
                continue;
            }
            let src = (iy * input.width + (x0 + first as isize) as usize) * c;
            patch[(dy * alpha + first) * c..(dy * alpha + end) * c]
                .copy_from_slice(&input.data[src..src + (end - first) * c]);
        }
        // Bᵀ d: half[a][x] = Σ_y Bᵀ[a][y] d[y][x].
        let half = grown(&mut scratch.half, alpha * alpha * c);
        for (a, row) in self.bt_rows.iter().enumerate() {
            for x in 0..alpha {
                combine(
                    &mut half[(a * alpha + x) * c..][..c],
                    row.iter()
                        .map(|&(y, coef)| (coef, &patch[(y * alpha + x) * c..][..c])),
                );
            }
        }
        // (Bᵀ d) B: v[a][b] = Σ_x half[a][x] Bᵀ[b][x].
        let v = grown(&mut scratch.v, alpha * alpha * count * c);
        for a in 0..alpha {
            for (b, row) in self.bt_rows.iter().enumerate() {
                combine(
                    &mut v[((a * alpha + b) * count + t) * c..][..c],
                    row.iter()
                        .map(|&(x, coef)| (coef, &half[(a * alpha + x) * c..][..c])),
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 1D `F(m, r)`: `y = Aᵀ [(G g) ⊙ (Bᵀ d)]` is the correlation `y_i = Σ_k d_{i+k} g_k`.
    #[test]
    fn the_transforms_compute_a_correlation() {
        for (m, r) in [(2, 3), (4, 3), (4, 5), (2, 5), (6, 3)] {
            let t = Transform::new(m, r);
            let alpha = t.alpha;
            assert_eq!(alpha, m + r - 1);
            let d: Vec<f64> = (0..alpha)
                .map(|i| ((i * 7 + 3) % 11) as f64 / 5.0 - 1.0)
                .collect();
            let g: Vec<f64> = (0..r)
                .map(|k| ((k * 5 + 2) % 7) as f64 / 3.0 - 1.0)
                .collect();
            let gg: Vec<f64> = (0..alpha)
                .map(|j| (0..r).map(|k| t.g[j * r + k] * g[k]).sum())
                .collect();
            let bd: Vec<f64> = (0..alpha)
                .map(|j| (0..alpha).map(|y| t.bt[j * alpha + y] as f64 * d[y]).sum())
                .collect();
            for i in 0..m {
                let fast: f64 = (0..alpha)
                    .map(|j| t.at[i * alpha + j] as f64 * gg[j] * bd[j])
                    .sum();
                let direct: f64 = (0..r).map(|k| d[i + k] * g[k]).sum();
                assert!(
                    (fast - direct).abs() < 1e-5,
                    "F({m}, {r}) output {i}: {fast} vs {direct}"
                );
            }
        }
    }
}
