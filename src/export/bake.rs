//! Baking a 4D model into static 3D Gaussians at one time `t`: the
//! conditional mean and covariance of each slice, the covariance split into scale and
//! rotation by eigen-decomposition, opacity × temporal weight, and the temporal cosine
//! terms of the colour folded into the spatial SH coefficients. Gaussians that cannot
//! contribute at `t` (culled by the temporal cutoff, or opacity below `min_opacity`) are
//! dropped. Pure computation, no file IO.

use crate::math::numerics::{MIN_TIME_VARIANCE, logit, scale_from_log, sigmoid};
use crate::math::rotation4d::rotation;
use crate::math::slice::slice;
use crate::model::Gaussians;
use glam::{DMat3, DQuat};
use rayon::prelude::*;

/// Spatial SH coefficients per channel at degree 3.
pub const SH_COEFFS: usize = 16;

/// Smallest variance given to a (nearly) flat axis of a slice; its log-scale is
/// `½·ln(MIN_VARIANCE) = −18`, the engine's lower log-scale clamp.
pub const MIN_VARIANCE: f64 = 2.319_522_830_243_569e-16;

/// One static 3D Gaussian, the content of a 3DGS PLY row.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splat3d {
    pub position: [f32; 3],
    /// Spatial SH coefficients `sh[s][c]` (3DGS basis order; `s = 0` is DC). Coefficients
    /// above the model's active spatial degree are zero.
    pub sh: [[f32; 3]; SH_COEFFS],
    /// Opacity logit (already multiplied by the temporal weight).
    pub opacity_logit: f32,
    /// Natural log of the standard deviations along the rotated axes.
    pub log_scale: [f32; 3],
    /// Unit quaternion `(w, x, y, z)`, `w ≥ 0`; its rotation matrix has the axes as columns.
    pub rotation: [f32; 4],
}

/// The 3D Gaussians of one time step.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame3d {
    /// Model time of the slice.
    pub t: f64,
    pub splats: Vec<Splat3d>,
    /// Gaussians of the model that were dropped (culled in time or transparent).
    pub dropped: usize,
    /// Spatial SH degree that carries data (the model's active degree).
    pub sh_degree: u32,
}

/// The temporal colour period `T` the renderer uses (duration, or 1 if not positive).
pub fn colour_period(model: &Gaussians<f32>) -> f64 {
    let d = model.time.duration;
    if d.is_finite() && d > 0.0 { d } else { 1.0 }
}

/// Spatial SH coefficients of Gaussian `i` at time `t`: `Σ_j c[j][s] · cos(2πj(μt−t)/T)`
/// over the active temporal degrees (the spherindrical colour with time fixed).
pub fn folded_sh(model: &Gaussians<f32>, i: usize, t: f64) -> [[f32; 3]; SH_COEFFS] {
    let active = model.active.min(model.capacity);
    let ns = active.spatial_count();
    let ns_cap = model.capacity.spatial_count();
    let coeffs = model.colour_of(i);
    let dt = model.means[i][3] as f64 - t;
    let period = colour_period(model);
    let nt = active.temporal_count();
    let psi: [f64; 3] =
        std::array::from_fn(|j| (2.0 * std::f64::consts::PI * j as f64 * dt / period).cos());
    let mut out = [[0f32; 3]; SH_COEFFS];
    for s in 0..ns {
        let mut acc = [0f64; 3];
        for j in 0..nt {
            for c in 0..3 {
                acc[c] += coeffs[(j * ns_cap + s) * 3 + c] as f64 * psi[j];
            }
        }
        out[s] = acc.map(|v| v as f32);
    }
    out
}

/// Scale (log σ) and rotation `(w, x, y, z)` of a symmetric 3×3 covariance.
pub fn covariance_to_scale_rotation(cov: [[f64; 3]; 3]) -> ([f64; 3], [f64; 4]) {
    let m = nalgebra::Matrix3::from_fn(|r, c| 0.5 * (cov[r][c] + cov[c][r]));
    let eig = nalgebra::SymmetricEigen::new(m);
    let mut v = eig.eigenvectors;
    if v.determinant() < 0.0 {
        v.column_mut(2).neg_mut();
    }
    let log_scale = [0, 1, 2].map(|k| {
        let var = eig.eigenvalues[k];
        let var = if var.is_finite() {
            var.max(MIN_VARIANCE)
        } else {
            MIN_VARIANCE
        };
        0.5 * var.ln()
    });
    let col = |k: usize| glam::DVec3::new(v[(0, k)], v[(1, k)], v[(2, k)]);
    let mut q = DQuat::from_mat3(&DMat3::from_cols(col(0), col(1), col(2))).normalize();
    if q.w < 0.0 {
        q = -q;
    }
    (log_scale, [q.w, q.x, q.y, q.z])
}

