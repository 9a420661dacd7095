//! A simulated capture with moving objects and its clean frames at chosen moments, for
//! the point-init tests (triangulation, plane sweep), checked against the simulator's
//! true surfaces and moving-object masks.

use std::path::{Path, PathBuf};

use glam::DVec3;
use pointinit::{Moment, ViewImage};
use shared_types::{CameraSet, NoProgress};

/// `fixtures/tiny.toml`'s frame rate.
pub const FPS: f64 = 15.0;

/// A simulated `fixtures/tiny.toml` capture at 480×360 with its true cameras.
pub struct Capture {
    pub dir: PathBuf,
    pub scene: rig::sim::Scene,
    pub cameras: CameraSet,
    pub fps: f64,
}

/// Simulate `fixtures/tiny.toml` at 480×360 into a kept temporary folder.
pub fn simulate() -> Capture {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    // tiny's 160×120 frames give SIFT too little to match across the rig: 480×360.
    let text = std::fs::read_to_string(root.join("fixtures/tiny.toml")).unwrap();
    let text = text.replacen(
        "width = 160\nheight = 120\nhfov = 70",
        "width = 480\nheight = 360\nhfov = 70",
        1,
    );
    assert!(text.contains("width = 480"));
    let scene = rig::sim::Scene::from_toml_str(&text, "tiny.toml at 480×360").unwrap();
    let dir = tempfile::tempdir().unwrap().keep();
    rig::sim::simulate(&scene, &dir.join("capture"), &NoProgress).unwrap();
    let gt: CameraSet = serde_json::from_str(
        &std::fs::read_to_string(dir.join("capture/groundtruth/cameras.json")).unwrap(),
    )
    .unwrap();
    let video = scene.video_cameras().cloned().collect::<Vec<_>>();
    assert!(video.iter().all(|c| c.start_time == 0.0));
    let cameras = CameraSet::new(
        video
            .iter()
            .map(|v| gt.get(&v.camera.name).unwrap().clone())
            .collect(),
    );
    Capture {
        dir,
        cameras,
        fps: FPS,
        scene,
    }
}

/// The clean frames of every camera at each of `frames` (model time = seconds).
pub fn moments(c: &Capture, frames: &[usize]) -> Vec<Moment> {
    frames
        .iter()
        .map(|&n| {
            let t = n as f64 / c.fps;
            let views = c
                .cameras
                .cameras
                .iter()
                .map(|cam| {
                    let r = rig::sim::render_clean(&c.scene, &cam.name, t).unwrap();
                    let (w, h) = (r.width as u32, r.height as u32);
                    let rgb = image::RgbImage::from_fn(w, h, |x, y| {
                        let v = r.color[(y * w + x) as usize];
                        image::Rgb(v.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
                    });
                    let path = c.dir.join(format!("frames/{}/{n:06}.png", cam.name));
                    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                    rgb.save(&path).unwrap();
                    ViewImage {
                        camera: cam.name.clone(),
                        path,
                        time: t,
                    }
                })
                .collect();
            Moment {
                frame: n,
                time: t,
                views,
            }
        })
        .collect()
}

/// Distance from `p` to the nearest of `triangles`.
pub fn surface_distance(triangles: &[[DVec3; 3]], p: DVec3) -> f64 {
    triangles
        .iter()
        .map(|t| (rig::sim::closest_on_triangle(p, *t) - p).length())
        .fold(f64::INFINITY, f64::min)
}

/// The median of `v` (upper middle for an even count).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Whether `p` lands on the moving-object mask of frame `n` in a camera that sees it.
pub fn on_moving_mask(c: &Capture, p: DVec3, n: usize) -> bool {
    c.cameras.cameras.iter().any(|cam| {
        let Some((px, _)) = cam.project(p) else {
            return false;
        };
        let (w, h) = (cam.intrinsics.width as f64, cam.intrinsics.height as f64);
        if px.x < 0.0 || px.y < 0.0 || px.x >= w || px.y >= h {
            return false;
        }
        let mask = c
            .dir
            .join(format!("capture/groundtruth/masks/{}/{n:06}.png", cam.name));
        let m = image::open(&mask).unwrap().to_luma8();
        m.get_pixel(px.x as u32, px.y as u32).0[0] > 127
    })
}
