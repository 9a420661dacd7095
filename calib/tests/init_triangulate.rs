//! Point init by triangulation at several moments with the TRUE cameras (the situation of
//! an imported calibration: no COLMAP solve, no sparse points), on `fixtures/tiny.toml`
//! (a moving crate, a waving flag, a static ball in a room). Checked against the
//! simulator's true surfaces and its moving-object masks. Needs COLMAP (skipped without
//! it, except under CI=true).

mod common;

use std::path::{Path, PathBuf};

use calib::init::{InitConfig, InitInputs, Moment, Source, UsedSource, ViewImage, run_init};
use glam::DVec3;
use shared_types::{CameraSet, NoProgress};

/// Aligned frames used as moments (tiny: 15 frames at 15 fps, cameras start together).
const FRAMES: [usize; 3] = [0, 7, 14];
/// `fixtures/tiny.toml`'s frame rate.
const FPS: f64 = 15.0;

fn colmap_or_skip() -> bool {
    if common::colmap_available() {
        return true;
    }
    let ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
    assert!(!ci, "COLMAP is required under CI");
    false
}

struct Capture {
    dir: PathBuf,
    scene: rig::sim::Scene,
    cameras: CameraSet,
    fps: f64,
}

fn simulate() -> Capture {
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

/// The clean frames of every camera at each moment (model time = seconds).
fn moments(c: &Capture) -> Vec<Moment> {
    FRAMES
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

fn surface_distance(triangles: &[[DVec3; 3]], p: DVec3) -> f64 {
    triangles
        .iter()
        .map(|t| (rig::sim::closest_on_triangle(p, *t) - p).length())
        .fold(f64::INFINITY, f64::min)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Whether `p` lands on the moving-object mask of frame `n` in a camera that sees it.
fn on_moving_mask(c: &Capture, p: DVec3, n: usize) -> bool {
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

#[test]
fn moments_triangulated_with_true_cameras_lie_on_the_true_surfaces() {
    if !colmap_or_skip() {
        return;
    }
    let c = simulate();
    let inputs = InitInputs {
        cameras: c.cameras.clone(),
        images: vec![],
        sparse: None,
        moments: moments(&c),
    };
    let config = InitConfig {
        source: Source::Triangulate,
        moments: FRAMES.len(),
        ..InitConfig::default()
    };
    let out = c.dir.join("init");
    let start = std::time::Instant::now();
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    let seconds = start.elapsed().as_secs_f64();
    assert_eq!(report.source, UsedSource::Triangulated, "{report:#?}");
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    let (times, spans) = (cloud.time.unwrap(), cloud.time_span.unwrap());
    let s = &report.statics;
    eprintln!(
        "{:.1} s; points per moment {:?}; static {} (from {} tagged), moving {} (from {})",
        seconds,
        report.moments.iter().map(|m| m.points).collect::<Vec<_>>(),
        s.static_points,
        s.static_tagged,
        s.dynamic_points,
        s.dynamic_tagged
    );
    assert_eq!(report.moments.len(), FRAMES.len());
    for m in &report.moments {
        assert!(m.error.is_none() && m.points >= 30, "{m:?}");
    }

    // Static points: on the true surfaces (measured: median 6 mm; one pixel ≈ 7 mm at 3 m).
    let triangles = rig::sim::surface_triangles(&c.scene, 0.0);
    let xyz = |i: usize| DVec3::from_array(cloud.xyz[i].map(f64::from));
    let statics: Vec<f64> = (0..cloud.xyz.len())
        .filter(|&i| spans[i] > 0.0)
        .map(|i| surface_distance(&triangles, xyz(i)))
        .collect();
    let med = median(statics.clone());
    eprintln!("static points: median distance to the true surfaces {med:.4} m");
    assert!(s.static_points >= 30 && med < 0.015, "{med}");
    let clip = (FRAMES[2] - FRAMES[0]) as f32 / FPS as f32;
    for i in (0..spans.len()).filter(|&i| spans[i] > 0.0) {
        // Centre of a span within the clip.
        assert!(spans[i] <= clip + 1e-4 && times[i] - spans[i] / 2.0 >= -1e-4);
        assert!(times[i] + spans[i] / 2.0 <= clip + 1e-4);
    }

    // Moving points at later moments: on the moving objects' masks at their time, and on
    // the surfaces of that time.
    let mut later = 0;
    let mut on_mask = 0;
    let mut dists = Vec::new();
    for &n in FRAMES.iter().skip(1) {
        let t = n as f64 / c.fps;
        let tris = rig::sim::surface_triangles(&c.scene, t);
        for i in (0..spans.len()).filter(|&i| spans[i] == 0.0 && (times[i] as f64 - t).abs() < 1e-4)
        {
            later += 1;
            if on_moving_mask(&c, xyz(i), n) {
                on_mask += 1;
                dists.push(surface_distance(&tris, xyz(i)));
            }
        }
    }
    eprintln!(
        "later moments: {later} moving points, {on_mask} on the moving masks, median distance {:.4} m",
        if dists.is_empty() {
            f64::NAN
        } else {
            median(dists.clone())
        }
    );
    assert!(on_mask >= 40, "{on_mask} of {later}");
    assert!(median(dists) < 0.015);
    // Static tagging: the room is mostly static.
    assert!(s.static_tagged > 2 * (s.dynamic_tagged - on_mask.min(s.dynamic_tagged)));
}
