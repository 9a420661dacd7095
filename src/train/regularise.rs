//! Shape constraints that keep splats honest when only a few cameras see them.
//!
//! With four cameras, a Gaussian can stretch into a long thin needle that matches a
//! training view's texture edge yet streaks across every other view. [`cap_anisotropy`]
//! projects each Gaussian back onto the set of shapes whose longest spatial axis is at
//! most `ratio` times its middle one: flat disks (the shape surfaces want) stay allowed,
//! needles are not. The projection keeps the product of the two axes (the disk's area),
//! so coverage is unchanged and only the shape is corrected.
//!
//! Dense point-map inits start every Gaussian as a round blob, and a few hundred steps do
//! not flatten them: a blob sitting on a wall spreads its colour over more of the wall the
//! more obliquely an unseen camera looks at it. [`add_flatten_gradient`] adds the gradient
//! of `weight · Σᵢ s_min,i / s_mid,i` (shortest over middle spatial scale), which pulls
//! each splat towards a disk in the surface; the photometric loss keeps the ones that
//! must stay round. The ratio is scale-free and its pull fades as a splat flattens.

use crate::model::Gaussians;
use crate::render::Gradients;

/// Add `d/d(log-scales)` of the flatness penalty `weight · Σᵢ s_min,i / s_mid,i` to
/// `grads` and return the penalty. `weight ≤ 0` (or non-finite) adds nothing.
pub fn add_flatten_gradient(
    model: &Gaussians<f32>,
    grads: &mut Gradients<f32>,
    weight: f64,
) -> f64 {
    if !(weight.is_finite() && weight > 0.0) {
        return 0.0;
    }
    let w = weight as f32;
    let mut penalty = 0.0f64;
    for (s, g) in model.log_scales.iter().zip(&mut grads.log_scales) {
        let (_, mid, low) = order3(s);
        // r = exp(log s_low − log s_mid): dr/dlog s_low = r, dr/dlog s_mid = −r.
        let r = (s[low] - s[mid]).exp();
        g[low] += w * r;
        g[mid] -= w * r;
        penalty += (w * r) as f64;
    }
    penalty
}

/// Indices of the largest, middle and smallest of the three spatial log-scales.
fn order3(s: &[f32; 4]) -> (usize, usize, usize) {
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
    (idx[0], idx[1], idx[2])
}

/// Limit every Gaussian's spatial anisotropy: the largest of its three spatial scales is
/// at most `ratio` × the middle one. Returns how many Gaussians were changed. `ratio ≤ 1`
/// or non-finite disables the cap (returns 0).
pub fn cap_anisotropy(model: &mut Gaussians<f32>, ratio: f64) -> usize {
    if !(ratio.is_finite() && ratio > 1.0) {
        return 0;
    }
    let limit = ratio.ln() as f32;
    let mut changed = 0;
    for s in &mut model.log_scales {
        let (hi, mid) = largest_two(s);
        let excess = s[hi] - s[mid] - limit;
        if excess > 0.0 {
            s[hi] -= 0.5 * excess;
            s[mid] += 0.5 * excess;
            changed += 1;
        }
    }
    changed
}

