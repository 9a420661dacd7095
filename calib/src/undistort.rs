//! Undistortion: a distorted camera + image → a pinhole camera + image, so the engine only
//! ever sees pinhole cameras. Happens exactly once, after the poses stage (see
//! `docs/poses.md`): build one [`UndistortMap`] per video camera and apply it to every frame.
//!
//! Done by OpenCV (Debian's 4.6 through the `opencv` crate): the pinhole camera comes from
//! `getOptimalNewCameraMatrix` (radial-tangential) or
//! `fisheye::estimateNewCameraMatrixForUndistortRectify` (fisheye), the map from
//! `initUndistortRectifyMap` / `fisheye::initUndistortRectifyMap` (float maps) and the
//! resampling from `remap` (bilinear; black outside the lens's view, edge pixels replicated
//! for [`Fit::ValidPixels`], whose OpenCV rectangle overshoots the source by up to ~0.2 px).
//! `remap` runs on OpenCV's own pool (TBB) even inside rayon: measured, no oversubscription
//! cost on 2 cores, so OpenCV's default thread count is kept.
//!
//! Pixel convention: our cameras put a pixel's centre at integer + 0.5 (COLMAP's and the
//! engine's); OpenCV puts it at the integer. The principal point is shifted by 0.5 on the way
//! into OpenCV and back on the way out; the tests pin this to < 0.05 px.

use std::ffi::c_void;

use glam::DVec2;
use image::{ImageBuffer, Pixel};
use opencv::calib3d;
use opencv::core::{self as cv, Mat, Point2d, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};
use shared_types::{Camera, Distortion, Intrinsics};

/// How the pinhole camera's field of view is chosen (OpenCV's `alpha` / `balance` 0 / 1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fit {
    /// Only pixels the lens saw: no black borders, the corners are cropped (`alpha = 0`).
    #[default]
    ValidPixels,
    /// Every source pixel kept: black borders where the lens saw nothing (`alpha = 1`).
    AllPixels,
    /// Same focal length and principal point as the distorted camera.
    KeepFocal,
}

#[derive(Clone, Debug, thiserror::Error)]
pub enum UndistortError {
    #[error(
        "image is {got_w}×{got_h} but camera {camera} is calibrated for {want_w}×{want_h}: resize the \
         frames to the working size first, or scale the camera with Intrinsics::scaled_to"
    )]
    SizeMismatch {
        camera: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    /// OpenCV refused the camera (or gave a degenerate result) while building its map.
    #[error(
        "cannot undistort camera {camera}: OpenCV {step} failed: {message}; check its intrinsics \
         and distortion coefficients in the poses stage's cameras.json"
    )]
    OpenCv {
        camera: String,
        step: &'static str,
        message: String,
    },
    /// Intrinsics or coefficients no lens has (zero size, non-positive focal, NaN, …).
    #[error(
        "cannot undistort camera {camera}: {reason}; check its intrinsics and distortion \
         coefficients in the poses stage's cameras.json"
    )]
    InvalidCamera { camera: String, reason: String },
}

/// A precomputed remap from one distorted camera to its pinhole twin (same size).
#[derive(Clone, Debug)]
pub struct UndistortMap {
    source: Camera,
    pinhole: Camera,
    /// OpenCV's float maps (row-major source x and y per output pixel, OpenCV's pixel
    /// convention), or why they could not be built (reported by [`UndistortMap::apply`]).
    maps: Result<Maps, UndistortError>,
}

#[derive(Clone, Debug)]
struct Maps {
    x: Vec<f32>,
    y: Vec<f32>,
    /// `BORDER_REPLICATE` for [`Fit::ValidPixels`] (OpenCV's rectangle, from a 9×9 grid of
    /// border points, overshoots the source by a fraction of a pixel at a few edge pixels,
    /// which `BORDER_CONSTANT` would darken), else `BORDER_CONSTANT` (black outside).
    border: i32,
}

/// Intrinsics → OpenCV's 3×3 camera matrix (pixel centre at the integer).
fn to_cv_matrix(k: &Intrinsics) -> opencv::Result<Mat> {
    Mat::from_slice_2d(&[
        [k.fx, 0.0, k.cx - 0.5],
        [0.0, k.fy, k.cy - 0.5],
        [0.0, 0.0, 1.0],
    ])
}

