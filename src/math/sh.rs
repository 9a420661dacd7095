//! "Spherindrical" colour: spatial spherical harmonics of the view
//! direction (camera → canonical mean) times temporal cosines `1, cos(2πΔt/T),
//! cos(4πΔt/T)` with `Δt = μt − t`. RGB = 0.5 + Σ coeff·Y·ψ, clamped at 0. Forward and
//! backward; the direction gradient is the analytic gradient of the basis.

use crate::math::numerics::{Real, normalise3, normalise3_backward};
use serde::{Deserialize, Serialize};

/// Highest spatial spherical-harmonic degree (16 basis functions).
pub const MAX_SPATIAL_DEGREE: u32 = 3;
/// Highest temporal degree: the basis is `1, cos(2πΔt/T), cos(4πΔt/T)`.
pub const MAX_TEMPORAL_DEGREE: u32 = 2;

/// Spatial and temporal degrees of the "spherindrical" colour basis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ColourDegrees {
    /// Spatial SH degree, 0..=3.
    pub spatial: u32,
    /// Temporal cosine degree, 0..=2.
    pub temporal: u32,
}

impl ColourDegrees {
    pub const DC: Self = Self {
        spatial: 0,
        temporal: 0,
    };
    pub const FULL: Self = Self {
        spatial: MAX_SPATIAL_DEGREE,
        temporal: MAX_TEMPORAL_DEGREE,
    };

    /// Number of spatial basis functions, `(spatial+1)²`.
    pub fn spatial_count(&self) -> usize {
        ((self.spatial + 1) * (self.spatial + 1)) as usize
    }

    /// Number of temporal basis functions, `temporal+1`.
    pub fn temporal_count(&self) -> usize {
        (self.temporal + 1) as usize
    }

    /// Coefficients per colour channel.
    pub fn coeff_count(&self) -> usize {
        self.spatial_count() * self.temporal_count()
    }

    pub fn is_valid(&self) -> bool {
        self.spatial <= MAX_SPATIAL_DEGREE && self.temporal <= MAX_TEMPORAL_DEGREE
    }

    /// Component-wise minimum.
    pub fn min(self, other: Self) -> Self {
        Self {
            spatial: self.spatial.min(other.spatial),
            temporal: self.temporal.min(other.temporal),
        }
    }
}

/// The degree-0 real spherical harmonic `1 / (2√π)`: a DC coefficient `c` gives colour
/// `0.5 + SH_C0 · c`.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;
const C1: f64 = 0.488_602_511_902_919_9;
const C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
const C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// The first `count` real SH basis functions (3DGS ordering and signs) at unit `(x,y,z)`.
fn basis<F: Real>(x: F, y: F, z: F, count: usize, out: &mut [F; 16]) {
    let c = F::c;
    out[0] = c(SH_C0);
    if count > 1 {
        out[1] = y * c(-C1);
        out[2] = z * c(C1);
        out[3] = x * c(-C1);
    }
    if count > 4 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        out[4] = x * y * c(C2[0]);
        out[5] = y * z * c(C2[1]);
        out[6] = (zz * c(2.0) - xx - yy) * c(C2[2]);
        out[7] = x * z * c(C2[3]);
        out[8] = (xx - yy) * c(C2[4]);
        if count > 9 {
            out[9] = y * (xx * c(3.0) - yy) * c(C3[0]);
            out[10] = x * y * z * c(C3[1]);
            out[11] = y * (zz * c(4.0) - xx - yy) * c(C3[2]);
            out[12] = z * (zz * c(2.0) - xx * c(3.0) - yy * c(3.0)) * c(C3[3]);
            out[13] = x * (zz * c(4.0) - xx - yy) * c(C3[4]);
            out[14] = z * (xx - yy) * c(C3[5]);
            out[15] = x * (xx - yy * c(3.0)) * c(C3[6]);
        }
    }
}

