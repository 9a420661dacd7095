//! Telling static points from moving ones among points triangulated at several moments: a
//! point with a point of another moment within `radius` is static. Static points are merged
//! (one copy per `merge`-neighbourhood) and given the span of the moments they were seen at
//! (`time` = the span's centre); moving points keep their moment's time (span 0) and are
//! voxel-downsampled per moment. Sparse points of a pose solve join the static ones over
//! the whole clip, unless a moving point lies beside them (then they saw the moving object).

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::fuse::{FusedPoint, voxel_downsample};
use super::grid::Grid;

/// A point triangulated at one moment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedPoint {
    pub xyz: DVec3,
    /// Linear `[0, 255]` colour.
    pub rgb: [f32; 3],
    /// Index of the moment (points of one moment share it).
    pub moment: usize,
    /// Model time of the moment.
    pub time: f64,
}

/// Counts of [`split_static`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StaticCounts {
    /// Triangulated points tagged static (before merging), and the merged static points.
    pub static_tagged: usize,
    pub static_points: usize,
    /// Moving points before and after the per-moment voxel downsampling.
    pub dynamic_tagged: usize,
    pub dynamic_points: usize,
    /// Extra static points (the pose solve's sparse points, the stills' sweep) merged in,
    /// and those dropped beside a moving point.
    pub sparse_merged: usize,
    pub sparse_dropped: usize,
}

/// Tag, merge and downsample `points` (see the module doc): static within `radius` of a
/// point of another moment, static points within `merge` merged; `sparse` are a pose solve's
/// points (xyz, colour) and `clip` the model times of the first and last moment.
/// `radius ≤ 0` tags nothing static. With `given` tags (a static plate's, one per point)
/// those decide instead, and static points live over the whole clip. The output is
/// deterministic (input order).
pub fn split_static(
    points: &[TimedPoint],
    sparse: &[(DVec3, [f32; 3])],
    radius: f64,
    merge: f64,
    voxel: f64,
    clip: (f64, f64),
    given: Option<&[bool]>,
) -> (Vec<FusedPoint>, StaticCounts) {
    let mut counts = StaticCounts::default();
    let grid = (radius > 0.0).then(|| Grid::new(points.iter().map(|p| p.xyz).enumerate(), radius));
    let within = |a: DVec3, b: DVec3| (a - b).length_squared() <= radius * radius;
    let is_static: Vec<bool> = match given {
        Some(tags) => tags.to_vec(),
        None => points
            .par_iter()
            .map(|p| {
                grid.as_ref().is_some_and(|g| {
                    g.near(p.xyz)
                        .any(|j| points[j].moment != p.moment && within(points[j].xyz, p.xyz))
                })
            })
            .collect(),
    };
    counts.static_tagged = is_static.iter().filter(|s| **s).count();
    counts.dynamic_tagged = points.len() - counts.static_tagged;

    // The static pool: (xyz, colour, first time, last time).
    let mut pool: Vec<(DVec3, [f32; 3], f64, f64)> = points
        .iter()
        .zip(&is_static)
        .filter(|(_, s)| **s)
        .map(|(p, _)| match given {
            Some(_) => (p.xyz, p.rgb, clip.0, clip.1),
            None => (p.xyz, p.rgb, p.time, p.time),
        })
        .collect();
    for &(xyz, rgb) in sparse {
        let beside_moving = grid.as_ref().is_some_and(|g| {
            g.near(xyz)
                .any(|j| !is_static[j] && within(points[j].xyz, xyz))
        });
        if beside_moving {
            counts.sparse_dropped += 1;
        } else {
            counts.sparse_merged += 1;
            pool.push((xyz, rgb, clip.0, clip.1));
        }
    }
    let mut out = merge_pool(&pool, merge);
    counts.static_points = out.len();

    let moments = points.iter().map(|p| p.moment).max().map_or(0, |m| m + 1);
    for m in 0..moments {
        let moving: Vec<FusedPoint> = points
            .iter()
            .zip(&is_static)
            .filter(|(p, s)| !**s && p.moment == m)
            .map(|(p, _)| FusedPoint {
                xyz: p.xyz,
                rgb: p.rgb,
                time: p.time,
                time_span: 0.0,
            })
            .collect();
        let kept = voxel_downsample(&moving, voxel);
        counts.dynamic_points += kept.len();
        out.extend(kept);
    }
    (out, counts)
}

