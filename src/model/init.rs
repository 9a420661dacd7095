//! Initial Gaussians from a point cloud (`xyz`, `rgb`, optional time): isotropic spatial
//! scales from the mean squared distance to the 3 nearest neighbours (a k-d tree), time
//! uniform over the sequence when the cloud has none, opacity 0.1, DC colour from rgb;
//! temporal σ `time_scale_fraction` × the duration, at least a static point's time span, at
//! most a third of the time between moments for a point seen at one moment.
//! With `flatness > 0`, points on a locally planar patch of the cloud start as disks in
//! that plane (normal from the principal axes of their 10 nearest neighbours) instead of
//! balls: dense point-map clouds sample surfaces, and a ball on a wall smears its colour
//! over the wall in views the training cameras never saw. With `velocity`, points of
//! moving objects start moving as the neighbouring moments show ([`super::motion`]).

use super::motion::{moment_spacing, moment_velocities, moving_gaussian};
use crate::math::numerics::logit;
use crate::model::{ColourDegrees, Gaussians, TimeMapping};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZero;

pub use shared_types::PointCloud;

/// Longest temporal σ of a point seen at one moment, as a fraction of the time between the
/// cloud's moments.
const MOMENT_LIFETIME: f64 = 1.0 / 3.0;

/// Why a point cloud cannot seed a model.
#[derive(Debug, thiserror::Error)]
pub enum SeedError {
    #[error("the point cloud is empty; run the `init` stage (or give COLMAP points) first")]
    Empty,
    #[error("the point cloud has {xyz} positions but {other} {what}; rewrite points.ply")]
    LengthMismatch {
        xyz: usize,
        other: usize,
        what: &'static str,
    },
    #[error("point {index} has a non-finite coordinate or time; clean points.ply")]
    NonFinite { index: usize },
}

/// Parameters of the initialisation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InitOptions {
    /// Initial opacity of every Gaussian.
    pub opacity: f64,
    /// Initial temporal standard deviation as a fraction of the sequence duration.
    pub time_scale_fraction: f64,
    /// Colour storage of the model.
    pub capacity: ColourDegrees,
    /// Seed of the uniform times drawn when the cloud has none.
    pub seed: u64,
    /// Thickness of the initial disks as a fraction of their radius (0: balls, as 3DGS).
    pub flatness: f64,
    /// Moving points (time span 0) start with the velocity of their nearest moving points
    /// at the neighbouring moments ([`super::motion`]).
    pub velocity: bool,
}

impl Default for InitOptions {
    fn default() -> Self {
        Self {
            opacity: 0.1,
            time_scale_fraction: 0.2,
            capacity: ColourDegrees::FULL,
            seed: 0,
            flatness: 0.0,
            velocity: false,
        }
    }
}