/// `Σₛ d_y[s] ∇Yₛ(x, y, z)` over the basis functions `1..count` (the analytic gradient
/// of [`basis`]; the direction is not renormalised here).
fn basis_grad<F: Real>(x: F, y: F, z: F, count: usize, d_y: &[F; 16]) -> [F; 3] {
    let c = F::c;
    let mut g = [F::zero(); 3];
    if count > 1 {
        g[1] -= d_y[1] * c(C1);
        g[2] += d_y[2] * c(C1);
        g[0] -= d_y[3] * c(C1);
    }
    if count > 4 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        let two = c(2.0);
        let mut add = |w: F, k: f64, d: [F; 3]| {
            let wk = w * c(k);
            g[0] += wk * d[0];
            g[1] += wk * d[1];
            g[2] += wk * d[2];
        };
        add(d_y[4], C2[0], [y, x, F::zero()]);
        add(d_y[5], C2[1], [F::zero(), z, y]);
        add(d_y[6], C2[2], [-two * x, -two * y, c(4.0) * z]);
        add(d_y[7], C2[3], [z, F::zero(), x]);
        add(d_y[8], C2[4], [two * x, -two * y, F::zero()]);
        if count > 9 {
            let (three, four, six, eight) = (c(3.0), c(4.0), c(6.0), c(8.0));
            add(d_y[9], C3[0], [six * x * y, three * (xx - yy), F::zero()]);
            add(d_y[10], C3[1], [y * z, x * z, x * y]);
            add(
                d_y[11],
                C3[2],
                [-two * x * y, four * zz - xx - three * yy, eight * y * z],
            );
            add(
                d_y[12],
                C3[3],
                [-six * x * z, -six * y * z, six * zz - three * (xx + yy)],
            );
            add(
                d_y[13],
                C3[4],
                [four * zz - three * xx - yy, -two * x * y, eight * x * z],
            );
            add(d_y[14], C3[5], [two * x * z, -two * y * z, xx - yy]);
            add(d_y[15], C3[6], [three * (xx - yy), -six * x * y, F::zero()]);
        }
    }
    g
}

/// Temporal basis `1, cos(2πΔt/T), cos(4πΔt/T)` and its derivative by `Δt`.
fn temporal<F: Real>(delta_t: F, period: F, count: usize) -> ([F; 3], [F; 3]) {
    let mut psi = [F::one(), F::zero(), F::zero()];
    let mut d = [F::zero(); 3];
    for j in 1..count {
        let w = F::c(2.0) * F::PI() * F::c(j as f64) / period;
        psi[j] = (w * delta_t).cos();
        d[j] = -(w * delta_t).sin() * w;
    }
    (psi, d)
}

/// Inputs of the colour stage for one Gaussian.
#[derive(Clone, Copy, Debug)]
pub struct ColourInput<'a, F> {
    /// Canonical (unsliced) mean `(x, y, z, t)`.
    pub mean: [F; 4],
    /// Colour coefficients, `capacity.coeff_count() × 3`.
    pub coeffs: &'a [F],
    pub capacity: ColourDegrees,
    pub active: ColourDegrees,
    /// Camera centre in world coordinates.
    pub camera_centre: [F; 3],
    /// Render time.
    pub t: F,
    /// Sequence duration `T` in model time (> 0).
    pub period: F,
}

/// RGB of one Gaussian seen from the camera at time t (each channel ≥ 0).
#[inline]
pub fn colour<F: Real>(input: &ColourInput<F>) -> [F; 3] {
    colour_and_mask(input).0
}

/// [`colour`] plus which channels were positive before the clamp at 0 (bit `c` set for
/// channel `c`): pass the mask to [`colour_backward_masked`] to skip recomputing the colour.
#[inline]
pub fn colour_and_mask<F: Real>(input: &ColourInput<F>) -> ([F; 3], u8) {
    let (rgb, _) = colour_raw(input);
    let mut mask = 0u8;
    for (c, v) in rgb.iter().enumerate() {
        if *v > F::zero() {
            mask |= 1 << c;
        }
    }
    (
        [
            rgb[0].max(F::zero()),
            rgb[1].max(F::zero()),
            rgb[2].max(F::zero()),
        ],
        mask,
    )
}

