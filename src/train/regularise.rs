//! Shape constraints that keep splats honest when only a few cameras see them.
//!
//! With four cameras, a Gaussian can stretch into a long thin needle that matches a
//! training view's texture edge yet streaks across every other view. [`cap_anisotropy`]
//! projects each Gaussian back onto the set of shapes whose longest spatial axis is at
//! most `ratio` times its middle one: flat disks (the shape surfaces want) stay allowed,
//! needles are not. The projection keeps the product of the two axes (the disk's area),
//! so coverage is unchanged and only the shape is corrected.

use crate::model::Gaussians;

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
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
    (idx[0], idx[1])
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
}
