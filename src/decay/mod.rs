//! 4C4D's opacity decay (paper §3.2–3.3) as [`TrainHooks`]: the Neural Decaying Function
//! f_θ, visibility detection and the separate decay of invisible Gaussians, plus the
//! hand-tuned ablation variants. Plain 4DGS is `NoHooks` (or the `none` variant).
//!
//! Semantics of one optimiser step `s` (1-based) after the warm-up (`s > warmup`):
//! 1. f_θ is evaluated once for every Gaussian on the pre-step model (inputs detached);
//!    `τ_g = f_min + (f_max − f_min)·sigmoid(f_θ(x_g))`. τ depends on the Gaussian only,
//!    not on the view, so every view of the batch sees the same τ_g.
//! 2. Each view of the batch renders visible Gaussians (`G_m` of that view and time) with
//!    opacity `τ_g·ω(t)·sigmoid(o_g)` (invisible ones with factor 1); dL/dτ_g of all views
//!    is summed and back-propagated into f_θ's weights once per step.
//! 3. After the Gaussians' Adam step the stored opacity is multiplied ONCE:
//!    `o ← o·τ_g` (detached) if g was visible in at least one view of the batch, else
//!    `o ← o·β`. Then f_θ takes its own Adam step.
//!
//! The other variants only multiply the stored opacity after each step (`constant`: c;
//! `pow`/`exp`: hand-tuned functions of o, see [`variants`]); with visibility on,
//! invisible Gaussians get β instead. Nothing here runs at evaluation/render time.
//! On the GPU backend every variant but `none` runs on the device ([`gpu::GpuDecay`], lent
//! through [`TrainHooks::device_decay`] as a [`DeviceDecay`]).
//! Full description: docs/decay.md.

pub mod config;
pub mod gpu;
pub mod inputs;
pub mod mlp;
pub mod report;
pub mod variants;
pub mod visibility;

pub use config::{DecayConfig, DecayConfigError, DecayInputs, DecayVariant, VisibilityMode};

use crate::math::numerics::sigmoid;
use crate::model::Gaussians;
use crate::train::{DeviceDecay, ModelAccess, StepStats, TrainHooks, View};
use mlp::{Mlp, MlpAdam, MlpCache};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Per-step scratch, valid between the first `opacity_factor` of a step and `after_step`.
struct StepState {
    /// 0-based iteration index the trainer passes to `opacity_factor`.
    iteration: u64,
    len: usize,
    /// Neural only: f_θ's inputs, forward cache, τ, and summed dL/dτ.
    inputs: Vec<f32>,
    cache: MlpCache<f32>,
    tau: Vec<f32>,
    d_tau: Vec<f32>,
    /// Visible in at least one view of the batch so far.
    seen: Vec<bool>,
    /// Visibility of the view rendered last (its factor gradient comes next).
    last_view: Vec<bool>,
}

/// The 4C4D decay as trainer hooks. Construct with [`DecayHooks::new`], pass
/// `&mut hooks` to [`crate::train::train`].
pub struct DecayHooks {
    config: DecayConfig,
    mlp: Mlp<f32>,
    adam: MlpAdam,
    step: Option<StepState>,
    last: Option<StepStats>,
    stop: Option<Arc<AtomicBool>>,
    state_error: Option<String>,
    skipped_updates: u64,
}

const STATE_MAGIC: &[u8; 8] = b"4C4DMLP1";

impl DecayHooks {
    /// Hooks for `config` (f_θ initialised from `config.seed`).
    pub fn new(config: &DecayConfig) -> Result<Self, DecayConfigError> {
        config.validate()?;
        let mlp = Mlp::new(&config.mlp_dims(), config.seed);
        let adam = MlpAdam::new(
            mlp.params.len(),
            config.lr as f32,
            config.weight_decay as f32,
        );
        Ok(Self {
            config: config.clone(),
            mlp,
            adam,
            step: None,
            last: None,
            stop: None,
            state_error: None,
            skipped_updates: 0,
        })
    }

    /// Stop the run cleanly (checkpoint, resumable) once `flag` is set, e.g. by Ctrl-C.
    pub fn with_stop_flag(mut self, flag: Arc<AtomicBool>) -> Self {
        self.stop = Some(flag);
        self
    }

    pub fn config(&self) -> &DecayConfig {
        &self.config
    }

    /// f_θ (weights as trained so far).
    pub fn mlp(&self) -> &Mlp<f32> {
        &self.mlp
    }

    /// f_θ's optimiser state.
    pub fn optimiser(&self) -> &MlpAdam {
        &self.adam
    }

    /// What the decay did in the last step, if it ran.
    pub fn last_stats(&self) -> Option<StepStats> {
        self.last
    }

