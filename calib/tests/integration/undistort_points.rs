//! Where undistortion puts things, checked with an image whose pixels hold their own source
//! coordinates (bilinear resampling reproduces a linear ramp exactly): a world point seen by
//! the distorted camera lands, after undistortion, where the pinhole camera projects it. This
//! pins the half-pixel convention (ours: centre at +0.5, OpenCV's: at the integer). Also:
//! `Fit::ValidPixels` leaves no black or darkened border, `Fit::AllPixels` keeps the corners,
//! and bad cameras give typed errors, never panics.

use calib::undistort::{Fit, UndistortError, UndistortMap};
use glam::{DVec2, DVec3};
use image::{Rgb, Rgb32FImage, RgbImage};
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

fn camera(d: Distortion) -> Camera {
    Camera {
        name: "cam_left".into(),
        intrinsics: Intrinsics {
            width: 320,
            height: 240,
            fx: 200.0,
            fy: 198.0,
            cx: 161.3,
            cy: 118.6,
        },
        distortion: d,
        world_to_camera: WorldToCamera::look_at(DVec3::new(0.4, -3.0, 1.0), DVec3::ZERO, DVec3::Z)
            .unwrap(),
    }
}

fn lenses() -> [Distortion; 4] {
    let opencv = |c: &[f64]| Distortion::from_opencv_coefficients(c).unwrap();
    [
        Distortion::radial_tangential(-0.28, 0.09, 1e-3, -6e-4, -0.01),
        // OpenCV's rational model (CALIB_RATIONAL_MODEL, 8 coefficients).
        opencv(&[0.1, 0.02, 1e-3, -6e-4, 0.0, 0.3, 0.01, 0.0]),
        // Rational + thin prism + tilted sensor (14 coefficients).
        opencv(&[
            -0.2, 0.05, 8e-4, -5e-4, -0.004, 0.05, -0.01, 0.002, 2e-3, -4e-4, -1.5e-3, 3e-4, 0.01,
            -0.008,
        ]),
        Distortion::Fisheye {
            k1: 0.05,
            k2: -0.01,
            k3: 0.002,
            k4: 0.0,
        },
    ]
}

/// Each pixel holds its own centre (x + 0.5, y + 0.5) and a validity weight of 1.
fn coordinate_image(w: u32, h: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(w, h, |x, y| Rgb([x as f32 + 0.5, y as f32 + 0.5, 1.0]))
}

#[test]
fn world_points_land_where_the_pinhole_camera_projects_them() {
    for d in lenses() {
        for fit in [Fit::ValidPixels, Fit::AllPixels, Fit::KeepFocal] {
            let cam = camera(d);
            let map = UndistortMap::new(&cam, fit);
            let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
            let out = map.apply(&coordinate_image(w, h)).unwrap();
            let pinhole = map.pinhole();
            let (mut worst, mut checked) = (0.0f64, 0);
            for y in (0..h).step_by(7) {
                for x in (0..w).step_by(7) {
                    let px = out.get_pixel(x, y);
                    if px[2] < 0.999_999 {
                        continue; // Outside the lens's view (or blended with the border).
                    }
                    // A world point on the pinhole camera's ray through this pixel's centre.
                    let centre = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let world = cam.world_to_camera.centre() + pinhole.pixel_ray(centre) * 2.7;
                    let (at_pinhole, _) = pinhole.project(world).unwrap();
                    assert!((at_pinhole - centre).length() < 1e-9);
                    let (at_distorted, _) = cam.project(world).unwrap();
                    let (sw, sh) = (w as f64 - 0.5, h as f64 - 0.5);
                    if !(0.5..=sw).contains(&at_distorted.x)
                        || !(0.5..=sh).contains(&at_distorted.y)
                    {
                        // Beyond the outer pixel centres ValidPixels replicates the edge.
                        continue;
                    }
                    let landed = DVec2::new(px[0] as f64, px[1] as f64);
                    worst = worst.max((landed - at_distorted).length());
                    checked += 1;
                }
            }
            eprintln!("{d:?} {fit:?}: {checked} points, worst {worst:.4} px");
            assert!(checked > 1000, "{d:?} {fit:?}: only {checked} points");
            // OpenCV's remap quantises positions to 1/32 px: at most 1/64 px per axis.
            assert!(worst < 0.05, "{d:?} {fit:?}: {worst} px");
        }
    }
}

#[test]
fn valid_pixels_leave_no_dark_border_and_all_pixels_keep_the_corners() {
    for d in lenses() {
        let cam = camera(d);
        let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
        let grey = RgbImage::from_pixel(w, h, Rgb([200, 200, 200]));
        let inner = UndistortMap::new(&cam, Fit::ValidPixels)
            .apply(&grey)
            .unwrap();
        let dark = inner.pixels().filter(|p| p[0] < 198).count();
        eprintln!("{d:?}: ValidPixels has {dark} darkened pixels");
        assert_eq!(dark, 0, "{d:?}: {dark} darkened pixels");

        let all = UndistortMap::new(&cam, Fit::AllPixels);
        let out = all.apply(&coordinate_image(w, h)).unwrap();
        for corner in [
            DVec2::new(0.5, 0.5),
            DVec2::new(w as f64 - 0.5, 0.5),
            DVec2::new(0.5, h as f64 - 0.5),
            DVec2::new(w as f64 - 0.5, h as f64 - 0.5),
        ] {
            let nearest = out
                .pixels()
                .filter(|p| p[2] > 0.0)
                .map(|p| (DVec2::new(p[0] as f64, p[1] as f64) - corner).length())
                .fold(f64::INFINITY, f64::min);
            assert!(nearest < 2.0, "{d:?}: corner {corner} lost ({nearest} px)");
        }
        // The output still uses the frame: black only outside the lens's view.
        let black = out.pixels().filter(|p| p[2] == 0.0).count();
        assert!(black < (w * h / 4) as usize, "{d:?}: {black} black pixels");
    }
}

#[test]
fn bad_input_gives_typed_errors() {
    let cam = camera(lenses()[0]);
    let map = UndistortMap::new(&cam, Fit::ValidPixels);
    match map.apply(&RgbImage::new(100, 80)) {
        Err(UndistortError::SizeMismatch {
            camera,
            got_w: 100,
            got_h: 80,
            want_w: 320,
            want_h: 240,
        }) => assert_eq!(camera, "cam_left"),
        other => panic!("expected SizeMismatch, got {other:?}"),
    }
    for d in [
        Distortion::radial_tangential(f64::NAN, 0.0, 0.0, 0.0, 0.0),
        Distortion::Fisheye {
            k1: f64::NAN,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        },
    ] {
        for fit in [Fit::ValidPixels, Fit::AllPixels, Fit::KeepFocal] {
            let map = UndistortMap::new(&camera(d), fit);
            let err = map.apply(&RgbImage::new(320, 240)).unwrap_err();
            assert!(
                matches!(&err, UndistortError::InvalidCamera { camera, .. } if camera == "cam_left"),
                "{err:?}"
            );
            assert!(err.to_string().contains("cam_left"), "{err}");
        }
    }
    let mut flat = camera(lenses()[3]);
    flat.intrinsics.fx = 0.0;
    let err = UndistortMap::new(&flat, Fit::AllPixels)
        .apply(&RgbImage::new(320, 240))
        .unwrap_err();
    assert!(err.to_string().contains("focal length"), "{err}");
}