/// Build the initial model from `cloud` for a sequence described by `time`.
pub fn gaussians_from_points(
    cloud: &PointCloud,
    time: TimeMapping,
    options: &InitOptions,
) -> Result<Gaussians<f32>, SeedError> {
    let n = cloud.xyz.len();
    if n == 0 {
        return Err(SeedError::Empty);
    }
    if cloud.rgb.len() != n {
        return Err(SeedError::LengthMismatch {
            xyz: n,
            other: cloud.rgb.len(),
            what: "colours",
        });
    }
    if let Some(t) = &cloud.time
        && t.len() != n
    {
        return Err(SeedError::LengthMismatch {
            xyz: n,
            other: t.len(),
            what: "times",
        });
    }
    if let Some(s) = &cloud.time_span
        && s.len() != n
    {
        return Err(SeedError::LengthMismatch {
            xyz: n,
            other: s.len(),
            what: "time spans",
        });
    }
    for (i, p) in cloud.xyz.iter().enumerate() {
        let t_ok = cloud.time.as_ref().is_none_or(|t| t[i].is_finite());
        let span_ok = cloud
            .time_span
            .as_ref()
            .is_none_or(|s| s[i].is_finite() && s[i] >= 0.0);
        if !p.iter().all(|v| v.is_finite()) || !t_ok || !span_ok {
            return Err(SeedError::NonFinite { index: i });
        }
    }
    let scales = nearest_neighbour_scales(&cloud.xyz);
    let normals = if options.flatness > 0.0 {
        surface_normals(&cloud.xyz)
    } else {
        vec![None; n]
    };
    let thin = (options.flatness.clamp(1e-4, 1.0) as f32).ln();
    let duration = if time.duration.is_finite() && time.duration > 0.0 {
        time.duration
    } else {
        1.0
    };
    let sigma_t = (duration * options.time_scale_fraction).max(1e-6);
    // Moments closer than 2 % of the clip are one moment. A point seen at one moment lives
    // around it: at most a third of the time to the next moment, so that neighbouring
    // moments' copies of a moving object do not overlap into ghosts.
    let min_gap = 0.02 * duration as f32;
    let sigma_moving = match (&cloud.time, &cloud.time_span) {
        (Some(t), Some(span)) => moment_spacing(t, span, min_gap).map_or(sigma_t, |gap| {
            sigma_t.min(MOMENT_LIFETIME * gap as f64).max(1e-6)
        }),
        _ => sigma_t,
    };
    let velocities = match (&cloud.time, &cloud.time_span) {
        (Some(t), Some(span)) if options.velocity => {
            moment_velocities(&cloud.xyz, t, span, min_gap)
        }
        _ => vec![None; n],
    };
    let logit_o = logit(options.opacity) as f32;
    let mut model = Gaussians::new(options.capacity, time);
    let mut rng = SplitMix(options.seed ^ 0x5EED_1417);
    for i in 0..n {
        let t = match &cloud.time {
            Some(t) => t[i],
            None => (rng.uniform() * duration) as f32,
        };
        let [x, y, z] = cloud.xyz[i];
        let s = scales[i].ln();
        let rgb = cloud.rgb[i].map(|c| c as f32 / 255.0);
        // A point seen over a span of the clip (static) lives at least that long.
        let span = cloud.time_span.as_ref().map_or(0.0, |s| s[i] as f64);
        let sigma = if cloud.time_span.is_some() && span == 0.0 {
            sigma_moving
        } else {
            sigma_t
        };
        let log_t = sigma.max(span).ln() as f32;
        let i_new = model.push([x, y, z, t], [s, s, s, log_t], logit_o, rgb);
        if let Some(normal) = normals[i] {
            // The disk's thin axis (local z) along the normal: ql = qr = q rotates in 3D.
            let q = glam::Quat::from_rotation_arc(glam::Vec3::Z, glam::Vec3::from(normal));
            let q = [q.w, q.x, q.y, q.z];
            model.log_scales[i_new][2] = s + thin;
            model.rot_left[i_new] = q;
            model.rot_right[i_new] = q;
        }
        if let Some(v) = velocities[i] {
            let ls = model.log_scales[i_new];
            let (log_scales, ql, qr) =
                moving_gaussian([ls[0], ls[1], ls[2]], model.rot_left[i_new], log_t, v);
            model.log_scales[i_new] = log_scales;
            model.rot_left[i_new] = ql;
            model.rot_right[i_new] = qr;
        }
    }
    Ok(model)
}

