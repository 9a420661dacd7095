//! A calibration as OpenCV writes it with the rational model: `cv::calibrateCamera` with
//! `CALIB_RATIONAL_MODEL` on a simulated ChArUco/chessboard session of a wide 1920×1080
//! lens (8 coefficients, k4..k6 ≠ 0), saved by `cv::FileStorage` as YAML. It imports
//! (nothing refused), projects exactly like `cv::projectPoints` with the same numbers, goes
//! through the poses stage's import to the working size, and undistorts through OpenCV.

use std::collections::BTreeMap;

use calib::import::import_calibration;
use calib::poses::{CaptureCamera, write_imported};
use calib::undistort::{Fit, UndistortMap};
use glam::{DVec2, DVec3};
use opencv::calib3d;
use opencv::core::{self as cv, Mat, Point2d, Point2f, Point3d, Point3f, Size, Vector};
use opencv::prelude::*;

const SIZE: (i32, i32) = (1920, 1080);

/// The lens being calibrated: OpenCV's rational model, strong barrel (a GoPro-like wide).
fn true_lens() -> (Mat, Mat) {
    let k =
        Mat::from_slice_2d(&[[1010.0, 0.0, 958.4], [0.0, 1008.0, 542.7], [0.0, 0.0, 1.0]]).unwrap();
    let d = Mat::from_slice(&[0.62, 0.21, 8e-4, -4e-4, 0.004, 0.95, 0.38, 0.03])
        .unwrap()
        .try_clone()
        .unwrap();
    (k, d)
}

/// A 12×9-corner board, 50 mm squares, in its own frame (z = 0).
fn board() -> Vec<Point3f> {
    let mut pts = Vec::new();
    for j in 0..9 {
        for i in 0..12 {
            pts.push(Point3f::new(i as f32 * 0.05, j as f32 * 0.05, 0.0));
        }
    }
    pts
}

fn project(pts: &[Point3f], r: &Mat, t: &Mat, k: &Mat, d: &Mat) -> Vec<Point2d> {
    let object: Vector<Point3d> = pts
        .iter()
        .map(|p| Point3d::new(p.x as f64, p.y as f64, p.z as f64))
        .collect();
    let mut image: Vector<Point2d> = Vector::new();
    calib3d::project_points_def(&object, r, t, k, d, &mut image).unwrap();
    image.to_vec()
}

fn vec3(v: [f64; 3]) -> Mat {
    Mat::from_slice(&v).unwrap().try_clone().unwrap()
}

/// Board poses that sweep the frame, corners included, tilted up to ~35°.
fn views() -> Vec<(Mat, Mat)> {
    let mut out = Vec::new();
    for (n, (x, y)) in [
        (-0.75, -0.45),
        (0.2, -0.45),
        (-0.75, 0.1),
        (0.2, 0.1),
        (-0.27, -0.17),
        (-0.9, -0.5),
        (0.35, -0.5),
        (-0.9, 0.2),
        (0.35, 0.2),
        (-0.3, -0.6),
        (-0.3, 0.25),
        (-1.0, -0.17),
        (0.45, -0.17),
    ]
    .into_iter()
    .enumerate()
    {
        let tilt = 0.6 * ((n % 5) as f64 - 2.0) / 2.0;
        let r = vec3([0.35 * (n % 3) as f64 - 0.35, tilt, 0.05 * n as f64 - 0.3]);
        let t = vec3([x, y, 0.75 + 0.05 * (n % 4) as f64]);
        out.push((r, t));
    }
    out
}

