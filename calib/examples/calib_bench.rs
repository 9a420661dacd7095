//! Timings for BENCHMARKS.md that need no COLMAP run: undistortion (map build + apply at
//! 1920×1080 and 960×540; frames undistorted inside rayon as the train stage does) and
//! COLMAP model IO on the committed fixture.
//! `CARGO_TARGET_DIR=... cargo run --release -p calib --example calib_bench`

use std::path::Path;
use std::time::Instant;

use calib::colmap::{ColmapModel, ModelFormat};
use calib::undistort::{Fit, UndistortMap};
use rayon::prelude::*;
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

fn best_of<T>(n: usize, mut f: impl FnMut() -> T) -> f64 {
    (0..n)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    for (w, h) in [(1920u32, 1080u32), (960, 540)] {
        for d in [
            Distortion::radial_tangential(-0.25, 0.07, 1e-3, -5e-4, 0.0),
            Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: 0.0,
            },
        ] {
            let cam = Camera {
                name: "c".into(),
                intrinsics: Intrinsics::from_hfov(w, h, 90.0),
                distortion: d,
                world_to_camera: WorldToCamera::IDENTITY,
            };
            let build = best_of(5, || UndistortMap::new(&cam, Fit::ValidPixels));
            let map = UndistortMap::new(&cam, Fit::ValidPixels);
            let img = image::RgbImage::from_fn(w, h, |x, y| {
                image::Rgb([x as u8, y as u8, (x ^ y) as u8])
            });
            let apply = best_of(5, || map.apply(&img).unwrap());
            let kind = if matches!(d, Distortion::Fisheye { .. }) {
                "fisheye"
            } else {
                "radial-tangential"
            };
            println!(
                "undistort {w}x{h} {kind}: map build {:.1} ms, apply (RGB8) {:.1} ms",
                build * 1e3,
                apply * 1e3
            );
        }
    }
    // The train stage loads frames inside rayon (one frame per task) and undistorts each;
    // `apply` itself splits rows over rayon too.
    let cam = Camera {
        name: "c".into(),
        intrinsics: Intrinsics::from_hfov(960, 540, 90.0),
        distortion: Distortion::radial_tangential(-0.25, 0.07, 1e-3, -5e-4, 0.0),
        world_to_camera: WorldToCamera::IDENTITY,
    };
    let map = UndistortMap::new(&cam, Fit::ValidPixels);
    let frames: Vec<image::RgbImage> = (0..32)
        .map(|k| {
            image::RgbImage::from_fn(960, 540, |x, y| {
                image::Rgb([(x + k) as u8, y as u8, (x ^ y) as u8])
            })
        })
        .collect();
    let batch = best_of(3, || {
        frames
            .par_iter()
            .map(|f| map.apply(f).unwrap())
            .collect::<Vec<_>>()
    });
    println!(
        "32 frames of 960x540 inside rayon ({} threads): {:.2} ms/frame",
        rayon::current_num_threads(),
        batch * 1e3 / 32.0
    );
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/colmap/tiny");
    let model = ColmapModel::read(&fixture.join("bin")).unwrap();
    let tmp = std::env::temp_dir().join(format!("calib_bench_{}", std::process::id()));
    let n2d: usize = model.images.values().map(|i| i.points2d.len()).sum();
    println!(
        "model: {} images, {} 2D points, {} 3D points",
        model.images.len(),
        n2d,
        model.points3d.len()
    );
    for f in [ModelFormat::Binary, ModelFormat::Text] {
        let dir = fixture.join(f.extension());
        let read = best_of(10, || ColmapModel::read(&dir).unwrap());
        let write = best_of(10, || model.write(&tmp, f).unwrap());
        println!(
            "model IO {:?}: read {:.2} ms, write {:.2} ms",
            f,
            read * 1e3,
            write * 1e3
        );
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
