//! The normalised frame of the outputs: `x_norm = scale · (x_world − centre)`, centred on
//! the video cameras and scaled so they sit at a chosen mean distance from the centre.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use shared_types::{Camera, WorldToCamera};

/// `x_norm = scale · (x_world − centre)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    pub centre: [f64; 3],
    pub scale: f64,
}

impl Normalisation {
    pub const IDENTITY: Self = Self {
        centre: [0.0; 3],
        scale: 1.0,
    };

    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.scale * (p - DVec3::from_array(self.centre))
    }

    /// The same camera in the normalised frame: `t' = scale · (R·centre + t)`.
    pub fn apply_to_pose(&self, w2c: &WorldToCamera) -> WorldToCamera {
        let r = w2c.rotation();
        WorldToCamera::from_parts(
            r,
            self.scale * (r * DVec3::from_array(self.centre) + w2c.translation()),
        )
    }
}

/// Centre on the mean video-camera centre and scale so the cameras sit at mean distance
/// `radius`. With one camera (or all at one spot) the median distance of `points` (the
/// sparse points) is used; with neither, the scale stays 1.
pub fn normalisation_for(cameras: &[Camera], points: &[DVec3], radius: f64) -> Normalisation {
    let centres: Vec<DVec3> = cameras.iter().map(|c| c.world_to_camera.centre()).collect();
    if centres.is_empty() {
        return Normalisation::IDENTITY;
    }
    let centre = centres.iter().copied().sum::<DVec3>() / centres.len() as f64;
    let mut spread =
        centres.iter().map(|c| (*c - centre).length()).sum::<f64>() / centres.len() as f64;
    if spread < 1e-12 {
        let mut d: Vec<f64> = points.iter().map(|p| (*p - centre).length()).collect();
        d.sort_by(f64::total_cmp);
        spread = d.get(d.len() / 2).copied().unwrap_or(0.0);
    }
    let scale = if spread > 1e-12 && radius > 0.0 {
        radius / spread
    } else {
        1.0
    };
    Normalisation {
        centre: centre.to_array(),
        scale,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::looking_at;

    #[test]
    fn normalisation_puts_cameras_at_the_radius_and_keeps_projections() {
        use glam::DVec3;
        let intr = shared_types::Intrinsics::from_hfov(64, 48, 60.0);
        let cams: Vec<Camera> = [
            DVec3::new(5.0, 1.0, 2.0),
            DVec3::new(1.0, 6.0, 2.0),
            DVec3::new(-3.0, 2.0, 3.0),
        ]
        .iter()
        .enumerate()
        .map(|(i, &e)| looking_at(&format!("c{i}"), intr, e, DVec3::new(1.0, 2.0, 0.0)))
        .collect();
        let norm = normalisation_for(&cams, &[], 1.0);
        let p = DVec3::new(1.2, 2.1, 0.3);
        for c in &cams {
            let moved = Camera {
                world_to_camera: norm.apply_to_pose(&c.world_to_camera),
                ..c.clone()
            };
            assert!(
                (moved.world_to_camera.centre() - norm.apply(c.world_to_camera.centre())).length()
                    < 1e-12
            );
            let (a, da) = c.project(p).unwrap();
            let (b, db) = moved.project(norm.apply(p)).unwrap();
            assert!((a - b).length() < 1e-9 && (db - da * norm.scale).abs() < 1e-9);
        }
        let mean: f64 = cams
            .iter()
            .map(|c| norm.apply(c.world_to_camera.centre()).length())
            .sum::<f64>()
            / 3.0;
        assert!((mean - 1.0).abs() < 1e-12);
    }
}
