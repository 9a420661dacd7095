//! f64 reference check of our camera models: `shared_types::Distortion::distort` followed by the
//! intrinsics projection agrees with OpenCV's `projectPoints` (the full model: 5, 8, 12 and
//! 14 coefficients, i.e. radial-tangential, rational, thin prism, tilted sensor) and
//! `fisheye::projectPoints` to < 1e-9 px over a grid of points reaching the image corners.

use glam::DVec2;
use opencv::calib3d;
use opencv::core::{Mat, Point2d, Point3d, Vector};
use opencv::prelude::*;
use shared_types::{Distortion, Intrinsics};

/// Realistic lenses at 1920×1080: GoPro-like fisheye, mild and strong radial-tangential, a
/// wide lens calibrated with OpenCV's rational model (`CALIB_RATIONAL_MODEL`), and the same
/// with thin-prism and tilted-sensor terms (`CALIB_THIN_PRISM_MODEL`, `CALIB_TILTED_MODEL`).
pub(crate) fn lenses() -> Vec<(&'static str, Intrinsics, Distortion)> {
    let k = |fx: f64, fy: f64, cx: f64, cy: f64| Intrinsics {
        width: 1920,
        height: 1080,
        fx,
        fy,
        cx,
        cy,
    };
    vec![
        (
            "gopro fisheye",
            k(870.0, 868.5, 961.3, 538.2),
            Distortion::Fisheye {
                k1: 0.0412,
                k2: 0.0123,
                k3: -0.0089,
                k4: 0.0021,
            },
        ),
        (
            "mild fisheye",
            k(1150.0, 1150.0, 958.0, 541.0),
            Distortion::Fisheye {
                k1: -0.012,
                k2: 0.004,
                k3: 0.0,
                k4: 0.0,
            },
        ),
        (
            "mild radial-tangential",
            k(1400.0, 1398.0, 955.5, 544.25),
            Distortion::radial_tangential(-0.08, 0.03, 4e-4, -2.5e-4, -0.004),
        ),
        (
            "strong radial-tangential",
            k(1050.0, 1046.0, 963.0, 535.0),
            Distortion::radial_tangential(-0.31, 0.11, 1.2e-3, -9e-4, -0.018),
        ),
        (
            "rational (8 coefficients)",
            k(1010.0, 1008.0, 958.4, 542.7),
            Distortion::from_opencv_coefficients(&[
                1.92, 0.71, 1.1e-3, -6e-4, 0.016, 2.21, 1.46, 0.12,
            ])
            .unwrap(),
        ),
        (
            "rational + thin prism (12 coefficients)",
            k(1010.0, 1008.0, 958.4, 542.7),
            Distortion::from_opencv_coefficients(&[
                1.92, 0.71, 1.1e-3, -6e-4, 0.016, 2.21, 1.46, 0.12, 2.4e-3, -3e-4, -1.8e-3, 2e-4,
            ])
            .unwrap(),
        ),
        (
            "rational + thin prism + tilt (14 coefficients)",
            k(1010.0, 1008.0, 958.4, 542.7),
            Distortion::from_opencv_coefficients(&[
                1.92, 0.71, 1.1e-3, -6e-4, 0.016, 2.21, 1.46, 0.12, 2.4e-3, -3e-4, -1.8e-3, 2e-4,
                0.012, -0.007,
            ])
            .unwrap(),
        ),
    ]
}

/// 3D points (camera frame, z = 1..3) whose images fill the frame, corners included.
fn grid(intr: &Intrinsics, d: &Distortion) -> Vec<[f64; 3]> {
    let n = 12;
    let mut pts = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let p = DVec2::new(
                intr.width as f64 * i as f64 / n as f64,
                intr.height as f64 * j as f64 / n as f64,
            );
            let m = d.undistort(intr.to_normalised(p));
            let z = 1.0 + ((i + j) % 3) as f64;
            pts.push([m.x * z, m.y * z, z]);
        }
    }
    pts
}

fn ours(intr: &Intrinsics, d: &Distortion, p: [f64; 3]) -> DVec2 {
    intr.to_pixels(d.distort(DVec2::new(p[0] / p[2], p[1] / p[2])))
}

fn opencv_projection(intr: &Intrinsics, d: &Distortion, pts: &[[f64; 3]]) -> Vec<DVec2> {
    // Both sides use the same camera matrix, so no pixel-convention shift here.
    let k = Mat::from_slice_2d(&[
        [intr.fx, 0.0, intr.cx],
        [0.0, intr.fy, intr.cy],
        [0.0, 0.0, 1.0],
    ])
    .unwrap();
    let object: Vector<Point3d> = pts.iter().map(|p| Point3d::new(p[0], p[1], p[2])).collect();
    let zero = Mat::from_slice(&[0.0f64; 3]).unwrap().try_clone().unwrap();
    let mut image: Vector<Point2d> = Vector::new();
    match *d {
        Distortion::Opencv { .. } => {
            let c = d.coefficients();
            let coeffs = Mat::from_slice(&c).unwrap().try_clone().unwrap();
            calib3d::project_points_def(&object, &zero, &zero, &k, &coeffs, &mut image).unwrap();
        }
        Distortion::Fisheye { k1, k2, k3, k4 } => {
            let coeffs = Mat::from_slice(&[k1, k2, k3, k4])
                .unwrap()
                .try_clone()
                .unwrap();
            calib3d::fisheye_project_points_vec_def(&object, &mut image, &zero, &zero, &k, &coeffs)
                .unwrap();
        }
        Distortion::None => unreachable!("only lenses are checked"),
    }
    image.iter().map(|p| DVec2::new(p.x, p.y)).collect()
}

#[test]
fn our_camera_models_match_opencv_projection() {
    for (name, intr, d) in lenses() {
        let pts = grid(&intr, &d);
        let cv = opencv_projection(&intr, &d, &pts);
        assert_eq!(cv.len(), pts.len());
        let mut worst = 0.0f64;
        for (p, q) in pts.iter().zip(&cv) {
            worst = worst.max((ours(&intr, &d, *p) - *q).length());
        }
        // The grid really reaches the corners (undistort is exact there).
        let corner = ours(&intr, &d, pts[pts.len() - 1]);
        assert!(
            (corner - DVec2::new(1920.0, 1080.0)).length() < 1e-9,
            "{name}: {corner}"
        );
        eprintln!("{name}: worst |ours - OpenCV| = {worst:.2e} px");
        assert!(worst < 1e-9, "{name}: {worst} px");
    }
}