    /// Why a checkpoint's hook state was ignored (f_θ then restarted from its seed).
    pub fn state_error(&self) -> Option<&str> {
        self.state_error.as_deref()
    }

    /// f_θ updates skipped because their gradient was not finite.
    pub fn skipped_updates(&self) -> u64 {
        self.skipped_updates
    }

    /// τ of every Gaussian of `model` under the current f_θ.
    pub fn tau(&self, model: &Gaussians<f32>) -> Vec<f32> {
        let x = inputs::input_rows(model, self.config.inputs);
        let cache = self.mlp.forward(&x);
        self.tau_of(&cache)
    }

    fn tau_of(&self, cache: &MlpCache<f32>) -> Vec<f32> {
        let (lo, hi) = (self.config.f_min as f32, self.config.f_max as f32);
        // A NaN output (only from a NaN model, which the trainer reports) maps to mid-range.
        cache
            .z
            .iter()
            .map(|&z| {
                if z.is_nan() {
                    0.5 * (lo + hi)
                } else {
                    Mlp::tau(z, lo, hi)
                }
            })
            .collect()
    }

    fn active(&self, iteration: u64) -> bool {
        self.config.variant != DecayVariant::None && iteration >= self.config.warmup
    }

    /// The per-step decay factor of Gaussian `i` visible in the batch (`seen`).
    fn variant_factor(&self, state: &StepState, i: usize, logit: f32) -> f64 {
        let o = || sigmoid(logit as f64);
        match self.config.variant {
            DecayVariant::None => 1.0,
            DecayVariant::Constant => self.config.constant,
            DecayVariant::Pow => variants::pow_factor(o(), &self.config),
            DecayVariant::Exp => variants::exp_factor(o(), &self.config),
            DecayVariant::Neural => state.tau[i] as f64,
        }
    }
}

impl TrainHooks for DecayHooks {
    /// `none` leaves the model alone, the per-step decays edit opacities every step, the
    /// neural decay wants an opacity factor (on a device trainer, unless
    /// [`TrainHooks::device_decay`] lends the decay to it).
    fn model_access(&self) -> ModelAccess {
        match self.config.variant {
            DecayVariant::None => ModelAccess::None,
            DecayVariant::Constant | DecayVariant::Pow | DecayVariant::Exp => {
                ModelAccess::EveryStep
            }
            DecayVariant::Neural => ModelAccess::OpacityFactor,
        }
    }

    fn opacity_factor(
        &mut self,
        iteration: u64,
        model: &Gaussians<f32>,
        view: &View,
    ) -> Option<Vec<f32>> {
        if !self.active(iteration) {
            return None;
        }
        let fresh = match &self.step {
            Some(s) => s.iteration != iteration || s.len != model.len(),
            None => true,
        };
        if fresh {
            let neural = self.config.variant == DecayVariant::Neural;
            let (inputs, cache) = if neural {
                let x = inputs::input_rows(model, self.config.inputs);
                let cache = self.mlp.forward(&x);
                (x, cache)
            } else {
                (Vec::new(), MlpCache::default())
            };
            let tau = self.tau_of(&cache);
            self.step = Some(StepState {
                iteration,
                len: model.len(),
                inputs,
                cache,
                d_tau: vec![0.0; tau.len()],
                tau,
                seen: vec![false; model.len()],
                last_view: Vec::new(),
            });
        }
        let vis = visibility::visible(
            model,
            &view.camera,
            view.time,
            self.config.visibility,
            self.config.near as f32,
        );
        let state = self.step.as_mut().expect("step state was just set");
        state.seen.iter_mut().zip(&vis).for_each(|(s, &v)| *s |= v);
        let factor = (self.config.variant == DecayVariant::Neural).then(|| {
            vis.iter()
                .zip(&state.tau)
                .map(|(&v, &t)| if v { t } else { 1.0 })
                .collect()
        });
        state.last_view = vis;
        factor
    }

    fn factor_gradient(&mut self, iteration: u64, model: &Gaussians<f32>, gradient: &[f32]) {
        let Some(state) = self.step.as_mut() else {
            return;
        };
        if state.iteration != iteration || state.len != model.len() {
            return;
        }
        for ((d, &g), &v) in state.d_tau.iter_mut().zip(gradient).zip(&state.last_view) {
            if v {
                *d += g;
            }
        }
    }

