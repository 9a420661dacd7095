//! Per-camera exposure and white balance, matched before training.
//!
//! Real cameras of one capture rarely film alike: on the Panoptic basketball capture the
//! four training cameras see the same static walls up to 1.4× brighter from one camera than
//! from another. Trained on the frames as filmed, the model explains each camera's
//! brightness with view-dependent colour and with splats in front of that camera alone,
//! which every other viewpoint sees as mottled fog. [`estimate`] measures each camera's gain
//! per colour channel where the cameras see the same static surface: the initial points
//! that live over the whole clip, each sampled in every camera's frames (the median over a
//! spread of frames, so people walking past do not count), alternating a per-point colour
//! and a per-camera gain in log space with medians (occluded or shiny points are outliers).
//! The gains' geometric mean over the cameras is 1: the model learns the cameras' average
//! exposure, [`equalise`] divides each training frame by its camera's gain, and a render
//! for a training camera's own view is multiplied by it (`eval`).

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::model::init::PointCloud;
use crate::train::{Dataset, View};

/// Frames per camera whose median colour a point takes.
const FRAMES_PER_CAMERA: usize = 9;
/// Points sampled (evenly through the cloud) at most.
const MAX_POINTS: usize = 20_000;
/// A channel value (0..255) outside `[DARK, BRIGHT]` says nothing about exposure.
const DARK: u8 = 8;
const BRIGHT: u8 = 247;
/// Observations a camera needs for a gain of its own (else 1).
const MIN_OBSERVATIONS: usize = 50;
/// Rounds of alternating point colours and camera gains.
const ROUNDS: usize = 5;
/// A point is static when it was seen over at least this fraction of the clip.
const STATIC_SPAN: f32 = 0.5;
/// A gain this close to 1 is 1: cameras that film alike keep their frames untouched.
const DEADBAND: f32 = 0.01;

/// One camera's gain: what its frames are divided by (per RGB channel).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraGain {
    pub camera: String,
    pub gain: [f32; 3],
}

/// Each camera's gain for `dataset`, measured on the static points of `points` (every
/// point when the cloud carries no time spans). A camera that sees too few of them, or a
/// capture where fewer than two cameras share any, gets gain 1.
pub fn estimate(dataset: &Dataset, points: &PointCloud) -> Vec<CameraGain> {
    let cameras = camera_views(dataset);
    let statics = static_points(points, dataset);
    // observations[p] = (camera index, ln colour) of point p in each camera that sees it.
    let observations: Vec<Vec<(usize, [f64; 3])>> = statics
        .iter()
        .map(|&x| {
            cameras
                .iter()
                .enumerate()
                .filter_map(|(c, (_, views))| median_colour(views, x).map(|rgb| (c, rgb)))
                .collect::<Vec<_>>()
        })
        .filter(|o| o.len() >= 2)
        .collect();
    let mut log_gain = vec![[0.0f64; 3]; cameras.len()];
    for _ in 0..ROUNDS {
        let mut residuals: Vec<[Vec<f64>; 3]> = vec![Default::default(); cameras.len()];
        for obs in &observations {
            for ch in 0..3 {
                let mean = obs
                    .iter()
                    .map(|(c, v)| v[ch] - log_gain[*c][ch])
                    .sum::<f64>()
                    / obs.len() as f64;
                for (c, v) in obs {
                    residuals[*c][ch].push(v[ch] - mean);
                }
            }
        }
        for (c, r) in residuals.iter_mut().enumerate() {
            for ch in 0..3 {
                log_gain[c][ch] = if r[ch].len() >= MIN_OBSERVATIONS {
                    median(&mut r[ch])
                } else {
                    0.0
                };
            }
        }
        // The cameras' average exposure is the model's.
        let measured: Vec<usize> = (0..cameras.len())
            .filter(|&c| residuals[c][0].len() >= MIN_OBSERVATIONS)
            .collect();
        for ch in 0..3 {
            let mean = measured.iter().map(|&c| log_gain[c][ch]).sum::<f64>()
                / measured.len().max(1) as f64;
            for &c in &measured {
                log_gain[c][ch] -= mean;
            }
        }
    }
    cameras
        .iter()
        .zip(&log_gain)
        .map(|((name, _), g)| CameraGain {
            camera: name.clone(),
            gain: g.map(|v| {
                let gain = v.exp() as f32;
                if (gain - 1.0).abs() < DEADBAND {
                    1.0
                } else {
                    gain
                }
            }),
        })
        .collect()
}

