//! Is a COLMAP solve believable? Checks a model for the signs of a degenerate
//! reconstruction seen on repetitive scenes: lenses no real camera has (fx far from fy,
//! a focal length far from the image size or from the given prior, huge distortion),
//! a large reprojection error, or too few triangulated points; and, where the lenses are
//! known, video cameras their known lens does not fit once it is held fixed. It judges;
//! deciding to retry is [`crate::poses`]'s job.

use std::fmt;

use glam::{DVec2, DVec3};

use crate::colmap::{ColmapModel, INVALID_POINT3D_ID};

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
    /// A video camera whose known lens is held fixed may reproject (median) at most this
    /// many times what it did in the free solve, plus [`Self::known_lens_slack_px`].
    pub known_lens_ratio: f64,
    pub known_lens_slack_px: f64,
    /// ... and at most this many pixels (median) in any case: a free solve that is itself
    /// poor proves nothing.
    pub known_lens_max_px: f64,
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
            // Medians measured on the synthetic known-lens rig (480×360, 12 solves): sound
            // ones 0.08–0.17 px against 0.08–0.12 px free; wrong ones (poses off by 1–130°)
            // 0.4–28 px, their free solves 0.12–1.4 px.
            known_lens_ratio: 2.0,
            known_lens_slack_px: 0.25,
            known_lens_max_px: 1.0,
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
    /// With its known lens held fixed, a video camera reprojects far worse than in the
    /// free solve (medians): the mapper's solve leaned on a lens the camera does not have.
    KnownLens {
        image: String,
        median_px: f64,
        free_px: f64,
    },
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
            Self::KnownLens {
                image,
                median_px,
                free_px,
            } => write!(
                f,
                "{image}: with its known lens held fixed it reprojects {median_px:.2} px \
                 (median) against {free_px:.2} px in the free solve (a wrong solve, or a lens \
                 calibrated at another resolution, zoom or stabilisation setting)"
            ),
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
        let mean_px = mean_point_error(model);
        if mean_px > limits.max_reprojection_px {
            out.push(Degeneracy::Reprojection { mean_px });
        }
    }
    out
}

/// The mean reprojection error (pixels) of the points `model` triangulated, as COLMAP's
/// mapper recorded it.
pub fn mean_point_error(model: &ColmapModel) -> f64 {
    let n = model.points3d.len().max(1) as f64;
    model.points3d.values().map(|p| p.error).sum::<f64>() / n
}