    fn after_step(&mut self, iteration: u64, model: &mut Gaussians<f32>) {
        let Some(state) = self.step.take() else {
            return;
        };
        // Only the step whose views were just rendered (`iteration` is 1-based).
        if state.iteration + 1 != iteration || state.len != model.len() {
            return;
        }
        let (mut lo, mut hi, mut sum, mut visible) = (f64::INFINITY, 0.0f64, 0.0, 0);
        for i in 0..model.len() {
            let logit = model.opacity_logits[i];
            let d = if state.seen[i] {
                visible += 1;
                self.variant_factor(&state, i, logit)
            } else {
                self.config.beta
            };
            lo = lo.min(d);
            hi = hi.max(d);
            sum += d;
            model.opacity_logits[i] = variants::decayed_logit(logit, d);
        }
        self.last = Some(StepStats {
            iteration,
            visible,
            invisible: model.len() - visible,
            min_factor: lo,
            mean_factor: sum / model.len().max(1) as f64,
            max_factor: hi,
        });
        if self.config.variant == DecayVariant::Neural {
            let (f_min, f_max) = (self.config.f_min as f32, self.config.f_max as f32);
            let d_z: Vec<f32> = state
                .d_tau
                .iter()
                .zip(&state.cache.z)
                .map(|(&d, &z)| d * Mlp::tau_derivative(z, f_min, f_max))
                .collect();
            let grad = self.mlp.backward(&state.inputs, &state.cache, &d_z, false);
            // A non-finite gradient (a diverging render) must not poison f_θ: skip it;
            // the trainer's NaN guard reports the model.
            if grad.params.iter().all(|g| g.is_finite()) {
                self.adam.step(&mut self.mlp.params, &grad.params);
            } else {
                self.skipped_updates += 1;
            }
        }
    }

    /// Every variant but `none` lends itself to a device trainer (f_θ unused by the
    /// hand-tuned ones).
    fn device_decay(&mut self) -> Option<DeviceDecay<'_>> {
        if self.config.variant == DecayVariant::None {
            return None;
        }
        Some(DeviceDecay {
            config: &self.config,
            mlp: &mut self.mlp,
            adam: &mut self.adam,
            last: &mut self.last,
            skipped_updates: &mut self.skipped_updates,
        })
    }

    fn save_state(&self) -> Vec<u8> {
        if self.config.variant != DecayVariant::Neural {
            return Vec::new();
        }
        let mut b = STATE_MAGIC.to_vec();
        b.extend((self.mlp.dims.len() as u32).to_le_bytes());
        for &d in &self.mlp.dims {
            b.extend((d as u32).to_le_bytes());
        }
        b.extend(self.adam.step.to_le_bytes());
        for v in [&self.mlp.params, &self.adam.m, &self.adam.v] {
            for x in v.iter() {
                b.extend(x.to_le_bytes());
            }
        }
        b
    }

    fn load_state(&mut self, state: &[u8]) {
        if state.is_empty() || self.config.variant != DecayVariant::Neural {
            return;
        }
        match decode_state(state, &self.mlp.dims) {
            Ok((step, params, m, v)) => {
                self.mlp.params = params;
                self.adam.step = step;
                self.adam.m = m;
                self.adam.v = v;
                self.state_error = None;
            }
            Err(e) => self.state_error = Some(e),
        }
    }

    fn stop_requested(&mut self, _iteration: u64) -> bool {
        self.stop
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    }
}

type Decoded = (u64, Vec<f32>, Vec<f32>, Vec<f32>);

fn decode_state(b: &[u8], dims: &[usize]) -> Result<Decoded, String> {
    let mut pos = 0;
    let mut take = |n: usize| -> Result<&[u8], String> {
        let s = b
            .get(pos..pos + n)
            .ok_or("the checkpoint's decay state is truncated")?;
        pos += n;
        Ok(s)
    };
    if take(8)? != STATE_MAGIC {
        return Err("the checkpoint's hook state is not a 4C4D decay state".into());
    }
    let u32_at = |s: &[u8]| u32::from_le_bytes(s.try_into().expect("4 bytes")) as usize;
    let n = u32_at(take(4)?);
    let mut got = Vec::with_capacity(n.min(64));
    for _ in 0..n {
        got.push(u32_at(take(4)?));
    }
    if got != dims {
        return Err(format!(
            "the checkpoint's f_θ has layers {got:?}, the config asks for {dims:?}; restore [decay] inputs/hidden_* or start afresh"
        ));
    }
    let step = u64::from_le_bytes(take(8)?.try_into().expect("8 bytes"));
    let np = Mlp::<f32>::param_count(dims);
    let mut vecs = Vec::new();
    for _ in 0..3 {
        let s = take(4 * np)?;
        vecs.push(
            s.chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect::<Vec<f32>>(),
        );
    }
    let v = vecs.pop().expect("3");
    let m = vecs.pop().expect("2");
    let p = vecs.pop().expect("1");
    Ok((step, p, m, v))
}