/// OpenCV's camera matrix → intrinsics of a `width × height` image (pixel centre at +0.5).
fn from_cv_matrix(m: &Mat, width: u32, height: u32) -> opencv::Result<Intrinsics> {
    let at = |r, c| m.at_2d::<f64>(r, c).copied();
    Ok(Intrinsics {
        width,
        height,
        fx: at(0, 0)?,
        fy: at(1, 1)?,
        cx: at(0, 2)? + 0.5,
        cy: at(1, 2)? + 0.5,
    })
}

/// The distortion coefficients in OpenCV's order, every non-zero term included (`[k1 k2
/// p1 p2 k3]`, 8 with the rational `k4..k6`, 12 with thin prism, 14 with a tilted sensor;
/// fisheye `[k1..k4]`; none for a pinhole).
fn coefficients(d: &Distortion) -> Vec<f64> {
    d.coefficients()
}

/// [`coefficients`] as an OpenCV vector (five zeros for a pinhole).
fn to_cv_coefficients(d: &Distortion) -> opencv::Result<Mat> {
    let c = coefficients(d);
    let c = if c.is_empty() { vec![0.0; 5] } else { c };
    Mat::from_slice(&c).and_then(|m| m.try_clone())
}

fn cv_size(k: &Intrinsics) -> Size {
    Size::new(k.width as i32, k.height as i32)
}

/// The OpenCV call that failed, as a typed error naming the camera.
fn cv_error(camera: &Camera, step: &'static str) -> impl FnOnce(opencv::Error) -> UndistortError {
    let name = camera.name.clone();
    move |e| UndistortError::OpenCv {
        camera: name,
        step,
        message: e.message,
    }
}

/// Refuse cameras no lens has before OpenCV sees them (it would return NaN maps).
fn check_camera(camera: &Camera) -> Result<(), UndistortError> {
    let k = &camera.intrinsics;
    let coefficients = coefficients(&camera.distortion);
    let reason = if k.width < 2 || k.height < 2 {
        format!("its image is {}×{} pixels", k.width, k.height)
    } else if !(k.fx.is_finite() && k.fy.is_finite() && k.fx > 0.0 && k.fy > 0.0) {
        format!("its focal length ({}, {}) is not positive", k.fx, k.fy)
    } else if !(k.cx.is_finite() && k.cy.is_finite()) {
        format!("its principal point ({}, {}) is not finite", k.cx, k.cy)
    } else if !coefficients.iter().all(|c| c.is_finite()) {
        format!("its distortion coefficients {coefficients:?} are not finite")
    } else {
        return Ok(());
    };
    Err(UndistortError::InvalidCamera {
        camera: camera.name.clone(),
        reason,
    })
}

/// The pinhole intrinsics for `camera` and `fit` in OpenCV's convention.
fn new_cv_matrix(camera: &Camera, fit: Fit) -> Result<Mat, UndistortError> {
    check_camera(camera)?;
    let intr = &camera.intrinsics;
    let k = to_cv_matrix(intr).map_err(cv_error(camera, "camera matrix"))?;
    let d = to_cv_coefficients(&camera.distortion).map_err(cv_error(camera, "coefficients"))?;
    let size = cv_size(intr);
    let new = match (fit, camera.distortion) {
        (_, Distortion::None) | (Fit::KeepFocal, _) => k,
        (_, Distortion::Opencv { .. }) => {
            let alpha = if fit == Fit::ValidPixels { 0.0 } else { 1.0 };
            calib3d::get_optimal_new_camera_matrix(&k, &d, size, alpha, size, None, false)
                .map_err(cv_error(camera, "getOptimalNewCameraMatrix"))?
        }
        (_, Distortion::Fisheye { .. }) => {
            let fisheye = |balance: f64, fov_scale: f64| -> opencv::Result<Mat> {
                let mut p = Mat::default();
                calib3d::estimate_new_camera_matrix_for_undistort_rectify(
                    &k,
                    &d,
                    size,
                    &Mat::eye(3, 3, cv::CV_64F)?,
                    &mut p,
                    balance,
                    size,
                    fov_scale,
                )?;
                Ok(p)
            };
            let step = "fisheye::estimateNewCameraMatrixForUndistortRectify";
            if fit == Fit::ValidPixels {
                // balance 0 maps the edges' midpoints onto the output's edges: no black border.
                fisheye(0.0, 1.0).map_err(cv_error(camera, step))?
            } else {
                // balance 1 only looks at the edges' midpoints; widen it (fov_scale, which
                // scales about the image centre) until the source's corners are inside too.
                let p = fisheye(1.0, 1.0).map_err(cv_error(camera, step))?;
                let scale = fisheye_corner_overflow(camera, &k, &d, &p)
                    .map_err(cv_error(camera, "fisheye::undistortPoints"))?;
                if scale > 1.0 {
                    fisheye(1.0, scale).map_err(cv_error(camera, step))?
                } else {
                    p
                }
            }
        }
    };
    let finite =
        (0..3).all(|r| (0..3).all(|c| new.at_2d::<f64>(r, c).is_ok_and(|v| v.is_finite())));
    let positive = new.at_2d::<f64>(0, 0).is_ok_and(|v| *v > 0.0)
        && new.at_2d::<f64>(1, 1).is_ok_and(|v| *v > 0.0);
    if !(finite && positive) {
        return Err(UndistortError::OpenCv {
            camera: camera.name.clone(),
            step: "new camera matrix",
            message: format!("degenerate result {:?}", new.data_typed::<f64>().ok()),
        });
    }
    Ok(new)
}