/// `dataset` with each view's image divided by its camera's gain (rounded, clamped to
/// 0..255); views of cameras without a gain are unchanged.
pub fn equalise(dataset: &mut Dataset, gains: &[CameraGain]) {
    use rayon::prelude::*;
    // One lookup table per camera and channel: 0..255 divided by the gain.
    let tables: Vec<(&str, [[u8; 256]; 3])> = gains
        .iter()
        .filter(|g| g.gain != [1.0; 3])
        .map(|g| {
            let table = std::array::from_fn(|ch| {
                std::array::from_fn(|v| (v as f32 / g.gain[ch]).round().clamp(0.0, 255.0) as u8)
            });
            (g.camera.as_str(), table)
        })
        .collect();
    dataset.views.par_iter_mut().for_each(|view| {
        let Some((_, table)) = tables.iter().find(|(name, _)| *name == view.camera.name) else {
            return;
        };
        for (k, v) in view.image.data.iter_mut().enumerate() {
            *v = table[k % 3][*v as usize];
        }
    });
}

/// The gain of camera `name` in `gains` (1 when it has none).
pub fn gain_of(gains: &[CameraGain], name: &str) -> [f32; 3] {
    gains
        .iter()
        .find(|g| g.camera == name)
        .map_or([1.0; 3], |g| g.gain)
}

/// Each camera of `dataset` (in order of first appearance) with a spread of its views.
fn camera_views(dataset: &Dataset) -> Vec<(String, Vec<&View>)> {
    let mut cameras: Vec<(String, Vec<&View>)> = Vec::new();
    for v in &dataset.views {
        match cameras.iter_mut().find(|(n, _)| *n == v.camera.name) {
            Some((_, views)) => views.push(v),
            None => cameras.push((v.camera.name.clone(), vec![v])),
        }
    }
    for (_, views) in &mut cameras {
        views.sort_by(|a, b| a.time.total_cmp(&b.time));
        let n = views.len();
        let k = FRAMES_PER_CAMERA.min(n);
        *views = (0..k).map(|i| views[(2 * i + 1) * n / (2 * k)]).collect();
    }
    cameras
}

/// The points of `points` seen over most of the clip (all of them when the cloud has no
/// time spans), at most [`MAX_POINTS`] spread evenly through it.
fn static_points(points: &PointCloud, dataset: &Dataset) -> Vec<DVec3> {
    let clip = dataset
        .views
        .iter()
        .map(|v| v.time)
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), t| {
            (a.min(t), b.max(t))
        });
    let span = (clip.1 - clip.0).max(0.0);
    let keep: Vec<DVec3> = points
        .xyz
        .iter()
        .enumerate()
        .filter(|(i, _)| match &points.time_span {
            Some(s) => s.get(*i).is_some_and(|&s| s >= STATIC_SPAN * span),
            None => true,
        })
        .map(|(_, p)| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    let step = keep.len().div_ceil(MAX_POINTS).max(1);
    keep.into_iter().step_by(step).collect()
}

/// The per-channel median colour (ln of 0..255) of `x` over `views` of one camera, when
/// it lands inside their images and is neither dark nor clipped.
fn median_colour(views: &[&View], x: DVec3) -> Option<[f64; 3]> {
    let first = views.first()?;
    let (px, _) = first.camera.project(x)?;
    let (w, h) = (first.image.width, first.image.height);
    if !(px.x >= 0.0 && px.y >= 0.0 && px.x < w as f64 && px.y < h as f64) {
        return None;
    }
    let k = 3 * (px.y as usize * w as usize + px.x as usize);
    let mut out = [0.0; 3];
    for (ch, o) in out.iter_mut().enumerate() {
        let mut values: Vec<f64> = views
            .iter()
            .filter_map(|v| v.image.data.get(k + ch).map(|&c| c as f64))
            .collect();
        let m = median(&mut values);
        if !(DARK as f64..=BRIGHT as f64).contains(&m) {
            return None;
        }
        *o = m.ln();
    }
    Some(out)
}