fn colour_raw<F: Real>(input: &ColourInput<F>) -> ([F; 3], ([F; 16], [F; 3])) {
    let active = input.active.min(input.capacity);
    let ns = active.spatial_count();
    let nt = active.temporal_count();
    let ns_cap = input.capacity.spatial_count();
    let m = input.mean;
    let (dir, _) = normalise3([
        m[0] - input.camera_centre[0],
        m[1] - input.camera_centre[1],
        m[2] - input.camera_centre[2],
    ]);
    let mut y = [F::zero(); 16];
    basis(dir[0], dir[1], dir[2], ns, &mut y);
    let (psi, _) = temporal(m[3] - input.t, input.period, nt);
    let mut rgb = [F::c(0.5); 3];
    for (j, &p) in psi.iter().enumerate().take(nt) {
        let row = &input.coeffs[j * ns_cap * 3..(j * ns_cap + ns) * 3];
        for (c3, &ys) in row.chunks_exact(3).zip(&y) {
            let w = ys * p;
            rgb[0] += c3[0] * w;
            rgb[1] += c3[1] * w;
            rgb[2] += c3[2] * w;
        }
    }
    (rgb, (y, psi))
}

/// Backward of [`colour`]: adds dL/dcoeffs into `d_coeffs` and returns dL/dmean (4).
pub fn colour_backward<F: Real>(
    input: &ColourInput<F>,
    d_rgb: [F; 3],
    d_coeffs: &mut [F],
) -> [F; 4] {
    let (_, mask) = colour_and_mask(input);
    colour_backward_masked(input, mask, d_rgb, d_coeffs)
}

/// [`colour_backward`] given the positive-channel mask from [`colour_and_mask`].
pub fn colour_backward_masked<F: Real>(
    input: &ColourInput<F>,
    mask: u8,
    d_rgb: [F; 3],
    d_coeffs: &mut [F],
) -> [F; 4] {
    let mut d_raw = [F::zero(); 3];
    for c in 0..3 {
        if mask & (1 << c) != 0 {
            d_raw[c] = d_rgb[c];
        }
    }
    let active = input.active.min(input.capacity);
    let ns = active.spatial_count();
    let nt = active.temporal_count();
    let ns_cap = input.capacity.spatial_count();
    let m = input.mean;
    let (dir, norm) = normalise3([
        m[0] - input.camera_centre[0],
        m[1] - input.camera_centre[1],
        m[2] - input.camera_centre[2],
    ]);
    let mut y = [F::zero(); 16];
    basis(dir[0], dir[1], dir[2], ns, &mut y);
    let (psi, d_psi_dt) = temporal(m[3] - input.t, input.period, nt);
    let mut d_y = [F::zero(); 16];
    let mut d_psi = [F::zero(); 3];
    for j in 0..nt {
        let (lo, hi) = (j * ns_cap * 3, (j * ns_cap + ns) * 3);
        let (row, d_row) = (&input.coeffs[lo..hi], &mut d_coeffs[lo..hi]);
        let p = psi[j];
        let mut dp = F::zero();
        for (s, (c3, d3)) in row
            .chunks_exact(3)
            .zip(d_row.chunks_exact_mut(3))
            .enumerate()
        {
            let w = y[s] * p;
            d3[0] += d_raw[0] * w;
            d3[1] += d_raw[1] * w;
            d3[2] += d_raw[2] * w;
            let dot = d_raw[0] * c3[0] + d_raw[1] * c3[1] + d_raw[2] * c3[2];
            d_y[s] += dot * p;
            dp += dot * y[s];
        }
        d_psi[j] += dp;
    }
    let mut d_mean = [F::zero(); 4];
    for j in 1..nt {
        d_mean[3] += d_psi[j] * d_psi_dt[j];
    }
    if ns > 1 {
        let d_dir = basis_grad(dir[0], dir[1], dir[2], ns, &d_y);
        let g = normalise3_backward(dir, norm, d_dir);
        d_mean[0] = g[0];
        d_mean[1] = g[1];
        d_mean[2] = g[2];
    }
    d_mean
}
