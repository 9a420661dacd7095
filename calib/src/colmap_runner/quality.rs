//! Is a COLMAP solve believable? Checks a model for the signs of a degenerate
//! reconstruction seen on repetitive scenes: lenses no real camera has (fx far from fy,
//! a focal length far from the image size or from the given prior, huge distortion),
//! a large reprojection error, or too few triangulated points. It judges; deciding to
//! retry is [`crate::poses`]'s job.

use std::fmt;

use crate::colmap::ColmapModel;

/// Limits a sound solve stays within.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QualityLimits {
    /// Largest `|fx / fy − 1|` (square pixels: real cameras are within 1 %).
    pub max_aspect_deviation: f64,
    /// Focal length range as a multiple of the image's longest side (fisheye action
    /// cameras ≈ 0.3, phones ≈ 0.8, a long zoom ≈ 3).
    pub focal_ratio: (f64, f64),
    /// Largest relative difference from the prior focal length, when one was given.
    pub max_prior_deviation: f64,
    /// Largest absolute distortion coefficient.
    pub max_distortion: f64,
    /// Largest mean reprojection error of the points, pixels.
    pub max_reprojection_px: f64,
    /// Fewest 3D points.
    pub min_points: usize,
}

impl Default for QualityLimits {
    fn default() -> Self {
        Self {
            max_aspect_deviation: 0.05,
            focal_ratio: (0.2, 5.0),
            max_prior_deviation: 0.25,
            max_distortion: 1.0,
            max_reprojection_px: 2.0,
            min_points: 50,
        }
    }
}

/// One sign of a degenerate solve.
#[derive(Clone, Debug, PartialEq)]
pub enum Degeneracy {
    /// `fx` and `fy` disagree.
    Aspect { image: String, fx: f64, fy: f64 },
    /// The focal length is implausible for the image size.
    Focal {
        image: String,
        focal: f64,
        longest_side: u64,
    },
    /// The focal length is far from the given prior.
    FarFromPrior {
        image: String,
        focal: f64,
        prior: f64,
    },
    /// A distortion coefficient is huge.
    Distortion { image: String, coefficient: f64 },
    /// The points reproject badly.
    Reprojection { mean_px: f64 },
    /// Hardly any points were triangulated.
    FewPoints { count: usize },
}

impl fmt::Display for Degeneracy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Aspect { image, fx, fy } => {
                write!(f, "{image}: fx = {fx:.1} px but fy = {fy:.1} px")
            }
            Self::Focal {
                image,
                focal,
                longest_side,
            } => write!(
                f,
                "{image}: focal length {focal:.1} px for an image {longest_side} px wide"
            ),
            Self::FarFromPrior {
                image,
                focal,
                prior,
            } => write!(
                f,
                "{image}: focal length {focal:.1} px, the prior was {prior:.1} px"
            ),
            Self::Distortion { image, coefficient } => {
                write!(f, "{image}: distortion coefficient {coefficient:.3}")
            }
            Self::Reprojection { mean_px } => {
                write!(f, "mean reprojection error {mean_px:.2} px")
            }
            Self::FewPoints { count } => write!(f, "only {count} 3D points"),
        }
    }
}