/// The median of `values` (sorted in place; the upper one of an even count; 0 for none).
fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Camera;
    use crate::model::TimeMapping;
    use crate::train::ImageU8;
    use shared_types::{Intrinsics, WorldToCamera};

    const W: u32 = 48;
    const H: u32 = 36;

    /// Texture of the plane z = 0 (0..255, never dark or clipped).
    fn texture(x: f64, y: f64) -> [f64; 3] {
        [
            120.0 + 60.0 * (3.0 * x).sin(),
            110.0 + 50.0 * (2.0 * y + 1.0).cos(),
            90.0 + 40.0 * (2.0 * x + 3.0 * y).sin(),
        ]
    }

    /// Cameras above the plane looking at its centre.
    fn cameras() -> Vec<Camera> {
        [(-2.0, 0.0), (2.0, 0.5), (0.0, -2.0), (0.3, 2.2)]
            .iter()
            .enumerate()
            .map(|(i, &(x, y))| Camera {
                name: format!("cam{i}"),
                intrinsics: Intrinsics::from_hfov(W, H, 60.0),
                distortion: Default::default(),
                world_to_camera: WorldToCamera::look_at(
                    DVec3::new(x, y, 3.0),
                    DVec3::ZERO,
                    DVec3::Y,
                )
                .unwrap(),
            })
            .collect()
    }

    /// Frame `k` of `camera` filmed with `gain`: the plane's texture, and in every third
    /// frame a black block (someone walking past) over the left half.
    fn frame(camera: &Camera, gain: [f64; 3], k: usize) -> ImageU8 {
        let mut data = Vec::new();
        let centre = camera.world_to_camera.centre();
        for y in 0..H {
            for x in 0..W {
                let ray = camera.pixel_ray(glam::DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
                let p = centre + ray * (-centre.z / ray.z);
                let walker = k.is_multiple_of(3) && x < W / 2;
                let t = texture(p.x, p.y);
                for ch in 0..3 {
                    let v = if walker { 0.0 } else { t[ch] * gain[ch] };
                    data.push(v.round().clamp(0.0, 255.0) as u8);
                }
            }
        }
        ImageU8 {
            width: W,
            height: H,
            data,
        }
    }

    fn dataset(gains: &[[f64; 3]]) -> Dataset {
        let mut views = Vec::new();
        for (camera, gain) in cameras().iter().zip(gains) {
            for k in 0..9 {
                views.push(View::at_image_size(
                    camera.clone(),
                    k as f32 / 8.0,
                    frame(camera, *gain, k),
                ));
            }
        }
        Dataset {
            views,
            time_mapping: TimeMapping::frames_over_30(0.0, 9.0, 1.0),
        }
    }

    /// Static points on the plane (time span the whole clip) and a moving one.
    fn points() -> PointCloud {
        let mut cloud = PointCloud::default();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (-1.0 + i as f32 / 20.0, -1.0 + j as f32 / 20.0);
                cloud.xyz.push([x, y, 0.0]);
                cloud.rgb.push([128; 3]);
            }
        }
        let n = cloud.xyz.len();
        cloud.time = Some(vec![0.5; n]);
        cloud.time_span = Some(vec![1.0; n]);
        cloud
    }

    #[test]
    fn gains_of_cameras_filming_one_static_plane_are_recovered() {
        let truth = [
            [1.0, 1.0, 1.0],
            [1.2, 1.1, 0.9],
            [0.8, 0.85, 0.8],
            [1.1, 1.0, 1.3],
        ];
        let gains = estimate(&dataset(&truth), &points());
        assert_eq!(gains.len(), 4);
        for ch in 0..3 {
            let mean = truth.iter().map(|g| g[ch].ln()).sum::<f64>() / 4.0;
            for (g, t) in gains.iter().zip(&truth) {
                let expected = (t[ch].ln() - mean).exp();
                let got = g.gain[ch] as f64;
                assert!(
                    (got / expected - 1.0).abs() < 0.01,
                    "{} channel {ch}: {got} against {expected}",
                    g.camera
                );
            }
        }
        // Equalised, the cameras agree on a point they share.
        let mut data = dataset(&truth);
        equalise(&mut data, &gains);
        let again = estimate(&data, &points());
        for g in &again {
            for v in g.gain {
                assert!((v - 1.0).abs() < 0.01, "{} {:?}", g.camera, g.gain);
            }
        }
    }

    #[test]
    fn cameras_that_film_alike_get_gain_one_and_no_shared_points_change_nothing() {
        let gains = estimate(&dataset(&[[1.0; 3]; 4]), &points());
        for g in &gains {
            for v in g.gain {
                assert!((v - 1.0).abs() < 0.005, "{} {:?}", g.camera, g.gain);
            }
        }
        // Only moving points: nothing to measure on.
        let mut moving = points();
        moving.time_span = Some(vec![0.0; moving.xyz.len()]);
        let gains = estimate(&dataset(&[[1.0, 1.2, 0.8]; 4]), &moving);
        assert!(gains.iter().all(|g| g.gain == [1.0; 3]), "{gains:?}");
        assert_eq!(gain_of(&gains, "cam9"), [1.0; 3]);
    }
}
