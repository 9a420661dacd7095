//! A sparse depth prior from the initial points. The init stage's points, projected into
//! the training views they belong to, give a target depth z* at the pixels they land on
//! (the nearest point per pixel). Training then adds
//!
//! `L_depth = λ / |S| · Σ_{p ∈ S} |D_p − A_p·z*_p| / z*_p`, with `D = Σ wᵢ zᵢ`, `A = Σ wᵢ`,
//!
//! over those pixels S: `D − A·z* = Σ wᵢ (zᵢ − z*)` pulls each ray's blend weight towards
//! the surface the multi-view init found, so fog in front of it and splats behind it both
//! cost, where the colour loss of four views cannot tell them apart.
//!
//! Which points a view gets: a point with a time span (static structure seen over the
//! clip) goes to every view inside its span, except at pixels where the view's image
//! differs from its camera's temporal median (something moving passes in front); a
//! point of one moment goes to the views within half a frame interval of it.

use super::dataset::View;
use glam::DVec3;
use shared_types::points::PointCloud;

/// Per-channel difference (of 255) from the camera's median image above which a pixel
/// counts as moving, and static targets there are dropped.
const MOVING_DIFFERENCE: i32 = 24;
/// Frames per camera the median image is taken over (evenly spaced).
const MEDIAN_FRAMES: usize = 31;

/// One view's targets: pixel indices (row-major) and the depth z* at each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DepthTargets {
    pub pixels: Vec<u32>,
    pub depth: Vec<f32>,
}

/// The targets of every view (in `views`' order) from `points`.
pub fn targets(points: &PointCloud, views: &[View]) -> Vec<DepthTargets> {
    let tolerance = 0.5 * frame_interval(views);
    let medians = camera_medians(views);
    views
        .iter()
        .map(|view| {
            let median = medians
                .iter()
                .find(|(name, _)| *name == view.camera.name)
                .map(|(_, m)| m.as_slice());
            view_targets(points, view, tolerance, median)
        })
        .collect()
}

fn view_targets(
    points: &PointCloud,
    view: &View,
    tolerance: f32,
    median: Option<&[u8]>,
) -> DepthTargets {
    let (w, h) = (view.image.width as usize, view.image.height as usize);
    let mut nearest = vec![f32::INFINITY; w * h];
    for (i, p) in points.xyz.iter().enumerate() {
        let time = points.time.as_ref().map(|t| t[i]);
        let span = points.time_span.as_ref().map_or(0.0, |s| s[i]);
        let is_static = time.is_none() || span > 0.0;
        if let Some(t) = time
            && !((view.time - t).abs() <= 0.5 * span + tolerance)
        {
            continue;
        }
        let world = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let Some((px, z)) = view.camera.project(world) else {
            continue;
        };
        let (x, y) = (px.x.floor(), px.y.floor());
        if !(z > 0.0 && x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64) {
            continue;
        }
        let k = y as usize * w + x as usize;
        if is_static && median.is_some_and(|m| moving(&view.image.data, m, k)) {
            continue;
        }
        nearest[k] = nearest[k].min(z as f32);
    }
    let mut out = DepthTargets::default();
    for (k, &z) in nearest.iter().enumerate() {
        if z.is_finite() {
            out.pixels.push(k as u32);
            out.depth.push(z);
        }
    }
    out
}

/// Whether pixel `k` of `image` differs from the median image `m` by more than
/// [`MOVING_DIFFERENCE`] in a channel.
fn moving(image: &[u8], m: &[u8], k: usize) -> bool {
    (0..3).any(|c| (image[3 * k + c] as i32 - m[3 * k + c] as i32).abs() > MOVING_DIFFERENCE)
}

/// Half of this is how far in model time a moment's points reach: the median gap between
/// consecutive distinct view times (0 for a single time).
fn frame_interval(views: &[View]) -> f32 {
    let mut times: Vec<f32> = views.iter().map(|v| v.time).collect();
    times.sort_by(f32::total_cmp);
    times.dedup();
    let mut gaps: Vec<f32> = times.windows(2).map(|p| p[1] - p[0]).collect();
    if gaps.is_empty() {
        return 0.0;
    }
    gaps.sort_by(f32::total_cmp);
    gaps[gaps.len() / 2]
}