/// The signs of degeneracy in `model`, for the cameras of the images named in `check`
/// (COLMAP image names; each camera reported once). `prior_focal` applies to the images in
/// `prior_images`. Empty: the solve looks sound.
pub fn assess(
    model: &ColmapModel,
    check: &[&str],
    prior_focal: Option<(f64, &[&str])>,
    limits: &QualityLimits,
) -> Vec<Degeneracy> {
    let mut out = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for name in check {
        let Some(image) = model.image_by_name(name) else {
            continue;
        };
        if !seen.insert(image.camera_id) {
            continue;
        }
        let Some(cam) = model.cameras.get(&image.camera_id) else {
            continue;
        };
        let p = &cam.params;
        let (fx, fy, extra) = if cam.model.has_single_focal() {
            (p[0], p[0], &p[3..])
        } else {
            (p[0], p[1], &p[4..])
        };
        let image = name.to_string();
        if (fx / fy - 1.0).abs() > limits.max_aspect_deviation || !(fx / fy).is_finite() {
            out.push(Degeneracy::Aspect {
                image: image.clone(),
                fx,
                fy,
            });
        }
        let longest_side = cam.width.max(cam.height);
        let focal = 0.5 * (fx + fy);
        let ratio = focal / longest_side.max(1) as f64;
        if !(limits.focal_ratio.0..=limits.focal_ratio.1).contains(&ratio) {
            out.push(Degeneracy::Focal {
                image: image.clone(),
                focal,
                longest_side,
            });
        }
        if let Some((prior, names)) = prior_focal
            && names.contains(name)
            && (focal / prior - 1.0).abs() > limits.max_prior_deviation
        {
            out.push(Degeneracy::FarFromPrior {
                image: image.clone(),
                focal,
                prior,
            });
        }
        if let Some(&k) = extra
            .iter()
            .max_by(|a, b| a.abs().total_cmp(&b.abs()))
            .filter(|k| k.abs() > limits.max_distortion)
        {
            out.push(Degeneracy::Distortion {
                image,
                coefficient: k,
            });
        }
    }
    let count = model.points3d.len();
    if count < limits.min_points {
        out.push(Degeneracy::FewPoints { count });
    } else {
        let mean_px = model.points3d.values().map(|p| p.error).sum::<f64>() / count as f64;
        if mean_px > limits.max_reprojection_px {
            out.push(Degeneracy::Reprojection { mean_px });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colmap::{CameraModel, ColmapCamera, ColmapImage, ColmapPoint3D};

    fn model(params: Vec<f64>, model: CameraModel, n_points: usize, error: f64) -> ColmapModel {
        let mut m = ColmapModel::default();
        m.cameras.insert(
            1,
            ColmapCamera {
                id: 1,
                model,
                width: 640,
                height: 480,
                params,
            },
        );
        for (id, name) in [(1, "video/cam0.png"), (2, "video/cam1.png")] {
            m.images.insert(
                id,
                ColmapImage {
                    id,
                    qvec: [1.0, 0.0, 0.0, 0.0],
                    tvec: [0.0; 3],
                    camera_id: 1,
                    name: name.into(),
                    points2d: Vec::new(),
                },
            );
        }
        for i in 0..n_points as u64 {
            m.points3d.insert(
                i,
                ColmapPoint3D {
                    id: i,
                    xyz: [0.0; 3],
                    rgb: [0; 3],
                    error,
                    track: Vec::new(),
                },
            );
        }
        m
    }

    const NAMES: [&str; 2] = ["video/cam0.png", "video/cam1.png"];

    #[test]
    fn a_plausible_lens_passes() {
        let m = model(
            vec![502.0, 503.0, 320.0, 240.0, -0.1, 0.02, 0.0, 0.0],
            CameraModel::Opencv,
            500,
            0.6,
        );
        let limits = QualityLimits::default();
        assert_eq!(assess(&m, &NAMES, None, &limits), []);
        assert_eq!(
            assess(&m, &NAMES, Some((500.0, &NAMES[..])), &limits),
            [],
            "within the prior"
        );
    }

    #[test]
    fn degenerate_lenses_and_points_are_named_once_per_camera() {
        // What COLMAP gave on the repetitive room: fy ≈ 0.4·fx, tiny focal lengths.
        let m = model(
            vec![91.5, 60.1, 320.0, 240.0, -0.01, 0.0, -0.02, 1.6],
            CameraModel::Opencv,
            20,
            0.5,
        );
        let found = assess(
            &m,
            &NAMES,
            Some((500.0, &NAMES[..])),
            &QualityLimits::default(),
        );
        assert_eq!(found.len(), 5, "{found:?}");
        assert!(matches!(found[0], Degeneracy::Aspect { .. }));
        assert!(matches!(
            found[1],
            Degeneracy::Focal {
                longest_side: 640,
                ..
            }
        ));
        assert!(matches!(found[2], Degeneracy::FarFromPrior { .. }));
        assert!(
            matches!(found[3], Degeneracy::Distortion { coefficient, .. } if coefficient == 1.6)
        );
        assert_eq!(found[4], Degeneracy::FewPoints { count: 20 });
        assert!(
            found[0]
                .to_string()
                .contains("fx = 91.5 px but fy = 60.1 px")
        );

        let m = model(
            vec![500.0, 320.0, 240.0, 0.0],
            CameraModel::SimpleRadial,
            100,
            3.5,
        );
        assert_eq!(
            assess(&m, &NAMES, None, &QualityLimits::default()),
            [Degeneracy::Reprojection { mean_px: 3.5 }]
        );
    }
}
