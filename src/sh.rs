//! "Spherindrical" colour (REFERENCE.md §1): spatial spherical harmonics of the view
//! direction (camera → canonical mean) times temporal cosines `1, cos(2πΔt/T),
//! cos(4πΔt/T)` with `Δt = μt − t`. RGB = 0.5 + Σ coeff·Y·ψ, clamped at 0. Forward and
//! backward; the direction gradient uses forward-mode dual numbers over the basis.

use crate::model::ColourDegrees;
use crate::numerics::{Real, normalise3, normalise3_backward};
use std::ops::{Add, Mul, Sub};

const C0: f64 = 0.282_094_791_773_878_14;
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

/// Scalars the basis can be evaluated in: plain floats and dual numbers.
trait Arith<F>:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Mul<F, Output = Self>
{
}
impl<F: Real> Arith<F> for F {}

/// A value and its gradient with respect to the direction `(x, y, z)`.
#[derive(Clone, Copy, Debug)]
struct Dual<F> {
    v: F,
    d: [F; 3],
}
impl<F: Real> Add for Dual<F> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Dual {
            v: self.v + o.v,
            d: [self.d[0] + o.d[0], self.d[1] + o.d[1], self.d[2] + o.d[2]],
        }
    }
}
impl<F: Real> Sub for Dual<F> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Dual {
            v: self.v - o.v,
            d: [self.d[0] - o.d[0], self.d[1] - o.d[1], self.d[2] - o.d[2]],
        }
    }
}
impl<F: Real> Mul for Dual<F> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        Dual {
            v: self.v * o.v,
            d: [
                self.d[0] * o.v + self.v * o.d[0],
                self.d[1] * o.v + self.v * o.d[1],
                self.d[2] * o.v + self.v * o.d[2],
            ],
        }
    }
}
impl<F: Real> Mul<F> for Dual<F> {
    type Output = Self;
    fn mul(self, s: F) -> Self {
        Dual {
            v: self.v * s,
            d: [self.d[0] * s, self.d[1] * s, self.d[2] * s],
        }
    }
}
impl<F: Real> Arith<F> for Dual<F> {}

/// The first `count` real SH basis functions (3DGS ordering and signs) at unit `(x,y,z)`.
fn basis<F: Real, T: Arith<F>>(x: T, y: T, z: T, one: T, count: usize, out: &mut [T; 16]) {
    let c = F::c;
    out[0] = one * c(C0);
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
    let (rgb, _) = colour_raw(input);
    [
        rgb[0].max(F::zero()),
        rgb[1].max(F::zero()),
        rgb[2].max(F::zero()),
    ]
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
    basis::<F, F>(dir[0], dir[1], dir[2], F::one(), ns, &mut y);
    let (psi, _) = temporal(m[3] - input.t, input.period, nt);
    let mut rgb = [F::c(0.5); 3];
    for j in 0..nt {
        for s in 0..ns {
            let w = y[s] * psi[j];
            let base = (j * ns_cap + s) * 3;
            for c in 0..3 {
                rgb[c] += input.coeffs[base + c] * w;
            }
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
    let (rgb, (y, psi)) = colour_raw(input);
    let mut d_raw = [F::zero(); 3];
    for c in 0..3 {
        if rgb[c] > F::zero() {
            d_raw[c] = d_rgb[c];
        }
    }
    let active = input.active.min(input.capacity);
    let ns = active.spatial_count();
    let nt = active.temporal_count();
    let ns_cap = input.capacity.spatial_count();
    let mut d_y = [F::zero(); 16];
    let mut d_psi = [F::zero(); 3];
    for j in 0..nt {
        for s in 0..ns {
            let base = (j * ns_cap + s) * 3;
            let mut dot = F::zero();
            for c in 0..3 {
                d_coeffs[base + c] += d_raw[c] * y[s] * psi[j];
                dot += d_raw[c] * input.coeffs[base + c];
            }
            d_y[s] += dot * psi[j];
            d_psi[j] += dot * y[s];
        }
    }
    let m = input.mean;
    let mut d_mean = [F::zero(); 4];
    let (_, d_psi_dt) = temporal(m[3] - input.t, input.period, nt);
    for j in 1..nt {
        d_mean[3] += d_psi[j] * d_psi_dt[j];
    }
    if ns > 1 {
        let (dir, norm) = normalise3([
            m[0] - input.camera_centre[0],
            m[1] - input.camera_centre[1],
            m[2] - input.camera_centre[2],
        ]);
        let z = F::zero();
        let o = F::one();
        let dx = Dual {
            v: dir[0],
            d: [o, z, z],
        };
        let dy = Dual {
            v: dir[1],
            d: [z, o, z],
        };
        let dz = Dual {
            v: dir[2],
            d: [z, z, o],
        };
        let mut yd = [Dual { v: z, d: [z; 3] }; 16];
        basis::<F, Dual<F>>(dx, dy, dz, Dual { v: o, d: [z; 3] }, ns, &mut yd);
        let mut d_dir = [F::zero(); 3];
        for s in 1..ns {
            for a in 0..3 {
                d_dir[a] += d_y[s] * yd[s].d[a];
            }
        }
        let g = normalise3_backward(dir, norm, d_dir);
        d_mean[0] = g[0];
        d_mean[1] = g[1];
        d_mean[2] = g[2];
    }
    d_mean
}
