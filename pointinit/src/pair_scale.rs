//! The scale of one pair's point maps, from the known poses: what puts the maps into the
//! world frame of the posed cameras.
//!
//! A MASt3R-style model returns both views' points in the first camera's frame at an
//! unknown scale `s`. The poses fix everything else: with `R, t` taking camera `a`'s frame
//! to camera `b`'s, a point `X` of the second view's map must lie on its pixel's ray in
//! camera `b`: `r × (s·R·X + t) = 0`. Each pixel gives a scale; their weighted median,
//! refined by least squares over the inliers, is the pair's scale ([`ray_scale`]). When
//! sparse COLMAP points exist, their depths in camera `a` against the map's depths give an
//! independent scale ([`sparse_scale`]) used as a check (or alone when the rays cannot fix
//! the scale, e.g. a zero baseline).
//!
//! This module does geometry only: which pixels are valid, and what to do with a pair
//! whose scale is rejected, is decided by the caller.

use glam::{DMat3, DVec2, DVec3};
use shared_types::Camera;

use super::npy::PointMap;

/// The transform from camera `a`'s frame to camera `b`'s: `x_b = rotation·x_a + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Relative {
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Relative {
    /// From two world-to-camera poses.
    pub fn between(a: &Camera, b: &Camera) -> Self {
        let (ra, ta) = (
            a.world_to_camera.rotation(),
            a.world_to_camera.translation(),
        );
        let (rb, tb) = (
            b.world_to_camera.rotation(),
            b.world_to_camera.translation(),
        );
        let rotation = rb * ra.transpose();
        Self {
            rotation,
            translation: tb - rotation * ta,
        }
    }
}

/// Scale found from the second view's rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayScale {
    pub scale: f64,
    /// Median reprojection error in camera `b` after scaling, as a fraction of the map width.
    pub residual: f64,
    /// Pixels within the inlier threshold.
    pub inliers: usize,
}

/// Pixel centre of index `i` in a `width`-wide map.
pub fn pixel_centre(i: usize, width: usize) -> DVec2 {
    DVec2::new((i % width) as f64 + 0.5, (i / width) as f64 + 0.5)
}

/// Weighted median of `(value, weight)` pairs (weights ≥ 0); `None` when empty.
pub fn weighted_median(mut v: Vec<(f64, f64)>) -> Option<f64> {
    v.retain(|(x, w)| x.is_finite() && w.is_finite() && *w > 0.0);
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = v.iter().map(|p| p.1).sum();
    let mut acc = 0.0;
    for (x, w) in &v {
        acc += w;
        if acc >= 0.5 * total {
            return Some(*x);
        }
    }
    v.last().map(|p| p.0)
}

/// Scale of the second view's map (`map`, valid pixels `valid`) given camera `b` (pinhole,
/// intrinsics at the map's size) and the relative pose `rel` from `a` to `b`.
/// `None` when the baseline is zero or too few pixels constrain the scale.
pub fn ray_scale(b: &Camera, rel: &Relative, map: &PointMap, valid: &[bool]) -> Option<RayScale> {
    let t = rel.translation;
    if t.length() < 1e-12 {
        return None;
    }
    let k = &b.intrinsics;
    // Per pixel: a = r × (R·X), c = r × t; the scale solving a·s + c = 0 in least squares.
    let terms = map
        .points
        .iter()
        .enumerate()
        .filter(|(i, _)| valid[*i])
        .map(|(i, p)| {
            let n = k.to_normalised(pixel_centre(i, map.width));
            let r = DVec3::new(n.x, n.y, 1.0).normalize();
            let x = rel.rotation * DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            (i, x, r.cross(x), r.cross(t))
        })
        .collect::<Vec<_>>();
    if terms.len() < 16 {
        return None;
    }
    let median = weighted_median(
        terms
            .iter()
            .map(|(_, _, a, c)| (-a.dot(*c) / a.length_squared(), a.length_squared()))
            .collect(),
    )?;
    if median <= 0.0 {
        return None;
    }
    let residual_px = |s: f64, i: usize, x: DVec3| -> f64 {
        let p = s * x + t;
        if p.z <= 1e-12 {
            return f64::INFINITY;
        }
        (k.to_pixels(DVec2::new(p.x / p.z, p.y / p.z)) - pixel_centre(i, map.width)).length()
    };
    let mut res = terms
        .iter()
        .map(|(i, x, ..)| residual_px(median, *i, *x))
        .collect::<Vec<_>>();
    let first_median = median_of(&mut res.clone())?;
    let threshold = (3.0 * first_median).max(2.0);
    let (mut num, mut den, mut inliers) = (0.0, 0.0, 0usize);
    for ((_, _, a, c), r) in terms.iter().zip(&res) {
        if *r < threshold {
            num -= a.dot(*c);
            den += a.length_squared();
            inliers += 1;
        }
    }
    let scale = if den > 0.0 { num / den } else { median };
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    res = terms
        .iter()
        .map(|(i, x, ..)| residual_px(scale, *i, *x))
        .collect();
    let residual = median_of(&mut res)? / map.width as f64;
    Some(RayScale {
        scale,
        residual,
        inliers,
    })
}