/// Each camera's per-pixel median image over up to [`MEDIAN_FRAMES`] of its views (views
/// of one camera share its image size).
fn camera_medians(views: &[View]) -> Vec<(String, Vec<u8>)> {
    let mut names: Vec<&str> = views.iter().map(|v| v.camera.name.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    names
        .into_iter()
        .map(|name| {
            let own: Vec<&View> = views.iter().filter(|v| v.camera.name == name).collect();
            let step = own.len().div_ceil(MEDIAN_FRAMES).max(1);
            let frames: Vec<&[u8]> = own
                .iter()
                .step_by(step)
                .map(|v| &v.image.data[..])
                .collect();
            let len = frames.iter().map(|f| f.len()).min().unwrap_or(0);
            let mut values = Vec::with_capacity(frames.len());
            let median = (0..len)
                .map(|i| {
                    values.clear();
                    values.extend(frames.iter().map(|f| f[i]));
                    values.sort_unstable();
                    values[values.len() / 2]
                })
                .collect();
            (name.to_string(), median)
        })
        .collect()
}

/// The loss `λ / |S| · Σ |D − A·z*| / z*` of one view's render (`depth` = Σ wᵢ zᵢ and
/// `alpha` = Σ wᵢ per pixel) and its gradients, added into `d_depth` and `d_alpha`
/// (per pixel, the length of `depth`). 0 without targets.
pub fn loss(
    targets: &DepthTargets,
    depth: &[f32],
    alpha: &[f32],
    weight: f64,
    d_depth: &mut [f32],
    d_alpha: &mut [f32],
) -> f64 {
    if targets.pixels.is_empty() || weight == 0.0 {
        return 0.0;
    }
    let scale = weight / targets.pixels.len() as f64;
    let mut total = 0.0;
    for (&k, &z) in targets.pixels.iter().zip(&targets.depth) {
        let k = k as usize;
        let z = z as f64;
        let r = (depth[k] as f64 - alpha[k] as f64 * z) / z;
        total += r.abs();
        let s = scale * r.signum() / z;
        d_depth[k] += s as f32;
        d_alpha[k] -= (s * z) as f32;
    }
    scale * total
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::ImageU8;
    use shared_types::camera::{Camera, Intrinsics, WorldToCamera};

    fn view(name: &str, time: f32, fill: u8) -> View {
        let intrinsics = Intrinsics::from_hfov(8, 6, 60.0);
        let pose =
            WorldToCamera::look_at(DVec3::new(0.0, 0.0, -5.0), DVec3::ZERO, DVec3::Y).unwrap();
        let camera = Camera {
            name: name.into(),
            intrinsics,
            distortion: Default::default(),
            world_to_camera: pose,
        };
        View {
            camera,
            time,
            image: ImageU8 {
                width: 8,
                height: 6,
                data: vec![fill; 8 * 6 * 3],
            },
        }
    }

    #[test]
    fn the_loss_gradient_matches_finite_differences_in_f64() {
        let targets = DepthTargets {
            pixels: vec![0, 2, 3],
            depth: vec![2.0, 5.0, 0.5],
        };
        let depth = [1.3f32, 0.0, 4.1, 0.2];
        let alpha = [0.7f32, 0.0, 0.9, 0.45];
        let weight = 0.3;
        let mut dd = [0.0f32; 4];
        let mut da = [0.0f32; 4];
        loss(&targets, &depth, &alpha, weight, &mut dd, &mut da);
        let h = 1e-3f32;
        for k in 0..4 {
            for (plane, grad) in [(0, dd[k]), (1, da[k])] {
                let eval = |delta: f32| {
                    let (mut d, mut a) = (depth, alpha);
                    if plane == 0 {
                        d[k] += delta;
                    } else {
                        a[k] += delta;
                    }
                    let (mut x, mut y) = ([0.0; 4], [0.0; 4]);
                    loss(&targets, &d, &a, weight, &mut x, &mut y)
                };
                let fd = (eval(h) - eval(-h)) / (2.0 * h as f64);
                assert!(
                    (fd - grad as f64).abs() < 1e-4,
                    "pixel {k} plane {plane}: {fd} vs {grad}"
                );
            }
        }
        // A ray whose weight sits exactly at the target costs nothing.
        let (mut x, mut y) = ([0.0; 1], [0.0; 1]);
        let on = DepthTargets {
            pixels: vec![0],
            depth: vec![2.0],
        };
        assert_eq!(loss(&on, &[1.6], &[0.8], 1.0, &mut x, &mut y), 0.0);
    }

    #[test]
    fn static_points_reach_every_view_moments_only_their_own_and_moving_pixels_are_skipped() {
        // Two frames of one camera 0.1 apart, and a third that differs from the median
        // (something passes in front).
        let views = [
            view("cam0", 0.0, 100),
            view("cam0", 0.1, 100),
            view("cam0", 0.2, 200),
        ];
        let points = PointCloud {
            xyz: vec![[0.0, 0.0, 0.0], [0.0, 0.0, -1.0]],
            rgb: vec![[0; 3]; 2],
            // A static point over the whole clip, and a point of the moment t = 0.1.
            time: Some(vec![0.1, 0.1]),
            time_span: Some(vec![1.0, 0.0]),
        };
        let t = targets(&points, &views);
        // The centre pixel of the 8×6 image: (4, 3).
        let centre = 3 * 8 + 4;
        assert_eq!(t[0].pixels, vec![centre]);
        assert!((t[0].depth[0] - 5.0).abs() < 1e-5, "{:?}", t[0]);
        // At t = 0.1 the moment's point is nearer and wins the pixel.
        assert_eq!(t[1].pixels, vec![centre]);
        assert!((t[1].depth[0] - 4.0).abs() < 1e-5, "{:?}", t[1]);
        // The frame that differs from the median keeps no static target, and t = 0.2 is
        // more than half a frame from the moment.
        assert!(t[2].pixels.is_empty(), "{:?}", t[2]);
    }
}