/// Greedy clusters of the pool: each not yet taken point takes every untaken point within
/// `radius` of it; a cluster becomes its mean point, seen from its first to its last time.
fn merge_pool(pool: &[(DVec3, [f32; 3], f64, f64)], radius: f64) -> Vec<FusedPoint> {
    let cell = if radius > 0.0 { radius } else { 1.0 };
    let grid = Grid::new(pool.iter().map(|p| p.0).enumerate(), cell);
    let mut taken = vec![false; pool.len()];
    let mut out = Vec::new();
    for i in 0..pool.len() {
        if taken[i] {
            continue;
        }
        let centre = pool[i].0;
        let mut members: Vec<usize> = grid
            .near(centre)
            .filter(|&j| !taken[j] && (pool[j].0 - centre).length_squared() <= radius * radius)
            .collect();
        if members.is_empty() {
            members.push(i);
        }
        let (mut xyz, mut rgb) = (DVec3::ZERO, [0.0f64; 3]);
        let (mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY);
        for &j in &members {
            taken[j] = true;
            let (p, c, a, b) = pool[j];
            xyz += p;
            for k in 0..3 {
                rgb[k] += c[k] as f64;
            }
            (t0, t1) = (t0.min(a), t1.max(b));
        }
        let n = members.len() as f64;
        out.push(FusedPoint {
            xyz: xyz / n,
            rgb: rgb.map(|c| (c / n) as f32),
            time: 0.5 * (t0 + t1),
            time_span: t1 - t0,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, moment: usize) -> TimedPoint {
        TimedPoint {
            xyz: DVec3::new(x, 0.0, 0.0),
            rgb: [moment as f32 * 10.0; 3],
            moment,
            time: moment as f64,
        }
    }

    #[test]
    fn repeated_points_are_static_and_merged_moving_ones_keep_their_time() {
        // A wall point seen at moments 0, 2, 3 (jittered); an object at x = 5, 6, 7.
        let pts = [
            p(0.0, 0),
            p(0.01, 2),
            p(-0.01, 3),
            p(5.0, 0),
            p(6.0, 1),
            p(7.0, 2),
        ];
        let (out, c) = split_static(&pts, &[], 0.05, 0.05, 0.0, (0.0, 3.0), None);
        assert_eq!((c.static_tagged, c.static_points), (3, 1));
        assert_eq!((c.dynamic_tagged, c.dynamic_points), (3, 3));
        let wall = out[0];
        assert!(wall.xyz.length() < 1e-9);
        assert_eq!((wall.time, wall.time_span), (1.5, 3.0));
        let mut moving: Vec<_> = out[1..]
            .iter()
            .map(|q| (q.xyz.x, q.time, q.time_span))
            .collect();
        moving.sort_by(|a, b| a.0.total_cmp(&b.0));
        assert_eq!(moving, [(5.0, 0.0, 0.0), (6.0, 1.0, 0.0), (7.0, 2.0, 0.0)]);
    }

    #[test]
    fn sparse_points_join_static_ones_unless_beside_a_moving_point() {
        let pts = [p(0.0, 0), p(0.01, 1), p(5.0, 0)];
        let sparse = [
            (DVec3::new(0.02, 0.0, 0.0), [1.0; 3]), // merged with the wall point
            (DVec3::new(5.01, 0.0, 0.0), [1.0; 3]), // saw the moving object
            (DVec3::new(-3.0, 0.0, 0.0), [1.0; 3]), // alone: static over the clip
        ];
        let (out, c) = split_static(&pts, &sparse, 0.05, 0.05, 0.0, (0.0, 4.0), None);
        assert_eq!((c.sparse_merged, c.sparse_dropped), (2, 1));
        assert_eq!((c.static_points, c.dynamic_points), (2, 1));
        for q in &out[..2] {
            assert_eq!((q.time, q.time_span), (2.0, 4.0));
        }
        assert_eq!(out.len(), 3);
    }

    #[test]
    fn static_points_merge_within_the_merge_distance_only() {
        // Two wall points 0.03 apart, each seen at two moments (jitter 0.001).
        let pts = [p(0.0, 0), p(0.001, 1), p(0.03, 0), p(0.031, 1)];
        let (_, coarse) = split_static(&pts, &[], 0.05, 0.05, 0.0, (0.0, 1.0), None);
        let (fine, c) = split_static(&pts, &[], 0.05, 0.01, 0.0, (0.0, 1.0), None);
        assert_eq!((coarse.static_tagged, coarse.static_points), (4, 1));
        assert_eq!((c.static_tagged, c.static_points), (4, 2));
        let mut x: Vec<_> = fine.iter().map(|q| q.xyz.x).collect();
        x.sort_by(f64::total_cmp);
        assert!((x[0] - 0.0005).abs() < 1e-12 && (x[1] - 0.0305).abs() < 1e-12);
    }

    #[test]
    fn no_radius_tags_nothing_static() {
        let pts = [p(0.0, 0), p(0.0, 1)];
        let (_, c) = split_static(&pts, &[], 0.0, 0.0, 0.0, (0.0, 1.0), None);
        assert_eq!((c.static_tagged, c.dynamic_points), (0, 2));
    }
}
