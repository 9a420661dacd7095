//! Turning aligned point maps into one cloud: world points with the colour of their pixel
//! and the time of their frame, voxel downsampling, a cap on the count, and the random
//! cloud of the last fallback. No model or file knowledge here.

use glam::{DVec2, DVec3};
use image::RgbImage;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use shared_types::Camera;
use shared_types::PointCloud;

use crate::grid::{CellMap, Grid, cell_key};

/// One point of the fused cloud (world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FusedPoint {
    pub xyz: DVec3,
    /// Linear `[0, 255]` colour (averaged by downsampling).
    pub rgb: [f32; 3],
    pub time: f64,
    /// Model time over which the point was seen (0: one moment); `time` is its centre.
    pub time_span: f64,
}

/// Colour of `image` at a point-map pixel centre `p` of a `map_w × map_h` map covering the
/// whole image (nearest pixel).
pub fn colour_at(image: &RgbImage, p: DVec2, map_w: usize, map_h: usize) -> [f32; 3] {
    let (w, h) = image.dimensions();
    if w == 0 || h == 0 {
        return [0.0; 3];
    }
    let x = ((p.x * w as f64 / map_w as f64).floor().max(0.0) as u32).min(w - 1);
    let y = ((p.y * h as f64 / map_h as f64).floor().max(0.0) as u32).min(h - 1);
    let c = image.get_pixel(x, y).0;
    [c[0] as f32, c[1] as f32, c[2] as f32]
}

/// The world point at depth `z` along the ray of pixel centre `p` of `camera` (pinhole,
/// intrinsics at the map's size).
pub fn unproject(camera: &Camera, p: DVec2, z: f64) -> DVec3 {
    let n = camera.intrinsics.to_normalised(p);
    camera
        .world_to_camera
        .inverse_apply(DVec3::new(n.x * z, n.y * z, z))
}

/// Which of the points `xyz` have at least `min_neighbours` other points within `radius`:
/// a dense surface keeps every point, a lone wrong depth (a false stereo match) does not.
/// With `radius ≤ 0` or `min_neighbours` 0 every point is kept.
pub fn supported(xyz: &[DVec3], radius: f64, min_neighbours: usize) -> Vec<bool> {
    if min_neighbours == 0 || radius.is_nan() || radius <= 0.0 {
        return vec![true; xyz.len()];
    }
    let grid = Grid::new(xyz.iter().copied().enumerate(), radius);
    let r2 = radius * radius;
    xyz.par_iter()
        .enumerate()
        .map(|(i, p)| {
            grid.near(*p)
                .filter(|&j| j != i && xyz[j].distance_squared(*p) <= r2)
                .take(min_neighbours)
                .count()
                >= min_neighbours
        })
        .collect()
}

/// Average the points of each `voxel`-sized cube (xyz, colour and time); `voxel ≤ 0`
/// keeps every point. The output is ordered by voxel, so it does not depend on hash order.
pub fn voxel_downsample(points: &[FusedPoint], voxel: f64) -> Vec<FusedPoint> {
    if voxel.is_nan() || voxel <= 0.0 {
        return points.to_vec();
    }
    type Cell = (DVec3, [f64; 3], f64, f64, usize);
    let mut cells: CellMap<Cell> = CellMap::default();
    for p in points {
        let e = cells
            .entry(cell_key(p.xyz, voxel))
            .or_insert((DVec3::ZERO, [0.0; 3], 0.0, 0.0, 0));
        e.0 += p.xyz;
        for c in 0..3 {
            e.1[c] += p.rgb[c] as f64;
        }
        e.2 += p.time;
        e.3 += p.time_span;
        e.4 += 1;
    }
    let mut out = cells.into_iter().collect::<Vec<_>>();
    out.sort_by_key(|(k, _)| *k);
    out.into_iter()
        .map(|(_, (xyz, rgb, t, span, n))| {
            let n = n as f64;
            FusedPoint {
                xyz: xyz / n,
                rgb: rgb.map(|c| (c / n) as f32),
                time: t / n,
                time_span: span / n,
            }
        })
        .collect()
}