/// How far (as a factor ≥ 0 of the half-size) the source's corner pixels land from the
/// centre of the pinhole image `p`: > 1 means some corner is outside.
fn fisheye_corner_overflow(camera: &Camera, k: &Mat, d: &Mat, p: &Mat) -> opencv::Result<f64> {
    let (w, h) = (
        camera.intrinsics.width as f64,
        camera.intrinsics.height as f64,
    );
    let corners: Vector<Point2d> = [
        (0.0, 0.0),
        (w - 1.0, 0.0),
        (0.0, h - 1.0),
        (w - 1.0, h - 1.0),
    ]
    .into_iter()
    .map(|(x, y)| Point2d::new(x, y))
    .collect();
    let mut out: Vector<Point2d> = Vector::new();
    let eye = Mat::eye(3, 3, cv::CV_64F)?.to_mat()?;
    // OpenCV 4.6's default criteria, tightened.
    let criteria = cv::TermCriteria::new(cv::TermCriteria_COUNT + cv::TermCriteria_EPS, 50, 1e-12)?;
    calib3d::fisheye_undistort_points(&corners, &mut out, k, d, &eye, p, criteria)?;
    // OpenCV's estimate centres the pinhole image at (w/2, h/2) and fov_scale scales about it.
    let (hw, hh) = (0.5 * w, 0.5 * h);
    Ok(out.iter().fold(0.0f64, |m, q| {
        m.max((q.x - hw).abs() / (hw - 0.5))
            .max((q.y - hh).abs() / (hh - 0.5))
    }))
}

/// The pinhole camera [`UndistortMap::new`] would produce, without building the map
/// (the distorted camera's own intrinsics if OpenCV refuses it).
pub fn pinhole_for(camera: &Camera, fit: Fit) -> Camera {
    pinhole_with(camera, new_cv_matrix(camera, fit).ok().as_ref())
}

/// `camera` made pinhole with the OpenCV camera matrix `new` (its own intrinsics without one).
fn pinhole_with(camera: &Camera, new: Option<&Mat>) -> Camera {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    Camera {
        intrinsics: new
            .and_then(|m| from_cv_matrix(m, w, h).ok())
            .unwrap_or(camera.intrinsics),
        distortion: Distortion::None,
        ..camera.clone()
    }
}

/// OpenCV's float maps from `camera` to the pinhole camera matrix `new`.
fn build_maps(camera: &Camera, new: &Mat, fit: Fit) -> Result<Maps, UndistortError> {
    let intr = &camera.intrinsics;
    let k = to_cv_matrix(intr).map_err(cv_error(camera, "camera matrix"))?;
    let d = to_cv_coefficients(&camera.distortion).map_err(cv_error(camera, "coefficients"))?;
    let r = Mat::default();
    let (mut mx, mut my) = (Mat::default(), Mat::default());
    let size = cv_size(intr);
    let m1type = cv::CV_32FC1;
    if let Distortion::Fisheye { .. } = camera.distortion {
        calib3d::fisheye_init_undistort_rectify_map(
            &k, &d, &r, new, size, m1type, &mut mx, &mut my,
        )
        .map_err(cv_error(camera, "fisheye::initUndistortRectifyMap"))?;
    } else {
        calib3d::init_undistort_rectify_map(&k, &d, &r, new, size, m1type, &mut mx, &mut my)
            .map_err(cv_error(camera, "initUndistortRectifyMap"))?;
    }
    let take = |m: &Mat| m.data_typed::<f32>().map(<[f32]>::to_vec);
    Ok(Maps {
        x: take(&mx).map_err(cv_error(camera, "map x"))?,
        y: take(&my).map_err(cv_error(camera, "map y"))?,
        border: if fit == Fit::ValidPixels {
            cv::BORDER_REPLICATE
        } else {
            cv::BORDER_CONSTANT
        },
    })
}

