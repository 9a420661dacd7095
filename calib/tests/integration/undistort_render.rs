//! Undistortion against ground truth: a scene rendered through a distorted lens, undistorted,
//! matches the same scene rendered directly through the resulting pinhole camera.

use crate::common;

use calib::undistort::{Fit, UndistortMap};
use glam::DVec3;
use shared_types::{Distortion, Intrinsics};

fn psnr(a: &image::RgbImage, b: &image::RgbImage, margin: u32) -> f64 {
    let (w, h) = a.dimensions();
    let mut se = 0.0;
    let mut n = 0.0;
    for y in margin..h - margin {
        for x in margin..w - margin {
            for k in 0..3 {
                let d = a.get_pixel(x, y)[k] as f64 - b.get_pixel(x, y)[k] as f64;
                se += d * d;
                n += 1.0;
            }
        }
    }
    10.0 * (255.0f64 * 255.0 / (se / n)).log10()
}

#[test]
fn undistorted_render_matches_the_pinhole_render() {
    let intr = Intrinsics::from_hfov(240, 180, 80.0);
    let eye = DVec3::new(2.4, 0.8, 1.4);
    for d in [
        Distortion::radial_tangential(-0.28, 0.08, 5e-4, -8e-4, 0.0),
        Distortion::Fisheye {
            k1: 0.04,
            k2: -0.01,
            k3: 0.0,
            k4: 0.0,
        },
    ] {
        let distorted_cam = common::camera("c", eye, intr, d);
        let distorted = common::render(&distorted_cam);
        let map = UndistortMap::new(&distorted_cam, Fit::ValidPixels);
        let undistorted = map.apply(&distorted).unwrap();
        let direct = common::render(map.pinhole());
        let p = psnr(&undistorted, &direct, 2);
        // Without undistortion the images disagree badly.
        let p_raw = psnr(&distorted, &direct, 2);
        eprintln!("{d:?}: PSNR undistorted vs direct {p:.1} dB, distorted vs direct {p_raw:.1} dB");
        assert!(p > 24.0, "{p}");
        assert!(p > p_raw + 6.0, "{p} vs {p_raw}");
    }
}
