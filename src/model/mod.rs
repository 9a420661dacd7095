//! The 4D Gaussian model in structure-of-arrays form, plus its time mapping and colour
//! layout. Pure data: no rendering here (see `render`); the file format is [`file`], the
//! initialisation from a point cloud [`init`].

pub mod file;
pub mod init;
pub mod motion;

use crate::math::numerics::Real;
use crate::math::sh::SH_C0;
use serde::{Deserialize, Serialize};

pub use crate::math::sh::{ColourDegrees, MAX_SPATIAL_DEGREE, MAX_TEMPORAL_DEGREE};

/// Maps capture time in seconds to the model's normalised time `t`.
/// `t = (seconds − start_seconds) · units_per_second`; `duration` is the sequence length `T`
/// in model units, the period used by the temporal colour basis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimeMapping {
    pub start_seconds: f64,
    pub units_per_second: f64,
    pub duration: f64,
}

impl TimeMapping {
    /// The 4DGS convention: `t = frame / 30` for a sequence of `duration_seconds` at `fps`.
    pub fn frames_over_30(start_seconds: f64, fps: f64, duration_seconds: f64) -> Self {
        let units_per_second = fps / 30.0;
        Self {
            start_seconds,
            units_per_second,
            duration: duration_seconds * units_per_second,
        }
    }

    /// Model time of a capture timestamp.
    pub fn model_time(&self, seconds: f64) -> f64 {
        (seconds - self.start_seconds) * self.units_per_second
    }

    /// Capture timestamp of a model time.
    pub fn seconds(&self, model_time: f64) -> f64 {
        model_time / self.units_per_second + self.start_seconds
    }
}

impl Default for TimeMapping {
    fn default() -> Self {
        Self {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 1.0,
        }
    }
}

/// N 4D Gaussians, structure of arrays. Index `i` of every array is Gaussian `i`.
///
/// Colour coefficients: `colours[(i * coeffs + k) * 3 + c]` for channel `c`, where the
/// coefficient index `k = j * spatial_count + s` runs over temporal basis `j` (outer) and
/// spatial SH basis `s` (inner), both up to the *capacity* degrees `capacity`.
/// `k = 0` is the DC term. Only `active` degrees are evaluated when rendering.
#[derive(Clone, Debug, PartialEq)]
pub struct Gaussians<F: Real = f32> {
    /// Mean `(x, y, z, t)`: world position and model time.
    pub means: Vec<[F; 4]>,
    /// Natural logarithms of the scales along the 4 rotated axes (`x, y, z, t`).
    pub log_scales: Vec<[F; 4]>,
    /// Left quaternion `(a, b, c, d)` of the 4D rotation `Ml(ql)·Mr(qr)`; need not be unit.
    pub rot_left: Vec<[F; 4]>,
    /// Right quaternion `(p, q, r, s)`; need not be unit.
    pub rot_right: Vec<[F; 4]>,
    /// Opacity logit (`opacity = sigmoid(logit)`).
    pub opacity_logits: Vec<F>,
    /// Colour coefficients, see the type docs for the layout.
    pub colours: Vec<F>,
    /// Degrees the colour storage has room for.
    pub capacity: ColourDegrees,
    /// Degrees used when rendering (≤ `capacity`; grown during training).
    pub active: ColourDegrees,
    /// Seconds → model time.
    pub time: TimeMapping,
}

impl<F: Real> Gaussians<F> {
    /// An empty model with room for colour of `capacity` degrees.
    pub fn new(capacity: ColourDegrees, time: TimeMapping) -> Self {
        Self {
            means: Vec::new(),
            log_scales: Vec::new(),
            rot_left: Vec::new(),
            rot_right: Vec::new(),
            opacity_logits: Vec::new(),
            colours: Vec::new(),
            capacity,
            active: ColourDegrees::DC,
            time,
        }
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Coefficients per channel per Gaussian in storage.
    pub fn coeffs_per_channel(&self) -> usize {
        self.capacity.coeff_count()
    }

    /// Append an isotropic-in-time Gaussian with identity rotations; `rgb` in `[0, 1]` sets the
    /// DC colour (other coefficients zero). Returns its index.
    pub fn push(
        &mut self,
        mean: [F; 4],
        log_scales: [F; 4],
        opacity_logit: F,
        rgb: [F; 3],
    ) -> usize {
        let id = [F::one(), F::zero(), F::zero(), F::zero()];
        self.means.push(mean);
        self.log_scales.push(log_scales);
        self.rot_left.push(id);
        self.rot_right.push(id);
        self.opacity_logits.push(opacity_logit);
        let k = self.coeffs_per_channel();
        let start = self.colours.len();
        self.colours.resize(start + 3 * k, F::zero());
        for c in 0..3 {
            self.colours[start + c] = (rgb[c] - F::c(0.5)) / F::c(SH_C0);
        }
        self.means.len() - 1
    }

    /// The colour coefficients of Gaussian `i` (`coeffs × 3`).
    pub fn colour_of(&self, i: usize) -> &[F] {
        let k = 3 * self.coeffs_per_channel();
        &self.colours[i * k..(i + 1) * k]
    }

    /// Checks that every array has the length the count and capacity imply.
    pub fn check_consistent(&self) -> Result<(), String> {
        let n = self.len();
        let k = 3 * self.coeffs_per_channel();
        let lens = [
            ("log_scales", self.log_scales.len(), n),
            ("rot_left", self.rot_left.len(), n),
            ("rot_right", self.rot_right.len(), n),
            ("opacity_logits", self.opacity_logits.len(), n),
            ("colours", self.colours.len(), n * k),
        ];
        for (name, got, want) in lens {
            if got != want {
                return Err(format!(
                    "{name} has {got} values, expected {want} for {n} Gaussians"
                ));
            }
        }
        if !self.capacity.is_valid() || !self.active.is_valid() {
            return Err(format!(
                "colour degrees out of range: {:?} / {:?}",
                self.capacity, self.active
            ));
        }
        Ok(())
    }

    /// Append `other`'s Gaussians after this model's (the same colour capacity; this
    /// model's time mapping and active degrees are kept).
    pub fn append(&mut self, other: &Gaussians<F>) {
        assert_eq!(
            self.capacity, other.capacity,
            "appending Gaussians of another colour capacity"
        );
        self.means.extend_from_slice(&other.means);
        self.log_scales.extend_from_slice(&other.log_scales);
        self.rot_left.extend_from_slice(&other.rot_left);
        self.rot_right.extend_from_slice(&other.rot_right);
        self.opacity_logits.extend_from_slice(&other.opacity_logits);
        self.colours.extend_from_slice(&other.colours);
    }

    /// The same model in another float type.
    pub fn cast<G: Real>(&self) -> Gaussians<G> {
        let v4 = |v: &Vec<[F; 4]>| v.iter().map(|a| a.map(|x| G::c(x.f64()))).collect();
        Gaussians {
            means: v4(&self.means),
            log_scales: v4(&self.log_scales),
            rot_left: v4(&self.rot_left),
            rot_right: v4(&self.rot_right),
            opacity_logits: self.opacity_logits.iter().map(|x| G::c(x.f64())).collect(),
            colours: self.colours.iter().map(|x| G::c(x.f64())).collect(),
            capacity: self.capacity,
            active: self.active,
            time: self.time,
        }
    }
}