/// Keep at most `max` points, chosen at random (seeded); order is kept.
pub fn cap(points: Vec<FusedPoint>, max: usize, seed: u64) -> Vec<FusedPoint> {
    if points.len() <= max {
        return points;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut idx = (0..points.len()).collect::<Vec<_>>();
    // Partial Fisher–Yates: the first `max` entries are a uniform sample.
    for i in 0..max {
        let j = rng.random_range(i..idx.len());
        idx.swap(i, j);
    }
    let mut keep = idx[..max].to_vec();
    keep.sort_unstable();
    keep.into_iter().map(|i| points[i]).collect()
}

/// Keep at most `max` points as [`cap`] does, with the moving points (span 0) given
/// `moving_share` of the places and the static points the rest; places one side cannot
/// fill go to the other. Static points first, then moving ones.
pub fn cap_shared(
    points: Vec<FusedPoint>,
    max: usize,
    moving_share: f64,
    seed: u64,
) -> Vec<FusedPoint> {
    if points.len() <= max {
        return points;
    }
    let (moving, fixed): (Vec<FusedPoint>, Vec<FusedPoint>) =
        points.into_iter().partition(|p| p.time_span == 0.0);
    let moving_places =
        ((max as f64 * moving_share.clamp(0.0, 1.0)).round() as usize).min(moving.len());
    let static_places = (max - moving_places).min(fixed.len());
    let moving_places = (max - static_places).min(moving.len());
    let mut kept = cap(fixed, static_places, seed);
    kept.extend(cap(moving, moving_places, seed.wrapping_add(1)));
    kept
}

/// As a `points.ply` cloud (`time` and `time_span` always present).
pub fn to_cloud(points: &[FusedPoint]) -> PointCloud {
    PointCloud {
        xyz: points.iter().map(|p| p.xyz.as_vec3().to_array()).collect(),
        rgb: points
            .iter()
            .map(|p| p.rgb.map(|c| c.round().clamp(0.0, 255.0) as u8))
            .collect(),
        time: Some(points.iter().map(|p| p.time as f32).collect()),
        time_span: Some(points.iter().map(|p| p.time_span as f32).collect()),
    }
}

/// Mean distance of the camera centres from their centroid (1 when degenerate): the
/// length unit of the relative settings (voxel size, random-cloud extent).
pub fn rig_radius(cameras: &[Camera]) -> f64 {
    if cameras.is_empty() {
        return 1.0;
    }
    let centres = cameras
        .iter()
        .map(|c| c.world_to_camera.centre())
        .collect::<Vec<_>>();
    let mean = centres.iter().copied().sum::<DVec3>() / centres.len() as f64;
    let r = centres.iter().map(|c| (*c - mean).length()).sum::<f64>() / centres.len() as f64;
    if r.is_finite() && r > 1e-12 { r } else { 1.0 }
}

/// The point closest (least squares) to every camera's optical axis: where the rig looks.
/// Falls back to the centroid of the centres when the axes are (nearly) parallel.
pub fn rig_target(cameras: &[Camera]) -> DVec3 {
    let mut a = glam::DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for c in cameras {
        let o = c.world_to_camera.centre();
        let d = c.world_to_camera.rotation().transpose() * DVec3::Z;
        let p = glam::DMat3::IDENTITY - glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * o;
    }
    let centroid = cameras
        .iter()
        .map(|c| c.world_to_camera.centre())
        .sum::<DVec3>()
        / cameras.len().max(1) as f64;
    if a.determinant().abs() < 1e-9 {
        return centroid;
    }
    let x = a.inverse() * b;
    if x.is_finite() { x } else { centroid }
}

/// `count` random points in the cameras' common view volume: uniform in a cube of half-size
/// one rig radius around [`rig_target`], kept when every camera sees them (in front, inside
/// the image); after many misses a point seen by at least two cameras (then one) is
/// accepted. Grey, time drawn uniformly in `times`.
pub fn random_cloud(
    cameras: &[Camera],
    count: usize,
    times: (f64, f64),
    seed: u64,
) -> Vec<FusedPoint> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centre = rig_target(cameras);
    let half = rig_radius(cameras);
    let sees = |c: &Camera, p: DVec3| -> bool {
        match c.project(p) {
            Some((px, _)) => {
                px.x >= 0.0
                    && px.y >= 0.0
                    && px.x < c.intrinsics.width as f64
                    && px.y < c.intrinsics.height as f64
            }
            None => false,
        }
    };
    let mut out = Vec::with_capacity(count);
    let mut need = cameras.len().max(1);
    let mut misses = 0usize;
    while out.len() < count {
        let p = centre
            + half
                * DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
        let seen = cameras.iter().filter(|c| sees(c, p)).count();
        if seen >= need.min(cameras.len()) {
            let (t0, t1) = times;
            let time = if t1 > t0 {
                rng.random_range(t0..t1)
            } else {
                t0
            };
            out.push(FusedPoint {
                xyz: p,
                rgb: [128.0; 3],
                time,
                time_span: 0.0,
            });
        } else {
            misses += 1;
            if misses > 50 * count + 1000 && need > 1 {
                need = if need > 2 { 2 } else { 1 };
                misses = 0;
            } else if misses > 50 * count + 1000 {
                // Nothing is seen at all (or no cameras): take the cube as it is.
                need = 0;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib::test_support::looking_at;
    use shared_types::Intrinsics;

    #[test]
    fn lone_points_are_dropped_and_a_surface_is_kept() {
        // A 20 × 20 grid 1 cm apart, two lone points, and a pair of points close together.
        let mut xyz: Vec<DVec3> = (0..400)
            .map(|i| DVec3::new((i % 20) as f64 * 0.01, (i / 20) as f64 * 0.01, 0.0))
            .collect();
        xyz.extend([
            DVec3::new(0.1, 0.1, 0.5),
            DVec3::new(-0.3, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(1.0, 1.0, 1.005),
        ]);
        let count = |keep: Vec<bool>| keep.iter().filter(|k| **k).count();
        let keep = supported(&xyz, 0.025, 4);
        assert!(
            keep[..400].iter().all(|k| *k) && !keep[400..].iter().any(|k| *k),
            "the grid's corners have 5 neighbours within 2.5 cm"
        );
        assert_eq!(count(supported(&xyz, 0.025, 0)), 404);
        assert_eq!(count(supported(&xyz, 0.0, 4)), 404);
        assert_eq!(count(supported(&xyz, 0.025, 1)), 402);
    }

    fn cam(eye: DVec3) -> Camera {
        looking_at(
            "c",
            Intrinsics::from_hfov(64, 48, 60.0),
            eye,
            DVec3::new(0.0, 0.0, 0.5),
        )
    }

    #[test]
    fn voxels_average_and_cap_is_seeded() {
        let p = |x: f64, t: f64| FusedPoint {
            xyz: DVec3::new(x, 0.1, 0.1),
            rgb: [10.0, 20.0, 30.0],
            time: t,
            time_span: 0.0,
        };
        let out = voxel_downsample(&[p(0.1, 0.0), p(0.3, 1.0), p(1.5, 2.0)], 1.0);
        assert_eq!(out.len(), 2);
        assert!((out[0].xyz.x - 0.2).abs() < 1e-12 && (out[0].time - 0.5).abs() < 1e-12);
        let many = (0..100).map(|i| p(i as f64, 0.0)).collect::<Vec<_>>();
        let a = cap(many.clone(), 10, 3);
        assert_eq!(a.len(), 10);
        assert_eq!(a, cap(many, 10, 3));
    }

    #[test]
    fn the_shared_cap_gives_moving_points_their_share() {
        let p = |x: f64, span: f64| FusedPoint {
            xyz: DVec3::new(x, 0.0, 0.0),
            rgb: [0.0; 3],
            time: 0.0,
            time_span: span,
        };
        let moving = |ps: &[FusedPoint]| ps.iter().filter(|p| p.time_span == 0.0).count();
        // 900 static and 100 moving points: a plain cap would keep about 10 % moving.
        let points: Vec<FusedPoint> = (0..1000)
            .map(|i| p(i as f64, if i % 10 == 0 { 0.0 } else { 1.0 }))
            .collect();
        let kept = cap_shared(points.clone(), 200, 0.3, 7);
        assert_eq!((kept.len(), moving(&kept)), (200, 60));
        // Places the moving points cannot fill go to the static ones, and back.
        let kept = cap_shared(points.clone(), 200, 0.9, 7);
        assert_eq!((kept.len(), moving(&kept)), (200, 100));
        let few_static: Vec<FusedPoint> = points
            .iter()
            .map(|q| p(q.xyz.x, 0.0))
            .take(950)
            .chain(points[1..51].iter().copied())
            .collect();
        let kept = cap_shared(few_static, 200, 0.1, 7);
        assert_eq!(kept.len(), 200);
        assert_eq!(kept.len() - moving(&kept), 45);
        // Under the cap nothing is dropped.
        assert_eq!(cap_shared(points.clone(), 1000, 0.3, 7), points);
    }

    #[test]
    fn random_cloud_is_seen_by_every_camera() {
        let cams = [
            cam(DVec3::new(3.0, 0.0, 1.5)),
            cam(DVec3::new(0.0, 3.0, 1.5)),
            cam(DVec3::new(-2.0, -2.0, 1.0)),
        ];
        let target = rig_target(&cams);
        assert!(
            (target - DVec3::new(0.0, 0.0, 0.5)).length() < 1e-9,
            "{target}"
        );
        let pts = random_cloud(&cams, 500, (0.0, 2.0), 1);
        assert_eq!(pts.len(), 500);
        for p in &pts {
            for c in &cams {
                let (px, _) = c.project(p.xyz).unwrap();
                assert!(px.x >= 0.0 && px.x < 64.0 && px.y >= 0.0 && px.y < 48.0);
            }
            assert!((0.0..2.0).contains(&p.time));
        }
    }
}