/// Calibrate with OpenCV's rational model and write the result as OpenCV YAML, two
/// cameras (`gopro0`, `gopro1`) placed at the first two board poses (the board is the world).
fn calibrate_and_write(path: &std::path::Path) -> (f64, Mat, Mat, Vec<(Mat, Mat)>) {
    let (k_true, d_true) = true_lens();
    let board = board();
    let mut object: Vector<Vector<Point3f>> = Vector::new();
    let mut image: Vector<Vector<Point2f>> = Vector::new();
    let mut used = Vec::new();
    for (r, t) in views() {
        let seen = project(&board, &r, &t, &k_true, &d_true);
        let inside = seen.iter().all(|p| {
            p.x > 5.0 && p.y > 5.0 && p.x < SIZE.0 as f64 - 5.0 && p.y < SIZE.1 as f64 - 5.0
        });
        if inside {
            object.push(board.iter().copied().collect());
            image.push(
                seen.iter()
                    .map(|p| Point2f::new(p.x as f32, p.y as f32))
                    .collect(),
            );
            used.push((r, t));
        }
    }
    assert!(
        used.len() >= 8,
        "only {} views inside the frame",
        used.len()
    );
    let mut k = Mat::default();
    let mut d = Mat::default();
    let (mut rvecs, mut tvecs): (Vector<Mat>, Vector<Mat>) = (Vector::new(), Vector::new());
    let criteria =
        cv::TermCriteria::new(cv::TermCriteria_COUNT + cv::TermCriteria_EPS, 200, 1e-14).unwrap();
    let rms = calib3d::calibrate_camera(
        &object,
        &image,
        Size::new(SIZE.0, SIZE.1),
        &mut k,
        &mut d,
        &mut rvecs,
        &mut tvecs,
        calib3d::CALIB_RATIONAL_MODEL,
        criteria,
    )
    .unwrap();
    let poses: Vec<(Mat, Mat)> = rvecs.iter().zip(tvecs.iter()).take(2).collect();
    let mut fs = cv::FileStorage::new_def(path.to_str().unwrap(), cv::FileStorage_WRITE).unwrap();
    fs.start_write_struct("cameras", cv::FileNode_MAP, "")
        .unwrap();
    for (i, (r, t)) in poses.iter().enumerate() {
        fs.start_write_struct(&format!("gopro{i}"), cv::FileNode_MAP, "")
            .unwrap();
        cv::write_i32(&mut fs, "image_width", SIZE.0).unwrap();
        cv::write_i32(&mut fs, "image_height", SIZE.1).unwrap();
        cv::write_mat(&mut fs, "camera_matrix", &k).unwrap();
        cv::write_mat(&mut fs, "distortion_coefficients", &d).unwrap();
        cv::write_mat(&mut fs, "rvec", r).unwrap();
        cv::write_mat(&mut fs, "tvec", t).unwrap();
        fs.end_write_struct().unwrap();
    }
    fs.end_write_struct().unwrap();
    fs.release().unwrap();
    (rms, k, d, poses)
}

#[test]
fn a_rational_model_calibration_written_by_opencv_imports_and_projects_like_opencv() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("calibration.yaml");
    let (rms, k, d, poses) = calibrate_and_write(&path);
    let coefficients: Vec<f64> = d.data_typed::<f64>().unwrap().to_vec();
    eprintln!("calibrateCamera (rational): RMS {rms:.2e} px, coefficients {coefficients:?}");
    // OpenCV 4.6 writes all 14 terms; with CALIB_RATIONAL_MODEL alone the last 6 are 0.
    assert_eq!(coefficients.len(), 14);
    assert!(
        coefficients[5..8].iter().all(|&c| c.abs() > 1e-3),
        "k4..k6 = 0?"
    );
    assert!(coefficients[8..].iter().all(|&c| c == 0.0));
    assert!(rms < 0.01, "{rms}");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.starts_with("%YAML:1.0") && text.contains("!!opencv-matrix"),
        "{text}"
    );

    let set = import_calibration(&path).unwrap();
    assert_eq!(set.cameras.len(), 2);
    let board = board();
    let mut worst = 0.0f64;
    for (cam, (r, t)) in set.cameras.iter().zip(&poses) {
        // Kept as the 8 rational coefficients (the zero thin-prism and tilt terms dropped).
        assert_eq!(cam.distortion.coefficients(), coefficients[..8]);
        let cv_pixels = project(&board, r, t, &k, &d);
        for (p, q) in board.iter().zip(&cv_pixels) {
            let world = DVec3::new(p.x as f64, p.y as f64, p.z as f64);
            let (ours, _) = cam.project(world).unwrap();
            // The engine's pixel centres are at integer + 0.5, OpenCV's at the integer.
            worst = worst.max((ours - DVec2::splat(0.5) - DVec2::new(q.x, q.y)).length());
        }
    }
    eprintln!("imported rational calibration: worst |ours − cv::projectPoints| = {worst:.2e} px");
    assert!(worst < 1e-9, "{worst} px");

    // Through the poses stage's import at half size, and undistorted by OpenCV.
    let folders: Vec<CaptureCamera> = ["gopro0", "gopro1"]
        .into_iter()
        .map(|name| CaptureCamera {
            name: name.into(),
            recorded: Some((1920, 1080)),
            working: (960, 540),
        })
        .collect();
    let out_dir = tmp.path().join("poses");
    let out = write_imported(&set, &path, &out_dir, &folders, &BTreeMap::new(), 1.0).unwrap();
    let cam = &out.file.set.cameras[0];
    assert_eq!(cam.distortion, set.cameras[0].distortion);
    let map = UndistortMap::new(cam, Fit::ValidPixels);
    let frame = image::RgbImage::from_pixel(960, 540, image::Rgb([90, 120, 200]));
    let pinhole = map.apply(&frame).unwrap();
    let dark = pinhole.pixels().filter(|p| p[2] < 195).count();
    assert_eq!(dark, 0, "{dark} dark pixels after undistortion");
    assert!(map.pinhole().distortion.is_none());
}
