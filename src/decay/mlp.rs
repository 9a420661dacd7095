//! The Neural Decaying Function's network f_θ: a small fully connected ReLU MLP with one
//! output, its hand-written backward pass and its own Adam. Batched over rows (one row per
//! Gaussian) with rayon; the weight gradients are reduced over fixed-size row chunks in a
//! fixed order, so results do not depend on the thread count (resume stays bit-identical).
//!
//! Parameters live in one flat vector: for each layer `W` (out × in, row-major) then `b`.
//! The output `z` is mapped to `τ = f_min + (f_max − f_min)·sigmoid(z)` by [`Mlp::tau`].

use crate::math::numerics::{Real, sigmoid};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use rayon::prelude::*;

/// Rows per parallel work item (fixed, for a thread-count-independent reduction order).
const CHUNK: usize = 512;

/// A chunk of rows in the forward pass: index, outputs, hidden activations per layer.
type RowChunk<'a, F> = (usize, &'a mut [F], Vec<&'a mut [F]>);

/// A ReLU MLP `in → hidden… → 1` in float type `F`.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp<F: Real = f32> {
    /// Layer widths, input first, output (1) last.
    pub dims: Vec<usize>,
    /// All weights and biases, see the module docs for the layout.
    pub params: Vec<F>,
}

/// Forward intermediates of a batch, needed by [`Mlp::backward`].
#[derive(Clone, Debug, Default)]
pub struct MlpCache<F> {
    /// Post-ReLU activations of each hidden layer, `rows × width` each.
    hidden: Vec<Vec<F>>,
    /// Output before the sigmoid, one per row.
    pub z: Vec<F>,
}

/// Gradients of a batch's scalar loss.
#[derive(Clone, Debug, PartialEq)]
pub struct MlpGrad<F> {
    /// dL/d(params), laid out like [`Mlp::params`].
    pub params: Vec<F>,
    /// dL/d(inputs), `rows × dims[0]` (only when asked for).
    pub inputs: Option<Vec<F>>,
}

impl<F: Real> Mlp<F> {
    /// Number of parameters for these widths.
    pub fn param_count(dims: &[usize]) -> usize {
        dims.windows(2).map(|w| w[1] * w[0] + w[1]).sum()
    }

    /// PyTorch-style initialisation (`U(−1/√fan_in, 1/√fan_in)` for weights and biases),
    /// deterministic from `seed`. `dims` must start with the input width and end with 1.
    pub fn new(dims: &[usize], seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut params = Vec::with_capacity(Self::param_count(dims));
        for w in dims.windows(2) {
            let bound = 1.0 / (w[0] as f64).sqrt();
            for _ in 0..(w[1] * w[0] + w[1]) {
                let u = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
                params.push(F::c(bound * (2.0 * u - 1.0)));
            }
        }
        Self {
            dims: dims.to_vec(),
            params,
        }
    }

    /// The same network in another float type.
    pub fn cast<G: Real>(&self) -> Mlp<G> {
        Mlp {
            dims: self.dims.clone(),
            params: self.params.iter().map(|p| G::c(p.f64())).collect(),
        }
    }

    pub fn input_width(&self) -> usize {
        self.dims[0]
    }

    /// Offsets of layer `l`'s weights and biases in `params`.
    fn offsets(&self, l: usize) -> (usize, usize) {
        let mut o = 0;
        for w in self.dims.windows(2).take(l) {
            o += w[1] * w[0] + w[1];
        }
        (o, o + self.dims[l + 1] * self.dims[l])
    }

    /// One row forward: fills `acts[l]` (hidden activations) and returns `z`.
    fn forward_row(&self, x: &[F], acts: &mut [Vec<F>]) -> F {
        let layers = self.dims.len() - 1;
        let mut z = F::zero();
        for l in 0..layers {
            let (wo, bo) = self.offsets(l);
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            let (before, after) = acts.split_at_mut(l);
            let input: &[F] = if l == 0 { x } else { &before[l - 1] };
            for j in 0..n_out {
                let row = &self.params[wo + j * n_in..wo + (j + 1) * n_in];
                let mut s = self.params[bo + j];
                for k in 0..n_in {
                    s += row[k] * input[k];
                }
                if l + 1 == layers {
                    z = s;
                } else {
                    after[0][j] = s.max(F::zero());
                }
            }
        }
        z
    }

    /// Forward over `rows` inputs (`inputs.len() == rows × dims[0]`): the pre-sigmoid
    /// outputs, plus the cache for [`Mlp::backward`].
    pub fn forward(&self, inputs: &[F]) -> MlpCache<F> {
        let d = self.dims[0];
        let rows = inputs.len() / d;
        let hidden_dims = &self.dims[1..self.dims.len() - 1];
        let mut hidden: Vec<Vec<F>> = hidden_dims
            .iter()
            .map(|&w| vec![F::zero(); rows * w])
            .collect();
        let mut z = vec![F::zero(); rows];
        // Split every buffer into matching row chunks.
        let mut chunks: Vec<RowChunk<F>> = z
            .chunks_mut(CHUNK)
            .enumerate()
            .map(|(c, zc)| (c, zc, Vec::new()))
            .collect();
        for (h, &w) in hidden.iter_mut().zip(hidden_dims) {
            for (slot, hc) in chunks.iter_mut().zip(h.chunks_mut(CHUNK * w)) {
                slot.2.push(hc);
            }
        }
        let run = |(c, zc, mut hs): RowChunk<F>| {
            let mut acts: Vec<Vec<F>> = hidden_dims.iter().map(|&w| vec![F::zero(); w]).collect();
            for (r, zr) in zc.iter_mut().enumerate() {
                let row = c * CHUNK + r;
                *zr = self.forward_row(&inputs[row * d..(row + 1) * d], &mut acts);
                for (h, (a, &w)) in hs.iter_mut().zip(acts.iter().zip(hidden_dims)) {
                    h[r * w..(r + 1) * w].copy_from_slice(a);
                }
            }
        };
        // One chunk: no thread hand-off (small batches, finite-difference checks).
        if chunks.len() == 1 {
            chunks.into_iter().for_each(run);
        } else {
            chunks.into_par_iter().for_each(run);
        }
        MlpCache { hidden, z }
    }

