//! Comparing solved cameras with reference ones: the similarity transform (Umeyama 1991)
//! that best maps solved camera centres onto reference centres, and the rotation and
//! centre errors that remain after it.

use glam::{DMat3, DVec3};
use shared_types::Camera;

/// `x_ref ≈ scale · rotation · x + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Similarity {
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation * p) + self.translation
    }
}

/// Least-squares similarity from `src` to `dst` (same length, at least 3 non-collinear
/// points); `None` when degenerate.
pub fn umeyama(src: &[DVec3], dst: &[DVec3]) -> Option<Similarity> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let mu_s = src.iter().copied().sum::<DVec3>() / n as f64;
    let mu_d = dst.iter().copied().sum::<DVec3>() / n as f64;
    let var_s = src
        .iter()
        .map(|p| (*p - mu_s).length_squared())
        .sum::<f64>()
        / n as f64;
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let (s, d) = (*s - mu_s, *d - mu_d);
        cov += nalgebra::Vector3::new(d.x, d.y, d.z) * nalgebra::RowVector3::new(s.x, s.y, s.z);
    }
    cov /= n as f64;
    let svd = cov.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut sign = nalgebra::Matrix3::<f64>::identity();
    if (u * vt).determinant() < 0.0 {
        sign[(2, 2)] = -1.0;
    }
    let r = u * sign * vt;
    let trace_ds = (0..3)
        .map(|i| svd.singular_values[i] * sign[(i, i)])
        .sum::<f64>();
    if var_s < 1e-300 || !trace_ds.is_finite() {
        return None;
    }
    let scale = trace_ds / var_s;
    let rotation = to_dmat3(&r);
    let translation = mu_d - scale * (rotation * mu_s);
    Some(Similarity {
        scale,
        rotation,
        translation,
    })
}

/// Errors of one solved camera against its reference after alignment.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseError {
    pub name: String,
    /// Angle of the residual rotation, degrees.
    pub rotation_deg: f64,
    /// Distance between aligned and reference centres, in reference units.
    pub centre: f64,
}

/// Align `solved` to `reference` by their centres (matched by name) and measure each
/// camera's rotation and centre error. Also returns the reference rig radius (mean distance
/// of the reference centres from their mean) to express centre errors relative to it.
pub fn compare(
    solved: &[Camera],
    reference: &[Camera],
) -> Option<(Similarity, Vec<PoseError>, f64)> {
    let pairs: Vec<(&Camera, &Camera)> = solved
        .iter()
        .filter_map(|s| reference.iter().find(|r| r.name == s.name).map(|r| (s, r)))
        .collect();
    let src: Vec<DVec3> = pairs
        .iter()
        .map(|(s, _)| s.world_to_camera.centre())
        .collect();
    let dst: Vec<DVec3> = pairs
        .iter()
        .map(|(_, r)| r.world_to_camera.centre())
        .collect();
    let sim = umeyama(&src, &dst)?;
    let mean = dst.iter().copied().sum::<DVec3>() / dst.len() as f64;
    let radius = dst.iter().map(|c| (*c - mean).length()).sum::<f64>() / dst.len() as f64;
    let errors = pairs
        .iter()
        .map(|(s, r)| {
            // World-to-camera rotation in the reference frame: R_s · Sᵀ.
            let r_aligned = s.world_to_camera.rotation() * sim.rotation.transpose();
            let residual = r_aligned * r.world_to_camera.rotation().transpose();
            let cos = ((residual.x_axis.x + residual.y_axis.y + residual.z_axis.z - 1.0) / 2.0)
                .clamp(-1.0, 1.0);
            PoseError {
                name: s.name.clone(),
                rotation_deg: cos.acos().to_degrees(),
                centre: (sim.apply(s.world_to_camera.centre()) - r.world_to_camera.centre())
                    .length(),
            }
        })
        .collect();
    Some((sim, errors, radius))
}

/// A nalgebra 3×3 matrix (used for SVDs) as a glam matrix.
pub(crate) fn to_dmat3(m: &nalgebra::Matrix3<f64>) -> DMat3 {
    DMat3::from_cols_array(&[
        m[(0, 0)],
        m[(1, 0)],
        m[(2, 0)],
        m[(0, 1)],
        m[(1, 1)],
        m[(2, 1)],
        m[(0, 2)],
        m[(1, 2)],
        m[(2, 2)],
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::looking_at;
    use shared_types::{Intrinsics, WorldToCamera};

    #[test]
    fn recovers_a_known_similarity_and_zero_errors() {
        let rot = DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        let truth = Similarity {
            scale: 2.5,
            rotation: rot,
            translation: DVec3::new(1.0, -2.0, 0.5),
        };
        let intr = Intrinsics::from_hfov(64, 48, 60.0);
        let eyes = [
            DVec3::new(3.0, 0.0, 1.0),
            DVec3::new(0.0, 3.0, 1.5),
            DVec3::new(-3.0, 0.5, 1.0),
            DVec3::new(0.5, -3.0, 2.0),
        ];
        let reference: Vec<Camera> = eyes
            .iter()
            .enumerate()
            .map(|(i, &e)| looking_at(&format!("c{i}"), intr, e, DVec3::ZERO))
            .collect();
        // Solved = reference mapped by the inverse similarity: x_s = Rᵀ(x_r − t)/s.
        let solved: Vec<Camera> = reference
            .iter()
            .map(|c| {
                let r = c.world_to_camera.rotation() * rot;
                let centre = rot.transpose() * (c.world_to_camera.centre() - truth.translation)
                    / truth.scale;
                Camera {
                    world_to_camera: WorldToCamera::from_parts(r, -(r * centre)),
                    ..c.clone()
                }
            })
            .collect();
        let (sim, errors, radius) = compare(&solved, &reference).unwrap();
        assert!((sim.scale - 2.5).abs() < 1e-9);
        assert!((sim.rotation - rot).abs_diff_eq(DMat3::ZERO, 1e-9));
        assert!(radius > 2.0);
        for e in errors {
            assert!(e.rotation_deg < 1e-5 && e.centre < 1e-9, "{e:?}");
        }
    }
}