impl UndistortMap {
    /// Build the map for `camera` (its intrinsics must match the frames' size). An OpenCV
    /// failure is kept and returned by [`UndistortMap::apply`].
    pub fn new(camera: &Camera, fit: Fit) -> Self {
        let new = new_cv_matrix(camera, fit);
        Self {
            source: camera.clone(),
            pinhole: pinhole_with(camera, new.as_ref().ok()),
            maps: new.and_then(|m| build_maps(camera, &m, fit)),
        }
    }

    /// The distorted camera this map starts from.
    pub fn source(&self) -> &Camera {
        &self.source
    }

    /// The pinhole camera of the undistorted images (same name, pose and size).
    pub fn pinhole(&self) -> &Camera {
        &self.pinhole
    }

    /// Source position (pixel-centre convention) of output pixel position `p`, from the
    /// camera models (`shared_types::Distortion::distort`); the map agrees to OpenCV's 1/32 px.
    pub fn source_position(&self, p: DVec2) -> DVec2 {
        let n = self.pinhole.intrinsics.to_normalised(p);
        self.source
            .intrinsics
            .to_pixels(self.source.distortion.distort(n))
    }

    /// Undistort one image (`u8`, `u16` or `f32` samples, 1–4 channels) with OpenCV's
    /// bilinear `remap`; pixels the lens did not see are 0 (none with [`Fit::ValidPixels`]).
    pub fn apply<P, S>(
        &self,
        image: &ImageBuffer<P, Vec<S>>,
    ) -> Result<ImageBuffer<P, Vec<S>>, UndistortError>
    where
        P: Pixel<Subpixel = S> + Send + Sync,
        S: Sample,
    {
        let (w, h) = (self.source.intrinsics.width, self.source.intrinsics.height);
        if image.dimensions() != (w, h) {
            return Err(UndistortError::SizeMismatch {
                camera: self.source.name.clone(),
                got_w: image.width(),
                got_h: image.height(),
                want_w: w,
                want_h: h,
            });
        }
        let maps = self.maps.as_ref().map_err(Clone::clone)?;
        let mut out = vec![S::ZERO; image.as_raw().len()];
        if !out.is_empty() {
            self.remap(image.as_raw(), &mut out, P::CHANNEL_COUNT, maps)
                .map_err(cv_error(&self.source, "remap"))?;
        }
        Ok(ImageBuffer::from_raw(w, h, out).expect("same size as the input"))
    }

    /// `remap` of the `channels`-channel image `src` into `dst` (both `width × height`).
    fn remap<S: Sample>(
        &self,
        src: &[S],
        dst: &mut [S],
        channels: u8,
        maps: &Maps,
    ) -> opencv::Result<()> {
        let (w, h) = (
            self.source.intrinsics.width as i32,
            self.source.intrinsics.height as i32,
        );
        let typ = cv::CV_MAKETYPE(S::CV_DEPTH, channels as i32);
        let step = w as usize * channels as usize * std::mem::size_of::<S>();
        // SAFETY: both buffers hold exactly `h` rows of `step` bytes of `typ` pixels and
        // outlive the Mats that borrow them (dropped at the end of this function); `src` is
        // only read (remap's input).
        let src_mat = unsafe {
            Mat::new_rows_cols_with_data_unsafe(h, w, typ, src.as_ptr() as *mut c_void, step)?
        };
        // SAFETY: as above; `dst` is borrowed mutably for the Mat's whole life.
        let mut dst_mat = unsafe {
            Mat::new_rows_cols_with_data_unsafe(h, w, typ, dst.as_mut_ptr() as *mut c_void, step)?
        };
        let map_x = Mat::new_rows_cols_with_data(h, w, &maps.x)?;
        let map_y = Mat::new_rows_cols_with_data(h, w, &maps.y)?;
        imgproc::remap(
            &src_mat,
            &mut dst_mat,
            &map_x,
            &map_y,
            imgproc::INTER_LINEAR,
            maps.border,
            cv::Scalar::all(0.0),
        )?;
        // remap writes in place when the output already has the right size and type.
        if dst_mat.data() != dst.as_ptr().cast() {
            return Err(opencv::Error::new(
                cv::StsError,
                "remap reallocated its output",
            ));
        }
        Ok(())
    }
}