/// Median of finite and infinite values (`None` when empty).
fn median_of(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    Some(v[v.len() / 2])
}

/// Scale of the first view's map from sparse world points: the median over points seen in
/// camera `a` (pinhole, intrinsics at the map's size) of `depth / map depth` at their
/// pixel. Returns the scale and the number of points used; `None` with fewer than `min`.
pub fn sparse_scale(
    a: &Camera,
    map: &PointMap,
    valid: &[bool],
    sparse: &[DVec3],
    min: usize,
) -> Option<(f64, usize)> {
    let k = &a.intrinsics;
    let mut ratios = Vec::new();
    for p in sparse {
        let pc = a.world_to_camera.apply(*p);
        if pc.z <= 1e-9 {
            continue;
        }
        let px = k.to_pixels(DVec2::new(pc.x / pc.z, pc.y / pc.z));
        if !(px.x >= 0.0 && px.y >= 0.0) {
            continue;
        }
        let (x, y) = (px.x as usize, px.y as usize);
        if x >= map.width || y >= map.height {
            continue;
        }
        let i = y * map.width + x;
        let z = map.points[i][2] as f64;
        if valid[i] && z > 0.0 {
            ratios.push(pc.z / z);
        }
    }
    if ratios.len() < min.max(1) {
        return None;
    }
    let n = ratios.len();
    median_of(&mut ratios).map(|s| (s, n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib::test_support::looking_at;
    use shared_types::Intrinsics;

    fn camera(name: &str, eye: DVec3) -> Camera {
        looking_at(name, Intrinsics::from_hfov(40, 30, 60.0), eye, DVec3::ZERO)
    }

    /// Both views of a sphere-ish surface in camera a's frame, divided by `true_scale`.
    fn maps(a: &Camera, b: &Camera, true_scale: f64) -> (PointMap, PointMap) {
        let mk = |cam: &Camera| {
            let k = cam.intrinsics;
            let points = (0..(k.width * k.height) as usize)
                .map(|i| {
                    let ray = cam.pixel_ray(pixel_centre(i, k.width as usize));
                    let o = cam.world_to_camera.centre();
                    // hit the plane x·(1,1,1) = 0.3 (a slanted wall)
                    let n = DVec3::ONE.normalize();
                    let d = (0.3 - n.dot(o)) / n.dot(ray);
                    let pw = o + d * ray;
                    let pa = a.world_to_camera.apply(pw) / true_scale;
                    [pa.x as f32, pa.y as f32, pa.z as f32]
                })
                .collect();
            PointMap {
                width: k.width as usize,
                height: k.height as usize,
                points,
                confidence: None,
            }
        };
        (mk(a), mk(b))
    }

    #[test]
    fn ray_and_sparse_scales_recover_the_true_scale() {
        let a = camera("a", DVec3::new(3.0, -1.0, 1.0));
        let b = camera("b", DVec3::new(2.0, 2.5, 1.2));
        let (m1, m2) = maps(&a, &b, 2.5);
        let valid = vec![true; m1.points.len()];
        let rel = Relative::between(&a, &b);
        let fit = ray_scale(&b, &rel, &m2, &valid).unwrap();
        assert!((fit.scale / 2.5 - 1.0).abs() < 1e-9, "{fit:?}");
        assert!(fit.residual < 1e-5, "{fit:?}"); // f32 point maps
        // Sparse points: the world surface points seen by camera a.
        let sparse = m1
            .points
            .iter()
            .step_by(7)
            .map(|p| {
                a.world_to_camera
                    .inverse_apply(2.5 * DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            })
            .collect::<Vec<_>>();
        let (s, n) = sparse_scale(&a, &m1, &valid, &sparse, 5).unwrap();
        assert!((s / 2.5 - 1.0).abs() < 1e-6, "{s}");
        assert!(n > 100);
    }

    #[test]
    fn zero_baseline_has_no_ray_scale() {
        let a = camera("a", DVec3::new(3.0, -1.0, 1.0));
        let (m1, _) = maps(&a, &a, 1.0);
        let valid = vec![true; m1.points.len()];
        assert!(ray_scale(&a, &Relative::between(&a, &a), &m1, &valid).is_none());
    }

    #[test]
    fn weighted_median_ignores_nan_and_zero_weights() {
        let v = vec![
            (1.0, 1.0),
            (f64::NAN, 5.0),
            (2.0, 1.0),
            (100.0, 0.0),
            (3.0, 1.0),
        ];
        assert_eq!(weighted_median(v), Some(2.0));
        assert_eq!(weighted_median(vec![]), None);
    }
}