/// Indices of the largest and the second-largest of the three spatial log-scales.
fn largest_two(s: &[f32; 4]) -> (usize, usize) {
    let (hi, mid, _) = order3(s);
    (hi, mid)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{ColourDegrees, TimeMapping};

    fn model(scales: &[[f32; 4]]) -> Gaussians<f32> {
        let mut g = Gaussians::new(ColourDegrees::DC, TimeMapping::default());
        for s in scales {
            g.push([0.0; 4], *s, 0.0, [0.5; 3]);
        }
        g
    }

    #[test]
    fn needles_become_ribbons_disks_and_blobs_stay() {
        let needle = [2.0f32.ln(), 0.01f32.ln(), 0.01f32.ln(), 0.0];
        let disk = [1.0f32.ln(), 1.0f32.ln(), 0.001f32.ln(), 0.0];
        let blob = [0.1f32.ln(), 0.12f32.ln(), 0.09f32.ln(), 0.0];
        let mut g = model(&[needle, disk, blob]);
        assert_eq!(cap_anisotropy(&mut g, 10.0), 1);
        let s = g.log_scales[0].map(f64::from);
        // The long axis over the middle one is exactly the ratio now…
        assert!((s[0] - s[1] - 10f64.ln()).abs() < 1e-5, "{s:?}");
        // …the area (product of the two) is what it was, the thin axis is untouched,
        assert!((s[0] + s[1] - (2f64.ln() + 0.01f64.ln())).abs() < 1e-5);
        assert_eq!(g.log_scales[0][2], needle[2]);
        // and the time scale is never touched.
        assert_eq!(g.log_scales[0][3], 0.0);
        assert_eq!(g.log_scales[1], disk);
        assert_eq!(g.log_scales[2], blob);
    }

    #[test]
    fn any_axis_order_and_extreme_values_stay_finite() {
        let mut g = model(&[
            [-30.0, 10.0, -30.0, 1.0],
            [-30.0, -30.0, 20.0, -5.0],
            [5.0, 5.0, 5.0, 0.0],
        ]);
        assert_eq!(cap_anisotropy(&mut g, 4.0), 2);
        for s in &g.log_scales {
            assert!(s.iter().all(|v| v.is_finite()));
            let (hi, mid) = largest_two(s);
            assert!(s[hi] - s[mid] <= 4f32.ln() + 1e-4, "{s:?}");
        }
        // Disabled for a ratio of 1 or less.
        let before = g.clone();
        assert_eq!(cap_anisotropy(&mut g, 1.0), 0);
        assert_eq!(cap_anisotropy(&mut g, f64::NAN), 0);
        assert_eq!(g.log_scales, before.log_scales);
    }

    /// The penalty in f64 straight from its definition.
    fn penalty(model: &Gaussians<f32>, perturbed: Option<(usize, usize, f64)>) -> f64 {
        model
            .log_scales
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let mut v = s.map(f64::from);
                if let Some((j, axis, d)) = perturbed
                    && j == i
                {
                    v[axis] += d;
                }
                let mut e = [v[0].exp(), v[1].exp(), v[2].exp()];
                e.sort_by(f64::total_cmp);
                e[0] / e[1]
            })
            .sum()
    }

    #[test]
    fn flatten_gradient_matches_central_differences_and_leaves_the_rest() {
        let scales = [
            [0.3f32.ln(), 0.2f32.ln(), 0.1f32.ln(), 0.5],
            [-3.0, -2.0, -2.5, 0.0],
            [-9.0, 4.0, 1.0, -1.0],
            [0.0, -20.0, 0.5, 2.0],
        ];
        let g0 = model(&scales);
        let weight = 0.7;
        let mut grads = Gradients::zeros_like(&g0, false);
        grads.log_scales[1][3] = 0.25;
        let p = add_flatten_gradient(&g0, &mut grads, weight);
        assert!((p - weight * penalty(&g0, None)).abs() < 1e-6 * p.abs().max(1.0));
        let eps = 1e-4;
        for i in 0..scales.len() {
            for axis in 0..3 {
                let fd = weight
                    * (penalty(&g0, Some((i, axis, eps))) - penalty(&g0, Some((i, axis, -eps))))
                    / (2.0 * eps);
                let got = grads.log_scales[i][axis] as f64;
                assert!(
                    (fd - got).abs() < 1e-4 * fd.abs().max(1e-3),
                    "{i}/{axis}: fd {fd} vs {got}"
                );
            }
        }
        // The time scale keeps its gradient; every value is finite even at e^±20 scales.
        assert_eq!(grads.log_scales[1][3], 0.25);
        assert!(grads.log_scales.iter().flatten().all(|v| v.is_finite()));
        // Off at weight 0 (and for nonsense weights).
        let mut none = Gradients::zeros_like(&g0, false);
        assert_eq!(add_flatten_gradient(&g0, &mut none, 0.0), 0.0);
        assert_eq!(add_flatten_gradient(&g0, &mut none, f64::NAN), 0.0);
        assert!(none.log_scales.iter().flatten().all(|v| *v == 0.0));
    }
}
