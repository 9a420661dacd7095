//! Test helpers: a small ray-cast scene (a textured room with a textured box in the middle)
//! rendered through real cameras, so COLMAP has something to solve with known answers.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};
use image::{Rgb, RgbImage};
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

/// Whether the real `colmap` binary is available; tests that need it skip (with a message)
/// when it is not.
pub fn colmap_available() -> bool {
    match calib::colmap_runner::find_colmap(None) {
        Ok(_) => true,
        Err(e) => {
            eprintln!("skipping: {e}");
            false
        }
    }
}

fn hash(ix: i64, iy: i64, seed: u64) -> f64 {
    let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn value_noise(u: f64, v: f64, seed: u64) -> f64 {
    let (iu, iv) = (u.floor(), v.floor());
    let (fu, fv) = (u - iu, v - iv);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (su, sv) = (s(fu), s(fv));
    let (iu, iv) = (iu as i64, iv as i64);
    let a = hash(iu, iv, seed);
    let b = hash(iu + 1, iv, seed);
    let c = hash(iu, iv + 1, seed);
    let d = hash(iu + 1, iv + 1, seed);
    a + (b - a) * su + (c - a) * sv + (a - b - c + d) * su * sv
}

/// Texture of face `face` at face coordinates (u, v) in metres.
fn texture(face: u64, u: f64, v: f64) -> [f64; 3] {
    let mut n = 0.0;
    let mut amp = 0.5;
    let mut freq = 3.0;
    for o in 0..5 {
        n += amp * value_noise(u * freq, v * freq, face * 31 + o);
        amp *= 0.55;
        freq *= 2.1;
    }
    let tint = [
        hash(face as i64, 1, 7),
        hash(face as i64, 2, 7),
        hash(face as i64, 3, 7),
    ];
    let blob = if value_noise(u * 6.0, v * 6.0, face * 97 + 5) > 0.72 {
        0.35
    } else {
        0.0
    };
    std::array::from_fn(|k| (0.15 + 0.85 * n * (0.6 + 0.4 * tint[k]) + blob).clamp(0.0, 1.0))
}

/// Half-size of the room and of the central box (metres).
const ROOM: f64 = 4.0;
const BOX: f64 = 0.6;

/// Colour seen along a ray: the nearest hit among the room's inner walls and the box.
fn trace(o: DVec3, d: DVec3) -> [f64; 3] {
    let mut best = (f64::INFINITY, [0.0; 3]);
    // Room: floor z=0, ceiling z=3, walls x=±ROOM, y=±ROOM (seen from inside).
    let planes: [(usize, f64, u64); 6] = [
        (2, 0.0, 1),
        (2, 3.0, 2),
        (0, -ROOM, 3),
        (0, ROOM, 4),
        (1, -ROOM, 5),
        (1, ROOM, 6),
    ];
    for (axis, pos, face) in planes {
        if d[axis].abs() < 1e-12 {
            continue;
        }
        let t = (pos - o[axis]) / d[axis];
        if t > 1e-6 && t < best.0 {
            let p = o + t * d;
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            best = (t, texture(face, p[a], p[b]));
        }
    }
    // Box [-BOX, BOX]² × [0, 2·BOX], slab test.
    let (lo, hi) = (DVec3::new(-BOX, -BOX, 0.0), DVec3::new(BOX, BOX, 2.0 * BOX));
    let inv = d.recip();
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    let tmin = t0.min(t1);
    let tmax = t0.max(t1);
    let (tn, tf) = (tmin.max_element(), tmax.min_element());
    if tn <= tf && tn > 1e-6 && tn < best.0 {
        let p = o + tn * d;
        let axis = if tmin.x == tn {
            0
        } else if tmin.y == tn {
            1
        } else {
            2
        };
        let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
        best = (
            tn,
            texture(
                10 + axis as u64 + if d[axis] > 0.0 { 0 } else { 3 },
                p[a],
                p[b],
            ),
        );
    }
    best.1
}

/// Render `camera` (distortion included) with 2×2 supersampling.
pub fn render(camera: &Camera) -> RgbImage {
    let Intrinsics { width, height, .. } = camera.intrinsics;
    let eye = camera.world_to_camera.centre();
    let rows: Vec<Vec<u8>> = (0..height)
        .map(|y| {
            let mut row = Vec::with_capacity(width as usize * 3);
            for x in 0..width {
                let mut c = [0.0; 3];
                for (sx, sy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    let d = camera.pixel_ray(DVec2::new(x as f64 + sx, y as f64 + sy));
                    let s = trace(eye, d);
                    (0..3).for_each(|k| c[k] += 0.25 * s[k]);
                }
                row.extend(c.iter().map(|v| (v * 255.0).round() as u8));
            }
            row
        })
        .collect();
    RgbImage::from_raw(width, height, rows.concat()).expect("buffer size")
}

/// A camera at `eye` looking at the box.
pub fn camera(name: &str, eye: DVec3, intrinsics: Intrinsics, distortion: Distortion) -> Camera {
    let target = DVec3::new(0.0, 0.0, BOX);
    Camera {
        name: name.into(),
        intrinsics,
        distortion,
        world_to_camera: WorldToCamera::look_at(eye, target, DVec3::Z).expect("eye != target"),
    }
}

/// The rig: 4 video cameras on an arc of radius 2.6 m (0°, 40°, 80°, 120°), and `n_stills`
/// stills between and around them at other heights.
pub fn rig(n_stills: usize, size: (u32, u32)) -> (Vec<Camera>, Vec<Camera>) {
    rig_with_lens(n_stills, size, Distortion::None)
}

/// [`rig`] with lens distortion on the video cameras.
pub fn rig_with_lens(
    n_stills: usize,
    size: (u32, u32),
    lens: Distortion,
) -> (Vec<Camera>, Vec<Camera>) {
    let video_intr = Intrinsics::from_hfov(size.0, size.1, 70.0);
    let video: Vec<Camera> = (0..4)
        .map(|i| {
            let a = (i as f64 * 40.0).to_radians();
            let eye = DVec3::new(2.6 * a.cos(), 2.6 * a.sin(), 1.5);
            camera(&format!("cam{i}"), eye, video_intr, lens)
        })
        .collect();
    let still_intr = Intrinsics::from_hfov(size.0, size.1, 62.0);
    let stills = (0..n_stills)
        .map(|i| {
            let a = (-10.0 + i as f64 * 140.0 / (n_stills.max(2) - 1) as f64).to_radians();
            let r = 2.2 + 0.4 * (i % 2) as f64;
            let eye = DVec3::new(r * a.cos(), r * a.sin(), 1.1 + 0.5 * (i % 3) as f64);
            camera(&format!("still{i}"), eye, still_intr, Distortion::None)
        })
        .collect();
    (video, stills)
}

/// Render cameras to `dir/<name>.png`, returning the paths.
pub fn render_to(dir: &Path, cameras: &[Camera]) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let images: Vec<RgbImage> = std::thread::scope(|s| {
        let handles: Vec<_> = cameras.iter().map(|c| s.spawn(move || render(c))).collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    cameras
        .iter()
        .zip(images)
        .map(|(c, img)| {
            let p = dir.join(format!("{}.png", c.name));
            img.save(&p).unwrap();
            p
        })
        .collect()
}

/// A uniform grey image (a "blank" frame).
pub fn blank(path: &Path, size: (u32, u32)) {
    RgbImage::from_pixel(size.0, size.1, Rgb([128, 128, 128]))
        .save(path)
        .unwrap();
}

/// An image of pure value noise (features, but nothing in common with any other image).
pub fn noise_image(path: &Path, size: (u32, u32), seed: u64) {
    let img = RgbImage::from_fn(size.0, size.1, |x, y| {
        let (u, v) = (x as f64 / 40.0, y as f64 / 40.0);
        let n = value_noise(u, v, seed) * 0.5
            + value_noise(u * 3.0, v * 3.0, seed + 1) * 0.3
            + value_noise(u * 9.0, v * 9.0, seed + 2) * 0.2;
        let g = (n * 255.0) as u8;
        Rgb([g, g.wrapping_add((seed * 37) as u8) / 2 + 60, 255 - g])
    });
    img.save(path).unwrap();
}

/// Paths of `n` stills and 4 video frames of the standard rig, rendered into `dir`.
pub struct RenderedRig {
    pub video: Vec<Camera>,
    pub stills: Vec<Camera>,
    pub video_paths: Vec<(String, PathBuf)>,
    pub still_paths: Vec<PathBuf>,
}

pub fn render_rig(dir: &Path, n_stills: usize, size: (u32, u32)) -> RenderedRig {
    render_rig_with_lens(dir, n_stills, size, Distortion::None)
}

pub fn render_rig_with_lens(
    dir: &Path,
    n_stills: usize,
    size: (u32, u32),
    lens: Distortion,
) -> RenderedRig {
    let (video, stills) = rig_with_lens(n_stills, size, lens);
    let all: Vec<Camera> = video.iter().chain(&stills).cloned().collect();
    let paths = render_to(dir, &all);
    let video_paths = video
        .iter()
        .zip(&paths)
        .map(|(c, p)| (c.name.clone(), p.clone()))
        .collect();
    let still_paths = paths[video.len()..].to_vec();
    RenderedRig {
        video,
        stills,
        video_paths,
        still_paths,
    }
}

/// A [`shared_types::Progress`] that records every call, to check what a stage reports.
#[derive(Default)]
pub struct RecordingProgress {
    pub messages: std::sync::Mutex<Vec<String>>,
    pub advanced: std::sync::atomic::AtomicU64,
}

impl shared_types::Progress for RecordingProgress {
    fn start(&self, total: u64, unit: &str) {
        self.messages
            .lock()
            .unwrap()
            .push(format!("start {total} {unit}"));
    }
    fn advance(&self, n: u64) {
        self.advanced
            .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
    }
    fn message(&self, msg: &str) {
        self.messages.lock().unwrap().push(msg.to_string());
    }
    fn finish(&self) {
        self.messages.lock().unwrap().push("finish".into());
    }
}