/// The median reprojection error (pixels) of the image named `name`: each of its features
/// with a 3D point against that point projected through the image's camera, lens and
/// distortion included (infinite when a point is behind it). A median, because a bundle
/// adjustment with squared loss leaves a few points far off (even behind the camera) in a
/// sound solve. `None` when the image is not in `model`, sees no point, or its camera
/// model cannot be converted.
pub fn image_reprojection_px(model: &ColmapModel, name: &str) -> Option<f64> {
    let image = model.image_by_name(name)?;
    let camera = crate::convert::camera_from_image(model, image, name).ok()?;
    let mut errors: Vec<f64> = image
        .points2d
        .iter()
        .filter(|p| p.point3d_id != INVALID_POINT3D_ID)
        .filter_map(|p| {
            let point = model.points3d.get(&p.point3d_id)?;
            Some(match camera.project(DVec3::from(point.xyz)) {
                Some((uv, _)) => (uv - DVec2::from(p.xy)).length(),
                None => f64::INFINITY,
            })
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    let n = errors.len();
    (n > 0).then(|| 0.5 * (errors[(n - 1) / 2] + errors[n / 2]))
}

/// The video images of `check` (COLMAP names) that `adjusted`, the model bundle-adjusted
/// with their known lenses held fixed, fits much worse than `free`, the mapper's model
/// with the lenses it solved (median errors, image by image): a pose COLMAP found for a
/// lens the camera does not have.
pub fn known_lens_misfits(
    adjusted: &ColmapModel,
    free: &ColmapModel,
    check: &[&str],
    limits: &QualityLimits,
) -> Vec<Degeneracy> {
    check
        .iter()
        .filter_map(|name| {
            let median_px = image_reprojection_px(adjusted, name)?;
            let free_px = image_reprojection_px(free, name).unwrap_or(0.0);
            let limit = limits.known_lens_ratio * free_px + limits.known_lens_slack_px;
            let limit = limit.min(limits.known_lens_max_px);
            (median_px > limit).then(|| Degeneracy::KnownLens {
                image: name.to_string(),
                median_px,
                free_px,
            })
        })
        .collect()
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

    /// One OPENCV camera at the origin looking down +z seeing a grid of points, observed
    /// where COLMAP's OPENCV model puts them (written out here, not through the engine),
    /// shifted by `shift` pixels in x; `behind` puts the last point behind the camera.
    fn seen_grid(shift: f64, behind: bool) -> ColmapModel {
        let (f, cx, cy, k1, k2, p1, p2) = (342.76, 240.0, 180.0, -0.12, 0.03, 0.001, -0.002);
        let mut m = ColmapModel::default();
        m.cameras.insert(
            7,
            ColmapCamera {
                id: 7,
                model: CameraModel::Opencv,
                width: 480,
                height: 360,
                params: vec![f, f, cx, cy, k1, k2, p1, p2],
            },
        );
        let mut points2d = Vec::new();
        for (id, (i, j)) in (0..5).flat_map(|i| (0..4).map(move |j| (i, j))).enumerate() {
            let xyz = [
                0.3 * i as f64 - 0.6,
                0.25 * j as f64 - 0.4,
                3.0 + 0.1 * i as f64,
            ];
            let (x, y) = (xyz[0] / xyz[2], xyz[1] / xyz[2]);
            let r2 = x * x + y * y;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let uv = [
                f * (x * radial + dx) + cx + shift,
                f * (y * radial + dy) + cy,
            ];
            let xyz = if behind && id == 19 {
                [0.0, 0.0, -2.0]
            } else {
                xyz
            };
            m.points3d.insert(
                id as u64,
                ColmapPoint3D {
                    id: id as u64,
                    xyz,
                    rgb: [0; 3],
                    error: 0.2,
                    track: Vec::new(),
                },
            );
            points2d.push(crate::colmap::Point2D {
                xy: uv,
                point3d_id: id as u64,
            });
        }
        points2d.push(crate::colmap::Point2D {
            xy: [1.0, 1.0],
            point3d_id: INVALID_POINT3D_ID,
        });
        m.images.insert(
            3,
            ColmapImage {
                id: 3,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0; 3],
                camera_id: 7,
                name: "video/cam0/cam0.png".into(),
                points2d,
            },
        );
        m
    }

    #[test]
    fn reprojection_goes_through_the_lens_and_misfits_are_named() {
        let name = "video/cam0/cam0.png";
        let exact = image_reprojection_px(&seen_grid(0.0, false), name).unwrap();
        assert!(exact < 1e-9, "{exact}");
        let off = image_reprojection_px(&seen_grid(1.5, false), name).unwrap();
        assert!((off - 1.5).abs() < 1e-9, "{off}");
        assert_eq!(
            image_reprojection_px(&seen_grid(0.0, false), "nope.png"),
            None
        );
        let limits = QualityLimits::default();
        // The free solve fits at 0.2 px: the limit is 2 × 0.2 + 0.25 = 0.65 px.
        let free = seen_grid(0.2, false);
        assert!(known_lens_misfits(&seen_grid(0.6, false), &free, &[name], &limits).is_empty());
        let misfit = known_lens_misfits(&seen_grid(1.5, false), &free, &[name], &limits);
        assert_eq!(
            misfit,
            vec![Degeneracy::KnownLens {
                image: name.into(),
                median_px: off,
                free_px: image_reprojection_px(&free, name).unwrap(),
            }]
        );
        assert!(misfit[0].to_string().contains("1.50 px"), "{}", misfit[0]);
        // A poor free solve proves nothing: over 1 px is a misfit whatever it fitted.
        let poor = seen_grid(0.9, false);
        assert_eq!(
            known_lens_misfits(&seen_grid(1.1, false), &poor, &[name], &limits).len(),
            1
        );
        // A point behind the camera is one bad observation, not a wrong solve; a median of
        // them is.
        let behind = seen_grid(0.0, true);
        assert_eq!(image_reprojection_px(&behind, name), Some(0.0));
        assert!(known_lens_misfits(&behind, &free, &[name], &limits).is_empty());
        let mut all_behind = seen_grid(0.0, false);
        for p in all_behind.points3d.values_mut() {
            p.xyz[2] = -p.xyz[2];
        }
        assert!(
            matches!(&known_lens_misfits(&all_behind, &free, &[name], &limits)[..],
                [Degeneracy::KnownLens { median_px, .. }] if median_px.is_infinite())
        );
    }
}
