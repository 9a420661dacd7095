//! An analytic 4D scene for trainer tests, drawn per pixel WITHOUT the Gaussian renderer:
//! a smoothly textured plane z = 0 with a soft red disc sliding along x over time, seen by
//! four cameras above it at several times.

#![allow(dead_code)]

use glam::{DVec2, DVec3};
use splat4d::train::{
    Dataset, ImageU8, NoHooks, PointCloud, TrainConfig, TrainSummary, View, train,
};
use splat4d::{Camera, Distortion, Intrinsics, TimeMapping, WorldToCamera};

/// Texture colour at plane point (x, y) and model time t ∈ [0, 1].
pub fn colour(x: f64, y: f64, t: f64) -> [f64; 3] {
    let base = [
        0.5 + 0.25 * (2.0 * x + 1.0).sin(),
        0.5 + 0.25 * (1.5 * y).cos(),
        0.4 + 0.2 * (x + y).sin(),
    ];
    let centre = DVec2::new(-0.4 + 0.8 * t, 0.1);
    let d = (DVec2::new(x, y) - centre).length();
    // Smooth edge between radius 0.3 and 0.45.
    let s = ((0.45 - d) / 0.15).clamp(0.0, 1.0);
    let w = s * s * (3.0 - 2.0 * s);
    let disc = [0.9, 0.2, 0.15];
    std::array::from_fn(|c| base[c] * (1.0 - w) + disc[c] * w)
}

pub fn cameras(width: u32, height: u32) -> Vec<Camera> {
    cameras_at(
        width,
        height,
        &[(-0.5, -0.4), (0.5, -0.4), (-0.5, 0.4), (0.5, 0.4)],
    )
}

/// Two held-out viewpoints between and beside the training cameras.
pub fn held_out_cameras(width: u32, height: u32) -> Vec<Camera> {
    cameras_at(width, height, &[(0.0, 0.0), (0.7, 0.1)])
}

pub fn cameras_at(width: u32, height: u32, eyes: &[(f64, f64)]) -> Vec<Camera> {
    eyes.iter()
        .enumerate()
        .map(|(i, &(x, y))| Camera {
            name: format!("cam{i}"),
            intrinsics: Intrinsics::from_hfov(width, height, 50.0),
            distortion: Distortion::None,
            world_to_camera: WorldToCamera::look_at(DVec3::new(x, y, 3.0), DVec3::ZERO, DVec3::Y)
                .unwrap(),
        })
        .collect()
}

/// The image of `camera` at time `t`: 3×3 supersampled ray–plane intersections.
pub fn draw(camera: &Camera, t: f64) -> ImageU8 {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let eye = camera.world_to_camera.centre();
    let mut rgb = Vec::with_capacity(3 * (w * h) as usize);
    for py in 0..h {
        for px in 0..w {
            let mut acc = [0.0; 3];
            for sy in 0..3 {
                for sx in 0..3 {
                    let p = DVec2::new(
                        px as f64 + (sx as f64 + 0.5) / 3.0,
                        py as f64 + (sy as f64 + 0.5) / 3.0,
                    );
                    let ray = camera.pixel_ray(p);
                    let s = -eye.z / ray.z;
                    let hit = eye + ray * s;
                    let c = colour(hit.x, hit.y, t);
                    (0..3).for_each(|k| acc[k] += c[k] / 9.0);
                }
            }
            rgb.extend(acc.iter().map(|&v| v as f32));
        }
    }
    ImageU8::from_f32(w, h, &rgb)
}

pub const TIMES: [f64; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

pub fn dataset(width: u32, height: u32) -> Dataset {
    dataset_of(&cameras(width, height), &TIMES)
}

pub fn dataset_of(cams: &[Camera], times: &[f64]) -> Dataset {
    let mut views = Vec::new();
    for &t in times {
        for cam in cams.iter().cloned() {
            views.push(View {
                image: draw(&cam, t),
                camera: cam,
                time: t as f32,
            });
        }
    }
    Dataset {
        views,
        time_mapping: TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 1.0,
        },
    }
}

/// Points on the plane (as a point-map initialisation would give), at a few times.
pub fn points(nx: usize, ny: usize, times: &[f64]) -> PointCloud {
    let mut c = PointCloud {
        time: Some(Vec::new()),
        ..Default::default()
    };
    for &t in times {
        for j in 0..ny {
            for i in 0..nx {
                let x = -1.7 + 3.4 * (i as f64 + 0.5) / nx as f64;
                let y = -1.3 + 2.6 * (j as f64 + 0.5) / ny as f64;
                c.xyz.push([x as f32, y as f32, 0.0]);
                c.rgb
                    .push(colour(x, y, t).map(|v| (v * 255.0).round() as u8));
                c.time.as_mut().unwrap().push(t as f32);
            }
        }
    }
    c
}

/// The points of `cloud` on the left half of the plane (x < 0): views of it leave their
/// right half to whatever is behind the Gaussians.
pub fn left_half(cloud: &PointCloud) -> PointCloud {
    let keep: Vec<usize> = (0..cloud.xyz.len())
        .filter(|&i| cloud.xyz[i][0] < 0.0)
        .collect();
    PointCloud {
        xyz: keep.iter().map(|&i| cloud.xyz[i]).collect(),
        rgb: keep.iter().map(|&i| cloud.rgb[i]).collect(),
        time: cloud
            .time
            .as_ref()
            .map(|t| keep.iter().map(|&i| t[i]).collect()),
        time_span: cloud
            .time_span
            .as_ref()
            .map(|t| keep.iter().map(|&i| t[i]).collect()),
    }
}

/// Train `config` on the CPU without hooks or progress into a new temporary folder (kept
/// alive by the returned guard).
pub fn train_cpu(
    config: &TrainConfig,
    data: &Dataset,
    init: &PointCloud,
) -> (tempfile::TempDir, TrainSummary) {
    let dir = tempfile::tempdir().unwrap();
    let summary = train(
        &splat4d::CpuBackend,
        config,
        data,
        init,
        dir.path(),
        false,
        &mut NoHooks,
        &splat4d::NoProgress,
    )
    .unwrap();
    (dir, summary)
}