/// Root of the mean squared distance to the 3 nearest other points (3DGS), floored at
/// 1e-7 so coincident points still get a usable scale.
pub fn nearest_neighbour_scales(xyz: &[[f32; 3]]) -> Vec<f32> {
    if xyz.len() < 2 {
        return vec![0.01; xyz.len()];
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(xyz);
    let k = 4.min(xyz.len());
    let want = NonZero::new(k).unwrap_or(NonZero::<usize>::MIN);
    xyz.iter()
        .map(|p| {
            let nn = tree.nearest_n::<SquaredEuclidean>(p, want);
            // The query point itself is among the results (distance 0): skip one zero.
            let mut dists: Vec<f32> = nn.iter().map(|n| n.distance).collect();
            dists.sort_by(f32::total_cmp);
            let others = &dists[1..];
            let mean = others.iter().sum::<f32>() / others.len() as f32;
            mean.max(1e-14).sqrt().max(1e-7)
        })
        .collect()
}

/// Unit normal of each point's neighbourhood (its 10 nearest points, itself included):
/// the principal axis of least spread, where that spread is under a quarter of the middle
/// one (a planar patch); `None` elsewhere (edges, corners, lines, sparse points).
pub fn surface_normals(xyz: &[[f32; 3]]) -> Vec<Option<[f32; 3]>> {
    const K: usize = 10;
    if xyz.len() < K {
        return vec![None; xyz.len()];
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(xyz);
    let want = NonZero::new(K).unwrap_or(NonZero::<usize>::MIN);
    xyz.par_iter()
        .map(|p| {
            let nn = tree.nearest_n::<SquaredEuclidean>(p, want);
            let pts: Vec<nalgebra::Vector3<f64>> = nn
                .iter()
                .map(|n| {
                    let q = xyz[n.item as usize];
                    nalgebra::Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64)
                })
                .collect();
            let mean = pts.iter().sum::<nalgebra::Vector3<f64>>() / pts.len() as f64;
            let cov = pts
                .iter()
                .map(|q| (q - mean) * (q - mean).transpose())
                .sum::<nalgebra::Matrix3<f64>>();
            let eig = nalgebra::SymmetricEigen::new(cov);
            let mut order = [0usize, 1, 2];
            order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
            let (low, mid) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
            let normal = eig.eigenvectors.column(order[0]);
            (mid > 0.0 && low.max(0.0) < 0.25 * mid && normal.iter().all(|v| v.is_finite())).then(
                || {
                    let n = normal.normalize();
                    [n[0] as f32, n[1] as f32, n[2] as f32]
                },
            )
        })
        .collect()
}

/// A tiny deterministic generator for reproducible initial times.
struct SplitMix(u64);

impl SplitMix {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_points_get_their_spacing_as_scale() {
        let mut xyz = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                xyz.push([i as f32 * 0.5, j as f32 * 0.5, 0.0]);
            }
        }
        let s = nearest_neighbour_scales(&xyz);
        // An interior point of a 0.5 grid: its 3 nearest are at 0.5.
        assert!((s[55] - 0.5).abs() < 1e-5, "{}", s[55]);
        let cloud = PointCloud {
            rgb: vec![[255, 0, 128]; xyz.len()],
            xyz,
            time: None,
            time_span: None,
        };
        let tm = TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 2.0,
        };
        let g = gaussians_from_points(&cloud, tm, &InitOptions::default()).unwrap();
        assert_eq!(g.len(), 100);
        assert!(g.means.iter().all(|m| (0.0..=2.0).contains(&m[3])));
        assert!((crate::math::numerics::sigmoid(g.opacity_logits[0]) - 0.1).abs() < 1e-6);
        let dc = g.colour_of(0);
        assert!((0.5 + crate::math::sh::SH_C0 as f32 * dc[0] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn points_on_a_tilted_plane_start_as_disks_in_it() {
        // A jittered 12×12 grid on the plane z = 0.3x − 0.2y + 1, and a line of points.
        let mut xyz = Vec::new();
        for i in 0..12 {
            for j in 0..12 {
                let (x, y) = (i as f32 * 0.1 + 0.013 * (j % 3) as f32, j as f32 * 0.1);
                xyz.push([x, y, 0.3 * x - 0.2 * y + 1.0]);
            }
        }
        let line: Vec<[f32; 3]> = (0..12).map(|i| [i as f32, 5.0, 5.0]).collect();
        let normals = surface_normals(&xyz);
        let want = glam::Vec3::new(-0.3, 0.2, 1.0).normalize();
        for n in &normals {
            let n = glam::Vec3::from(n.expect("a plane is planar"));
            assert!(n.dot(want).abs() > 1.0 - 1e-5, "{n} vs {want}");
        }
        assert!(surface_normals(&line).iter().all(Option::is_none));
        assert!(surface_normals(&xyz[..5]).iter().all(Option::is_none));

        let cloud = PointCloud {
            rgb: vec![[128; 3]; xyz.len()],
            xyz,
            time: None,
            time_span: None,
        };
        let options = InitOptions {
            flatness: 0.1,
            ..InitOptions::default()
        };
        let g = gaussians_from_points(&cloud, TimeMapping::default(), &options).unwrap();
        for i in 0..g.len() {
            // The covariance's thin axis (its rotated local z) is the plane's normal.
            let (r, _) = crate::math::rotation4d::rotation(g.rot_left[i], g.rot_right[i]);
            let axis_z = glam::Vec3::new(r[0][2], r[1][2], r[2][2]);
            assert!(axis_z.dot(want).abs() > 1.0 - 1e-4, "{axis_z}");
            assert!((r[3][3] - 1.0).abs() < 1e-6, "time is left alone");
            let s = g.log_scales[i];
            assert!((s[2] - s[0] - 0.1f32.ln()).abs() < 1e-5 && s[0] == s[1]);
        }
        // Balls by default.
        let balls = gaussians_from_points(&cloud, TimeMapping::default(), &InitOptions::default());
        let balls = balls.unwrap();
        assert!(balls.log_scales.iter().all(|s| s[0] == s[2]));
    }

    #[test]
    fn with_velocity_moving_points_follow_their_motion_and_static_ones_stay() {
        // A patch of points moving along z at 0.5 per unit time, seen at moments 0.2 and
        // 0.4, and a static row seen over the whole clip.
        let (mut xyz, mut time, mut span) = (Vec::new(), Vec::new(), Vec::new());
        for t in [0.2f32, 0.4] {
            for i in 0..15 {
                for j in 0..15 {
                    xyz.push([i as f32 * 0.02, j as f32 * 0.02, 1.0 + 0.5 * t]);
                    time.push(t);
                    span.push(0.0);
                }
            }
        }
        for i in 0..50 {
            xyz.push([i as f32 * 0.02, -1.0, 0.0]);
            time.push(0.5);
            span.push(1.0);
        }
        let cloud = PointCloud {
            rgb: vec![[128; 3]; xyz.len()],
            xyz,
            time: Some(time),
            time_span: Some(span),
        };
        let tm = TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 1.0,
        };
        let sliced_z = |g: &Gaussians<f32>, i: usize, t: f64| {
            let (s, _) = crate::math::slice::slice(
                g.means[i].map(f64::from),
                g.log_scales[i].map(f64::from),
                g.rot_left[i].map(f64::from),
                g.rot_right[i].map(f64::from),
                t,
            )
            .expect("alive");
            s.mean[2]
        };
        let options = InitOptions {
            time_scale_fraction: 0.05,
            velocity: true,
            ..InitOptions::default()
        };
        let moving = gaussians_from_points(&cloud, tm, &options).unwrap();
        let still = gaussians_from_points(
            &cloud,
            tm,
            &InitOptions {
                velocity: false,
                ..options
            },
        );
        let still = still.unwrap();
        for i in [0, 100, 300] {
            let z0 = moving.means[i][2] as f64;
            assert!(
                (sliced_z(&moving, i, moving.means[i][3] as f64 + 0.05) - (z0 + 0.025)).abs()
                    < 1e-4
            );
            assert!((sliced_z(&still, i, still.means[i][3] as f64 + 0.05) - z0).abs() < 1e-6);
        }
        // The static row keeps its axis-aligned, time-only rotation.
        assert_eq!(moving.rot_left[460], [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(moving.log_scales[460], still.log_scales[460]);
    }

    #[test]
    fn bad_clouds_are_refused() {
        assert!(matches!(
            gaussians_from_points(
                &PointCloud::default(),
                TimeMapping::default(),
                &InitOptions::default()
            ),
            Err(SeedError::Empty)
        ));
        let c = PointCloud {
            xyz: vec![[0.0, f32::NAN, 0.0]],
            rgb: vec![[0; 3]],
            time: None,
            time_span: None,
        };
        assert!(matches!(
            gaussians_from_points(&c, TimeMapping::default(), &InitOptions::default()),
            Err(SeedError::NonFinite { index: 0 })
        ));
        let spans = |s: Vec<f32>| PointCloud {
            xyz: vec![[0.0; 3], [1.0; 3]],
            rgb: vec![[0; 3]; 2],
            time: None,
            time_span: Some(s),
        };
        let refused = |c: &PointCloud| {
            gaussians_from_points(c, TimeMapping::default(), &InitOptions::default()).is_err()
        };
        assert!(refused(&spans(vec![1.0])), "length mismatch");
        assert!(refused(&spans(vec![1.0, -0.5])), "negative span");
        assert!(refused(&spans(vec![f32::INFINITY, 0.0])), "infinite span");
    }

    #[test]
    fn static_points_live_as_long_as_they_were_seen() {
        let cloud = PointCloud {
            xyz: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            rgb: vec![[0; 3]; 3],
            time: Some(vec![1.0, 1.0, 0.3]),
            // Seen over the whole clip, over a short stretch, at one moment.
            time_span: Some(vec![2.0, 0.1, 0.0]),
        };
        let tm = TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 2.0,
        };
        let g = gaussians_from_points(&cloud, tm, &InitOptions::default()).unwrap();
        let sigma_t = |i: usize| f64::from(g.log_scales[i][3]).exp();
        // σ_t = max(fraction × duration, span): 2.0, then 0.2 × 2.0 = 0.4 twice.
        assert!((sigma_t(0) - 2.0).abs() < 1e-5, "{}", sigma_t(0));
        assert!((sigma_t(1) - 0.4).abs() < 1e-5);
        assert!((sigma_t(2) - 0.4).abs() < 1e-5);
        assert_eq!(g.means[2][3], 0.3);
    }

    #[test]
    fn points_of_one_moment_live_a_third_of_the_time_to_the_next() {
        // Moving points at four moments 0.5 apart, and a static point over the clip.
        let mut time: Vec<f32> = [0.0f32, 0.5, 1.0, 1.5]
            .iter()
            .flat_map(|&t| [t, t + 0.01])
            .collect();
        let mut span = vec![0.0f32; time.len()];
        time.push(1.0);
        span.push(2.0);
        let n = time.len();
        let cloud = PointCloud {
            xyz: (0..n).map(|i| [i as f32 * 0.1, 0.0, 0.0]).collect(),
            rgb: vec![[0; 3]; n],
            time: Some(time),
            time_span: Some(span),
        };
        let tm = TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 2.0,
        };
        let sigmas = |fraction: f64| {
            let options = InitOptions {
                time_scale_fraction: fraction,
                ..InitOptions::default()
            };
            let g = gaussians_from_points(&cloud, tm, &options).unwrap();
            (0..n)
                .map(|i| f64::from(g.log_scales[i][3]).exp())
                .collect::<Vec<_>>()
        };
        // 0.2 × 2.0 = 0.4 is longer than a third of the 0.5 between moments.
        let s = sigmas(0.2);
        for v in &s[..n - 1] {
            assert!((v - 0.5 / 3.0).abs() < 1e-5, "{v}");
        }
        assert!((s[n - 1] - 2.0).abs() < 1e-5);
        // A shorter setting stays.
        let s = sigmas(0.05);
        assert!((s[0] - 0.1).abs() < 1e-5, "{}", s[0]);
    }
}