/// Undistort one image of `camera`: the pinhole camera and the undistorted image.
pub fn undistort_image<P, S>(
    camera: &Camera,
    image: &ImageBuffer<P, Vec<S>>,
    fit: Fit,
) -> Result<(Camera, ImageBuffer<P, Vec<S>>), UndistortError>
where
    P: Pixel<Subpixel = S> + Send + Sync,
    S: Sample,
{
    let map = UndistortMap::new(camera, fit);
    let out = map.apply(image)?;
    Ok((map.pinhole, out))
}

/// Pixel sample types [`UndistortMap::apply`] handles (`u8`, `u16`, `f32`), with their
/// OpenCV depth.
pub trait Sample: image::Primitive + Send + Sync {
    /// OpenCV's depth constant (`CV_8U`, …).
    const CV_DEPTH: i32;
    /// Black.
    const ZERO: Self;
}

impl Sample for u8 {
    const ZERO: Self = 0;
    const CV_DEPTH: i32 = cv::CV_8U;
}

impl Sample for u16 {
    const ZERO: Self = 0;
    const CV_DEPTH: i32 = cv::CV_16U;
}

impl Sample for f32 {
    const ZERO: Self = 0.0;
    const CV_DEPTH: i32 = cv::CV_32F;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::looking_at;
    use glam::DVec3;

    fn cam(d: Distortion) -> Camera {
        let intrinsics = Intrinsics::from_hfov(320, 240, 80.0);
        Camera {
            distortion: d,
            ..looking_at("c", intrinsics, DVec3::new(0.0, -3.0, 1.0), DVec3::ZERO)
        }
    }

    #[test]
    fn pinhole_and_distorted_cameras_see_world_points_where_the_map_says() {
        for d in [
            Distortion::radial_tangential(-0.25, 0.07, 1e-3, -5e-4, 0.0),
            Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: 0.0,
            },
        ] {
            for fit in [Fit::ValidPixels, Fit::AllPixels, Fit::KeepFocal] {
                let c = cam(d);
                let map = UndistortMap::new(&c, fit);
                assert!(map.pinhole().distortion.is_none());
                assert_eq!(map.pinhole(), &pinhole_for(&c, fit));
                for p in [
                    DVec3::new(0.3, 0.2, 0.5),
                    DVec3::new(-0.8, 0.5, 1.2),
                    DVec3::ZERO,
                ] {
                    let (out, _) = map.pinhole().project(p).unwrap();
                    let (src, _) = c.project(p).unwrap();
                    assert!(
                        (map.source_position(out) - src).length() < 1e-9,
                        "{d:?} {fit:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn valid_pixels_fit_leaves_no_holes_and_all_pixels_keeps_the_corners() {
        let c = cam(Distortion::radial_tangential(-0.3, 0.08, 0.0, 0.0, 0.0));
        let img = image::RgbImage::from_pixel(320, 240, image::Rgb([200, 100, 50]));
        let (_, inner) = undistort_image(&c, &img, Fit::ValidPixels).unwrap();
        let holes = inner.pixels().filter(|p| p.0 == [0, 0, 0]).count();
        assert!(holes <= 320 * 240 / 500, "{holes} black pixels");
        let (pin, outer) = undistort_image(&c, &img, Fit::AllPixels).unwrap();
        assert!(outer.pixels().filter(|p| p.0 == [0, 0, 0]).count() > 1000);
        // Barrel distortion: the "all pixels" pinhole is wider (shorter focal length).
        assert!(pin.intrinsics.fx < c.intrinsics.fx);
        let wrong = image::RgbImage::new(100, 100);
        assert!(matches!(
            UndistortMap::new(&c, Fit::ValidPixels).apply(&wrong),
            Err(UndistortError::SizeMismatch { .. })
        ));
    }
}
