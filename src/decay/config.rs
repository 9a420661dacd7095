//! The decay's settings: the `[decay]` section ([`DecayConfig`] and its enums).

use serde::{Deserialize, Serialize};

/// Which decay runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DecayVariant {
    /// No decay: plain 4DGS.
    None,
    /// Stored opacity × `constant` per step (Binocular3DGS).
    Constant,
    /// Stored opacity × `pow_factor(o)` per step.
    Pow,
    /// Stored opacity × `exp_factor(o)` per step.
    Exp,
    /// The Neural Decaying Function f_θ (4C4D).
    Neural,
}

/// The visibility test `Z_V` (`Z_T` is always part of it unless `off`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VisibilityMode {
    /// No visibility detection: every Gaussian gets the variant's decay (no β).
    Off,
    /// `Z_T` and the sliced centre in front of the near plane (like the authors' code).
    NearPlane,
    /// `Z_T` and the sliced centre in front of the near plane and inside the image.
    Frustum,
}

/// f_θ's inputs, see [`super::inputs`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DecayInputs {
    /// `(x, y, z, 2o−1, ql, qr)` as in the paper (12 values).
    Paper,
    /// `(2o−1, x, y, z, t, 4 log-scales)` as in the authors' code (9 values).
    Official,
}

/// The `[decay]` settings (TOML-friendly; unknown keys are rejected).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DecayConfig {
    pub variant: DecayVariant,
    pub visibility: VisibilityMode,
    /// Near plane of the visibility test (world units of camera depth).
    pub near: f64,
    /// Per-step factor of invisible Gaussians (1 reproduces the authors' code).
    pub beta: f64,
    /// Range of τ (and of the `pow`/`exp` factors).
    pub f_min: f64,
    pub f_max: f64,
    /// Per-step factor of the `constant` variant.
    pub constant: f64,
    /// Exponent γ of the `pow` variant.
    pub pow_gamma: f64,
    /// Scale κ of the `exp` variant.
    pub exp_kappa: f64,
    pub inputs: DecayInputs,
    /// Hidden layers of f_θ and their width.
    pub hidden_layers: usize,
    pub hidden_width: usize,
    /// f_θ's Adam learning rate and L2 weight decay.
    pub lr: f64,
    pub weight_decay: f64,
    /// Decay starts after this many optimiser steps.
    pub warmup: u64,
    /// Seed of f_θ's initial weights.
    pub seed: u64,
}

impl Default for DecayConfig {
    fn default() -> Self {
        Self {
            variant: DecayVariant::Constant,
            visibility: VisibilityMode::Frustum,
            near: 0.2,
            beta: 0.999,
            f_min: 0.996,
            f_max: 0.998,
            constant: 0.995,
            pow_gamma: 0.5,
            exp_kappa: 0.1,
            inputs: DecayInputs::Official,
            hidden_layers: 2,
            hidden_width: 32,
            lr: 1e-5,
            weight_decay: 1e-4,
            warmup: 500,
            seed: 0,
        }
    }
}

/// A `[decay]` setting out of range.
#[derive(Debug, thiserror::Error)]
#[error("invalid [decay] setting: {0}")]
pub struct DecayConfigError(pub String);

impl DecayConfig {
    /// Plain 4DGS.
    pub fn none() -> Self {
        Self {
            variant: DecayVariant::None,
            ..Default::default()
        }
    }

    /// The Neural Decaying Function f_θ with the other settings at their defaults.
    pub fn neural() -> Self {
        Self {
            variant: DecayVariant::Neural,
            ..Default::default()
        }
    }

    /// Checks every setting; the message names the key and its valid range.
    pub fn validate(&self) -> Result<(), DecayConfigError> {
        let bad = |s: String| Err(DecayConfigError(s));
        let unit = |x: f64| x > 0.0 && x <= 1.0;
        if !unit(self.beta) {
            return bad(format!("beta = {} must be in (0, 1]", self.beta));
        }
        if !(unit(self.f_min) && unit(self.f_max) && self.f_min <= self.f_max) {
            return bad(format!(
                "f_min = {}, f_max = {} must satisfy 0 < f_min ≤ f_max ≤ 1",
                self.f_min, self.f_max
            ));
        }
        if !unit(self.constant) {
            return bad(format!("constant = {} must be in (0, 1]", self.constant));
        }
        if !(self.pow_gamma > 0.0 && self.pow_gamma.is_finite()) {
            return bad(format!("pow_gamma = {} must be > 0", self.pow_gamma));
        }
        if !(self.exp_kappa > 0.0 && self.exp_kappa.is_finite()) {
            return bad(format!("exp_kappa = {} must be > 0", self.exp_kappa));
        }
        if !(self.near >= 0.0 && self.near.is_finite()) {
            return bad(format!("near = {} must be ≥ 0", self.near));
        }
        if self.hidden_width == 0 || self.hidden_width > 4096 || self.hidden_layers > 16 {
            return bad(format!(
                "hidden_layers = {} (≤ 16) and hidden_width = {} (1..=4096)",
                self.hidden_layers, self.hidden_width
            ));
        }
        if !(self.lr >= 0.0 && self.lr.is_finite() && self.weight_decay >= 0.0) {
            return bad("lr and weight_decay must be finite and ≥ 0".into());
        }
        Ok(())
    }

    /// Layer widths of f_θ: inputs, hidden layers, 1.
    pub fn mlp_dims(&self) -> Vec<usize> {
        let mut d = vec![self.inputs.width()];
        d.extend(std::iter::repeat_n(self.hidden_width, self.hidden_layers));
        d.push(1);
        d
    }

    /// The rows of the paper's ablation (Tab. 2–3) plus the input choice, as
    /// `(label, config)`: none, constant, pow, exp, neural w/o visibility, neural
    /// (official inputs), neural (paper inputs). Other settings are the defaults.
    pub fn variants_for_ablation() -> Vec<(String, DecayConfig)> {
        let with = |variant, visibility, inputs| DecayConfig {
            variant,
            visibility,
            inputs,
            ..Default::default()
        };
        use DecayInputs::*;
        use DecayVariant::*;
        use VisibilityMode::*;
        vec![
            ("none".into(), with(None, Frustum, Official)),
            ("constant".into(), with(Constant, Frustum, Official)),
            ("pow".into(), with(Pow, Frustum, Official)),
            ("exp".into(), with(Exp, Frustum, Official)),
            ("neural w/o vis".into(), with(Neural, Off, Official)),
            (
                "neural (official inputs)".into(),
                with(Neural, Frustum, Official),
            ),
            ("neural (paper inputs)".into(), with(Neural, Frustum, Paper)),
        ]
    }
}