    /// `τ = f_min + (f_max − f_min)·sigmoid(z)`.
    pub fn tau(z: F, f_min: F, f_max: F) -> F {
        f_min + (f_max - f_min) * sigmoid(z)
    }

    /// dτ/dz of [`Mlp::tau`].
    pub fn tau_derivative(z: F, f_min: F, f_max: F) -> F {
        let s = sigmoid(z);
        (f_max - f_min) * s * (F::one() - s)
    }

    /// Backward of a batch from dL/dz (one per row). Rows with a zero upstream gradient
    /// are skipped. With `want_inputs`, dL/d(inputs) is returned too.
    pub fn backward(
        &self,
        inputs: &[F],
        cache: &MlpCache<F>,
        d_z: &[F],
        want_inputs: bool,
    ) -> MlpGrad<F> {
        let d = self.dims[0];
        let rows = d_z.len();
        let layers = self.dims.len() - 1;
        let np = self.params.len();
        let max_w = *self.dims.iter().max().unwrap_or(&1);
        let mut d_inputs = if want_inputs {
            vec![F::zero(); rows * d]
        } else {
            Vec::new()
        };
        let mut input_chunks: Vec<Option<&mut [F]>> = if want_inputs {
            d_inputs.chunks_mut(CHUNK * d).map(Some).collect()
        } else {
            (0..rows.div_ceil(CHUNK)).map(|_| None).collect()
        };
        let work = |(c, d_in_chunk): (usize, &mut Option<&mut [F]>)| {
            let mut g = vec![F::zero(); np];
            let mut delta = vec![F::zero(); max_w];
            let mut next = vec![F::zero(); max_w];
            let end = ((c + 1) * CHUNK).min(rows);
            for row in c * CHUNK..end {
                if d_z[row] == F::zero() && !want_inputs {
                    continue;
                }
                delta[0] = d_z[row];
                for l in (0..layers).rev() {
                    let (wo, bo) = self.offsets(l);
                    let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
                    let input: &[F] = if l == 0 {
                        &inputs[row * d..(row + 1) * d]
                    } else {
                        &cache.hidden[l - 1][row * n_in..(row + 1) * n_in]
                    };
                    next[..n_in].iter_mut().for_each(|v| *v = F::zero());
                    for j in 0..n_out {
                        let dj = delta[j];
                        if dj == F::zero() {
                            continue;
                        }
                        g[bo + j] += dj;
                        for k in 0..n_in {
                            g[wo + j * n_in + k] += dj * input[k];
                            next[k] += dj * self.params[wo + j * n_in + k];
                        }
                    }
                    if l > 0 {
                        // Through the ReLU of the layer below.
                        for k in 0..n_in {
                            delta[k] = if input[k] > F::zero() {
                                next[k]
                            } else {
                                F::zero()
                            };
                        }
                    } else if let Some(di) = d_in_chunk.as_deref_mut() {
                        let r = row - c * CHUNK;
                        di[r * d..(r + 1) * d].copy_from_slice(&next[..d]);
                    }
                }
            }
            g
        };
        let partial: Vec<Vec<F>> = if input_chunks.len() == 1 {
            input_chunks.iter_mut().enumerate().map(work).collect()
        } else {
            input_chunks.par_iter_mut().enumerate().map(work).collect()
        };
        let mut params = vec![F::zero(); np];
        for g in &partial {
            params.iter_mut().zip(g).for_each(|(a, b)| *a += *b);
        }
        MlpGrad {
            params,
            inputs: want_inputs.then_some(d_inputs),
        }
    }
}

/// Adam for the MLP alone (PyTorch semantics: L2 weight decay added to the gradient).
#[derive(Clone, Debug, PartialEq)]
pub struct MlpAdam {
    pub lr: f32,
    pub weight_decay: f32,
    pub step: u64,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
}

impl MlpAdam {
    pub const BETA1: f32 = 0.9;
    pub const BETA2: f32 = 0.999;
    pub const EPSILON: f32 = 1e-8;

    pub fn new(params: usize, lr: f32, weight_decay: f32) -> Self {
        Self {
            lr,
            weight_decay,
            step: 0,
            m: vec![0.0; params],
            v: vec![0.0; params],
        }
    }

    /// One step of `params` with gradient `grad`.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) {
        self.step += 1;
        let bc1 = 1.0 - Self::BETA1.powi(self.step.min(i32::MAX as u64) as i32);
        let bc2 = 1.0 - Self::BETA2.powi(self.step.min(i32::MAX as u64) as i32);
        for i in 0..params.len() {
            let g = grad[i] + self.weight_decay * params[i];
            self.m[i] = Self::BETA1 * self.m[i] + (1.0 - Self::BETA1) * g;
            self.v[i] = Self::BETA2 * self.v[i] + (1.0 - Self::BETA2) * g * g;
            let mh = self.m[i] / bc1;
            let vh = self.v[i] / bc2;
            params[i] -= self.lr * mh / (vh.sqrt() + Self::EPSILON);
        }
    }
}
