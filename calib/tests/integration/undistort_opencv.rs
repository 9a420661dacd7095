//! Our undistortion (`calib::undistort`, pure Rust) against OpenCV 4.6, which it follows:
//! the pinhole camera against `getOptimalNewCameraMatrix` /
//! `fisheye::estimateNewCameraMatrixForUndistortRectify` (to 1e-6 px), and whole images
//! against `initUndistortRectifyMap` + `remap` (8-bit: at most one level apart; a float
//! image of its own coordinates: the same sample positions), for every lens model of
//! `opencv_models` at 480×270, both fits.

use calib::undistort::{Fit, UndistortMap};
use glam::DVec3;
use image::{Rgb, Rgb32FImage, RgbImage};
use opencv::calib3d;
use opencv::core::{self as cv, Mat, Point2d, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

use crate::opencv_models::lenses;

/// OpenCV's pinhole camera matrix for `camera` and `fit` (OpenCV's pixel convention), as
/// the undistortion did through the `opencv` crate.
fn opencv_pinhole(camera: &Camera, fit: Fit) -> Mat {
    let k = camera_matrix(&camera.intrinsics);
    let d = coefficients(&camera.distortion);
    let size = Size::new(
        camera.intrinsics.width as i32,
        camera.intrinsics.height as i32,
    );
    match camera.distortion {
        Distortion::Fisheye { .. } => {
            let estimate = |balance: f64, fov_scale: f64| {
                let mut p = Mat::default();
                calib3d::estimate_new_camera_matrix_for_undistort_rectify(
                    &k,
                    &d,
                    size,
                    &Mat::eye(3, 3, cv::CV_64F).unwrap(),
                    &mut p,
                    balance,
                    size,
                    fov_scale,
                )
                .unwrap();
                p
            };
            if fit == Fit::ValidPixels {
                return estimate(0.0, 1.0);
            }
            let p = estimate(1.0, 1.0);
            let (w, h) = (size.width as f64, size.height as f64);
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
            let eye = Mat::eye(3, 3, cv::CV_64F).unwrap().to_mat().unwrap();
            let criteria =
                cv::TermCriteria::new(cv::TermCriteria_COUNT + cv::TermCriteria_EPS, 50, 1e-12)
                    .unwrap();
            calib3d::fisheye_undistort_points(&corners, &mut out, &k, &d, &eye, &p, criteria)
                .unwrap();
            let (hw, hh) = (0.5 * w, 0.5 * h);
            let scale = out.iter().fold(0.0f64, |m, q| {
                m.max((q.x - hw).abs() / (hw - 0.5))
                    .max((q.y - hh).abs() / (hh - 0.5))
            });
            if scale > 1.0 { estimate(1.0, scale) } else { p }
        }
        _ => {
            let alpha = if fit == Fit::ValidPixels { 0.0 } else { 1.0 };
            calib3d::get_optimal_new_camera_matrix(&k, &d, size, alpha, size, None, false).unwrap()
        }
    }
}

fn camera_matrix(k: &Intrinsics) -> Mat {
    Mat::from_slice_2d(&[
        [k.fx, 0.0, k.cx - 0.5],
        [0.0, k.fy, k.cy - 0.5],
        [0.0, 0.0, 1.0],
    ])
    .unwrap()
}

fn coefficients(d: &Distortion) -> Mat {
    Mat::from_slice(&d.coefficients())
        .unwrap()
        .try_clone()
        .unwrap()
}

/// OpenCV's undistortion of a `typ` image `src` (`w × h`, bytes) into a new buffer.
fn opencv_undistort<T: cv::DataType + Copy + Default>(
    camera: &Camera,
    fit: Fit,
    src: &[T],
    typ: i32,
) -> Vec<T> {
    let (w, h) = (
        camera.intrinsics.width as i32,
        camera.intrinsics.height as i32,
    );
    let k = camera_matrix(&camera.intrinsics);
    let d = coefficients(&camera.distortion);
    let p = opencv_pinhole(camera, fit);
    let (mut mx, mut my) = (Mat::default(), Mat::default());
    let r = Mat::default();
    let size = Size::new(w, h);
    if let Distortion::Fisheye { .. } = camera.distortion {
        calib3d::fisheye_init_undistort_rectify_map(
            &k,
            &d,
            &r,
            &p,
            size,
            cv::CV_32FC1,
            &mut mx,
            &mut my,
        )
        .unwrap();
    } else {
        calib3d::init_undistort_rectify_map(&k, &d, &r, &p, size, cv::CV_32FC1, &mut mx, &mut my)
            .unwrap();
    }
    let src_mat = Mat::new_rows_cols_with_data(h, src.len() as i32 / h, src).unwrap();
    let src_mat = src_mat.reshape(3, h).unwrap();
    let mut out = Mat::default();
    let border = if fit == Fit::ValidPixels {
        cv::BORDER_REPLICATE
    } else {
        cv::BORDER_CONSTANT
    };
    imgproc::remap(
        &src_mat,
        &mut out,
        &mx,
        &my,
        imgproc::INTER_LINEAR,
        border,
        cv::Scalar::all(0.0),
    )
    .unwrap();
    assert_eq!(out.typ(), typ);
    out.reshape(1, h)
        .unwrap()
        .data_typed::<T>()
        .unwrap()
        .to_vec()
}

fn cameras() -> Vec<(&'static str, Camera)> {
    lenses()
        .into_iter()
        .map(|(name, intrinsics, distortion)| {
            (
                name,
                Camera {
                    name: name.into(),
                    intrinsics: intrinsics.scaled_to(480, 270),
                    distortion,
                    world_to_camera: WorldToCamera::look_at(
                        DVec3::new(0.0, -3.0, 1.0),
                        DVec3::ZERO,
                        DVec3::Z,
                    )
                    .unwrap(),
                },
            )
        })
        .collect()
}

#[test]
fn the_pinhole_camera_is_opencvs() {
    for (name, camera) in cameras() {
        for fit in [Fit::ValidPixels, Fit::AllPixels] {
            let ours = calib::undistort::pinhole_for(&camera, fit).intrinsics;
            let cv = opencv_pinhole(&camera, fit);
            let at = |r, c| *cv.at_2d::<f64>(r, c).unwrap();
            for (a, b, what) in [
                (ours.fx, at(0, 0), "fx"),
                (ours.fy, at(1, 1), "fy"),
                (ours.cx - 0.5, at(0, 2), "cx"),
                (ours.cy - 0.5, at(1, 2), "cy"),
            ] {
                assert!(
                    (a - b).abs() < 1e-6,
                    "{name} {fit:?} {what}: ours {a}, OpenCV {b}"
                );
            }
        }
    }
}

#[test]
fn undistorted_images_are_opencvs() {
    let (w, h) = (480u32, 270u32);
    // A texture with every kind of edge, and an image of its own coordinates.
    let texture = RgbImage::from_fn(w, h, |x, y| {
        let v = |a: u32| (a.wrapping_mul(2654435761) >> 24) as u8;
        Rgb([
            v(x * 7 + y * 131),
            ((x ^ y).wrapping_mul(5)) as u8,
            v(x + y * 977),
        ])
    });
    let coords = Rgb32FImage::from_fn(w, h, |x, y| Rgb([x as f32, y as f32, 1.0]));
    for (name, camera) in cameras() {
        for fit in [Fit::ValidPixels, Fit::AllPixels] {
            let map = UndistortMap::new(&camera, fit);
            let ours = map.apply(&texture).unwrap();
            let cv = opencv_undistort(&camera, fit, texture.as_raw(), cv::CV_8UC3);
            let worst = ours
                .as_raw()
                .iter()
                .zip(&cv)
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap();
            let differing = ours
                .as_raw()
                .iter()
                .zip(&cv)
                .filter(|(a, b)| a != b)
                .count();
            eprintln!("{name} {fit:?}: 8-bit differs at {differing} samples, by at most {worst}");
            assert!(worst <= 1, "{name} {fit:?}: 8-bit samples {worst} apart");
            assert!(
                differing * 1000 < cv.len(),
                "{name} {fit:?}: {differing} samples differ"
            );

            let ours = map.apply(&coords).unwrap();
            let cv = opencv_undistort(&camera, fit, coords.as_raw(), cv::CV_32FC3);
            let far = ours
                .as_raw()
                .iter()
                .zip(&cv)
                .filter(|(a, b)| (*a - *b).abs() > 1e-3)
                .count();
            let worst = ours
                .as_raw()
                .iter()
                .zip(&cv)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            eprintln!("{name} {fit:?}: sample positions differ at {far}, by at most {worst} px");
            // A map entry that lands on a 1/64 px rounding tie may round the other way.
            assert!(worst <= 1.0 / 32.0 + 1e-3, "{name} {fit:?}: {worst} px");
            assert!(
                far * 1000 < cv.len(),
                "{name} {fit:?}: {far} positions differ"
            );
        }
    }
}