/// Slice every Gaussian at `t` into a static 3D Gaussian; drop those with temporal weight
/// at or below the renderer's cutoff or with `opacity · ω < min_opacity`.
pub fn bake_frame(model: &Gaussians<f32>, t: f64, min_opacity: f64) -> Frame3d {
    let splats: Vec<Splat3d> = bake_rows(model, t, min_opacity)
        .into_iter()
        .flatten()
        .collect();
    Frame3d {
        t,
        dropped: model.len() - splats.len(),
        splats,
        sh_degree: model.active.min(model.capacity).spatial,
    }
}

/// Every Gaussian of the model sliced at `t`, in model order: `None` where
/// [`bake_frame`] drops it. The browser viewer keeps one row per Gaussian across frames.
pub fn bake_rows(model: &Gaussians<f32>, t: f64, min_opacity: f64) -> Vec<Option<Splat3d>> {
    (0..model.len())
        .into_par_iter()
        .with_min_len(512)
        .map(|i| bake_one(model, i, t, min_opacity))
        .collect()
}

fn bake_one(model: &Gaussians<f32>, i: usize, t: f64, min_opacity: f64) -> Option<Splat3d> {
    let f = |a: [f32; 4]| a.map(|x| x as f64);
    let (sl, _) = slice::<f64>(
        f(model.means[i]),
        f(model.log_scales[i]),
        f(model.rot_left[i]),
        f(model.rot_right[i]),
        t,
    )?;
    let opacity = sigmoid(model.opacity_logits[i] as f64) * sl.omega;
    if !(opacity >= min_opacity) || !sl.mean.iter().all(|m| m.is_finite()) {
        return None;
    }
    let b = sl.factor;
    let mut cov = [[0f64; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            cov[r][c] = (0..4).map(|k| b[r][k] * b[c][k]).sum();
        }
    }
    let (log_scale, rot) = covariance_to_scale_rotation(cov);
    Some(Splat3d {
        position: sl.mean.map(|v| v as f32),
        sh: folded_sh(model, i, t),
        opacity_logit: logit(opacity) as f32,
        log_scale: log_scale.map(|v| v as f32),
        rotation: rot.map(|v| v as f32),
    })
}

/// Linear motion form of Gaussian `i` (the conditional mean is exactly linear in t):
/// `(μ_xyz, velocity = Σ12/Σ44, Σ44, 3×3 conditional covariance)`.
pub fn linear_motion(model: &Gaussians<f32>, i: usize) -> ([f64; 3], [f64; 3], f64, [[f64; 3]; 3]) {
    let f = |a: [f32; 4]| a.map(|x| x as f64);
    let (r, _) = rotation(f(model.rot_left[i]), f(model.rot_right[i]));
    let s = f(model.log_scales[i]).map(|v| scale_from_log(v).0);
    let l: [[f64; 4]; 4] = std::array::from_fn(|a| std::array::from_fn(|k| r[a][k] * s[k]));
    let s44 = (0..4)
        .map(|k| l[3][k] * l[3][k])
        .sum::<f64>()
        .max(MIN_TIME_VARIANCE);
    let s12: [f64; 3] = std::array::from_fn(|a| (0..4).map(|k| l[a][k] * l[3][k]).sum());
    let mut cov = [[0f64; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            let s11: f64 = (0..4).map(|k| l[a][k] * l[b][k]).sum();
            cov[a][b] = s11 - s12[a] * s12[b] / s44;
        }
    }
    let m = f(model.means[i]);
    ([m[0], m[1], m[2]], s12.map(|v| v / s44), s44, cov)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen_split_reconstructs_the_covariance() {
        let cov = [[2.0, 0.3, -0.1], [0.3, 1.0, 0.2], [-0.1, 0.2, 0.5]];
        let (ls, q) = covariance_to_scale_rotation(cov);
        let r = DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]));
        let s = DMat3::from_diagonal(glam::DVec3::from_array(ls.map(|v| (2.0 * v).exp())));
        let back = r * s * r.transpose();
        for a in 0..3 {
            for b in 0..3 {
                assert!((back.col(b)[a] - cov[a][b]).abs() < 1e-12);
            }
        }
        assert!(q[0] >= 0.0);
    }
}
