#![allow(dead_code)] // each test binary uses a different part of this module
//! A small 4D scene and cameras shared by the render/eval tests.

use glam::DVec3;
use splat4d::{
    Camera, ColourDegrees, Distortion, Gaussians, Intrinsics, TimeMapping, WorldToCamera,
};

/// A 5×5×2 block of coloured Gaussians around the origin whose temporal centres spread
/// over the sequence (model time 0..1 = 1 s), so renders differ with time.
pub fn scene() -> Gaussians<f32> {
    let mut g = Gaussians::new(
        ColourDegrees::DC,
        TimeMapping::frames_over_30(0.0, 30.0, 1.0),
    );
    let mut k = 0;
    for i in 0..5 {
        for j in 0..5 {
            for l in 0..2 {
                let (x, y, z) = (
                    i as f32 * 0.4 - 0.8,
                    l as f32 * 0.4 - 0.2,
                    j as f32 * 0.4 - 0.8,
                );
                let rgb = [i as f32 / 4.0, j as f32 / 4.0, 0.3 + 0.4 * l as f32];
                let t = (k % 5) as f32 / 4.0;
                g.push([x, y, z, t], [-1.6, -1.6, -1.6, -1.0], 2.0, rgb);
                k += 1;
            }
        }
    }
    g
}

/// A pinhole camera at `eye` looking at the origin, z up.
pub fn camera(name: &str, eye: DVec3, width: u32, height: u32) -> Camera {
    Camera {
        name: name.into(),
        intrinsics: Intrinsics::from_hfov(width, height, 55.0),
        distortion: Distortion::None,
        world_to_camera: WorldToCamera::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap(),
    }
}

/// Four cameras around the scene at distance ~3.5.
pub fn rig(width: u32, height: u32) -> Vec<Camera> {
    (0..4)
        .map(|i| {
            let a = 0.4 + i as f64 * 1.3;
            camera(
                &format!("cam{i}"),
                DVec3::new(3.5 * a.cos(), 3.5 * a.sin(), 1.0),
                width,
                height,
            )
        })
        .collect()
}

/// The model's colour render as 8-bit PNG bytes on disk at `path`.
pub fn save_render(
    model: &Gaussians<f32>,
    cam: &Camera,
    t: f64,
    path: &std::path::Path,
) -> Vec<f32> {
    let r = splat4d::render::cpu::render(model, cam, t as f32).unwrap();
    let img = splat4d::eval::images::rgb8(&r);
    img.save(path).unwrap();
    img.into_raw().iter().map(|&v| v as f32 / 255.0).collect()
}
