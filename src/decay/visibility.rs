//! Visibility `G_m = Z_V(view, centres, Z_T(t, G))` of every Gaussian at one (view, t)
//! (paper §3.3):
//! - `Z_T`: the temporal weight `ω(t) > 0.05` (the renderer's own temporal cut-off);
//! - `Z_V`: the time-sliced centre `μ(t)` lies in front of the near plane and (mode
//!   `frustum`) projects inside the image; mode `near_plane` keeps only the depth test,
//!   like the authors' code (which tests the canonical mean at `z > 0.2`).
//!
//! A pure function of the model and the view; it never edits the model.

use super::VisibilityMode;
use crate::Camera;
use crate::math::numerics::Real;
use crate::math::project::PinholeCamera;
use crate::math::slice::slice;
use crate::model::Gaussians;
use rayon::prelude::*;

/// `true` for each Gaussian of `model` visible from `camera` at model time `t`.
/// With [`VisibilityMode::Off`] every Gaussian counts as visible.
pub fn visible<F: Real>(
    model: &Gaussians<F>,
    camera: &Camera,
    t: F,
    mode: VisibilityMode,
    near: F,
) -> Vec<bool> {
    if mode == VisibilityMode::Off {
        return vec![true; model.len()];
    }
    let cam = PinholeCamera::<F>::from_camera(camera, near);
    let (w, h) = (F::c(cam.width as f64), F::c(cam.height as f64));
    (0..model.len())
        .into_par_iter()
        .map(|i| {
            let Some((s, _)) = slice(
                model.means[i],
                model.log_scales[i],
                model.rot_left[i],
                model.rot_right[i],
                t,
            ) else {
                return false; // Z_T: ω(t) ≤ 0.05
            };
            let p = cam.to_camera(s.mean);
            if !(p[2] > near) {
                return false;
            }
            if mode == VisibilityMode::NearPlane {
                return true;
            }
            let [u, v] = cam.to_pixel(p);
            u >= F::zero() && u < w && v >= F::zero() && v < h
        })
        .collect()
}
