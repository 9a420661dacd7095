//! The exported browser viewer in headless Chromium (Debian's `/usr/bin/chromium` driven
//! by playwright-core, WebGL on SwiftShader), compared with the engine's own render:
//!
//! - a demo-sized scene (a textured room of ~9 000 Gaussians with large floor splats
//!   reaching under the cameras, metre-wide faint "fill" Gaussians centred far outside
//!   the pictures, as training leaves them, view-dependent colour, a figure walking through
//!   the clip, objects that appear early and late; 4 cameras at 480×360): the page, which
//!   draws the native 4D model, shows what the engine renders (PSNR ≥ 45 dB) at the first,
//!   middle and last time step on two cameras, after stepping inside the page, at a time
//!   between two export steps and from a viewpoint no camera had; the same export with its
//!   opacities deliberately broken does not; and the `.splatv`, played by gsplat's own
//!   `.splatv` renderer (`splatv.html`), shows the first, middle and last moment of the
//!   clip at the right time;
//! - a small scene whose red patch shows early and blue patch late.
//!
//! Skips (prints why, passes) when Chromium, Node.js or the built viewer bundle is
//! missing, except under `CI=true`, where they must be present (`scripts/setup.sh`
//! installs them). `SPLAT4D_KEEP_SHOTS=DIR` keeps the screenshots (viewer | engine).

use crate::browser;

use browser::{Browser, engine_render, psnr, serve, side_by_side};
use glam::DVec3;
use splat4d::export::{ExportOptions, even_times, export_all, web4d};
use splat4d::{
    Camera, CameraSet, ColourDegrees, Distortion, Gaussians, Intrinsics, NoProgress, TimeMapping,
    WorldToCamera,
};
use std::path::{Path, PathBuf};

/// Lowest PSNR (dB) of the viewer against the engine, at training cameras, at a novel
/// viewpoint and at any time. The page slices and projects with the engine's formulas in
/// `f32` on the GPU, from half-float fields and 8-bit higher harmonics, and blends in half
/// floats (55–57 dB here); a wrong opacity, scale, colour, time or camera costs far more
/// (opacities at 40 %: 22 dB).
const FLOOR_DB: f64 = 45.0;

/// Lowest PSNR of the `.splatv` (played by gsplat's own renderer) against the engine:
/// its single colour per Gaussian (seen from the mean camera at the Gaussian's own time
/// centre) cannot follow view-dependent and time-varying colour (31 dB here; with the
/// clip's time not mapped onto the player's [0, 1], 25 dB in mid-clip).
const SPLATV_FLOOR_DB: f64 = 27.0;

/// SplitMix64: deterministic, dependency-free.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
}

/// Quaternion `(w, x, y, z)` of a rotation by `angle` about unit `axis`.
fn axis_angle(axis: [f64; 3], angle: f64) -> [f32; 4] {
    let (s, c) = (0.5 * angle).sin_cos();
    [c, axis[0] * s, axis[1] * s, axis[2] * s].map(|v| v as f32)
}

/// A scene like the demo's trained model, in world coordinates with z up (metres), model
/// time `[0, 2]` (4 s at 15 fps, as `TimeMapping::frames_over_30`), and its 4 cameras.
fn demo_like_scene() -> (Gaussians<f32>, CameraSet) {
    let caps = ColourDegrees {
        spatial: 2,
        temporal: 1,
    };
    let mut g = Gaussians::<f32>::new(caps, TimeMapping::frames_over_30(0.25, 15.0, 4.0));
    g.active = caps;
    let k = g.coeffs_per_channel();
    let spatial = caps.spatial_count();
    let mut rng = Rng(7);
    // Static Gaussians: a long time scale, centred in the clip.
    let flat = |g: &mut Gaussians<f32>,
                rng: &mut Rng,
                p: [f64; 3],
                normal_axis: usize,
                size: f64,
                rgb: [f64; 3]| {
        let mut ls = [(size * rng.range(0.7, 1.3)).ln(); 4];
        ls[normal_axis] = (0.012f64).ln();
        ls[3] = 1.5;
        let ls = ls.map(|v| v as f32);
        let mean = [p[0] as f32, p[1] as f32, p[2] as f32, 1.0];
        let i = g.push(mean, ls, rng.range(1.0, 4.0) as f32, rgb.map(|v| v as f32));
        // Spin about the surface normal, so neighbours are not all aligned.
        let mut axis = [0.0; 3];
        axis[normal_axis] = 1.0;
        let q = axis_angle(axis, rng.range(0.0, std::f64::consts::PI));
        g.rot_left[i] = q;
        g.rot_right[i] = q;
        // Mild view-dependent colour (degree 1 and 2).
        for s in 1..spatial {
            for c in 0..3 {
                g.colours[(i * k + s) * 3 + c] = rng.range(-0.12, 0.12) as f32;
            }
        }
        i
    };
    let texture = |u: f64, v: f64, base: [f64; 3], rng: &mut Rng| -> [f64; 3] {
        let check = ((u / 0.5).floor() + (v / 0.5).floor()).rem_euclid(2.0);
        let dot = ((u * 3.1).sin() * (v * 2.7).cos()).abs() > 0.93;
        base.map(|b| {
            let x = b * (0.7 + 0.45 * check) + rng.range(-0.05, 0.05);
            if dot { 0.08 } else { x.clamp(0.0, 1.0) }
        })
    };
    // Floor: fine in the middle of the room; coarse, big splats around and under the
    // cameras (their centres below the picture, their footprints well inside it).
    for (step, near_cameras) in [(0.12f64, false), (0.45, true)] {
        let mut y: f64 = -5.5;
        while y < 3.0 {
            let mut x: f64 = -5.5;
            while x < 5.5 {
                let middle = x.abs() < 3.0 && (y.hypot(x) < 2.4 || y > 1.0);
                if middle != near_cameras {
                    let rgb = texture(x, y, [0.62, 0.58, 0.5], &mut rng);
                    flat(&mut g, &mut rng, [x, y, 0.0], 2, 0.55 * step, rgb);
                }
                x += step;
            }
            y += step;
        }
    }
    // Back wall and side walls.
    for (axis, fixed) in [(1usize, 3.0f64), (0, -3.0), (0, 3.0)] {
        let mut a = -3.0;
        while a < 3.0 {
            let mut z = 0.08;
            while z < 2.6 {
                let p = if axis == 1 {
                    [a, fixed, z]
                } else {
                    [fixed, a, z]
                };
                let rgb = texture(a, z, [0.35, 0.42, 0.62], &mut rng);
                flat(&mut g, &mut rng, p, axis, 0.065, rgb);
                z += 0.11;
            }
            a += 0.11;
        }
    }
    // A figure walking along x through the clip: a column of blobs whose 4D rotation tilts
    // time into x (velocity ≈ 1 m per model unit), with a colour that changes in time.
    for n in 0..900 {
        let h = rng.range(0.05, 1.7);
        let r = rng.range(0.0, 0.22);
        let a = rng.range(0.0, std::f64::consts::TAU);
        let mean = [
            (r * a.cos()) as f32,
            (0.3 + r * a.sin()) as f32,
            h as f32,
            1.0,
        ];
        let s = rng.range(0.035, 0.06).ln() as f32;
        let rgb = if h > 1.45 {
            [0.9, 0.75, 0.6]
        } else {
            [0.75, 0.2 + 0.1 * (n % 3) as f64, 0.15]
        };
        let i = g.push(mean, [s, s, s, 0.4], 3.0, rgb.map(|v| v as f32));
        // ql · qr = rotation by 2·0.39 rad in the (t, x) plane.
        let (sn, cs) = (0.39f32).sin_cos();
        g.rot_left[i] = [cs, sn, 0.0, 0.0];
        g.rot_right[i] = [cs, -sn, 0.0, 0.0];
        // Temporal colour: brighter green late in the clip.
        g.colours[(i * k + spatial) * 3 + 1] = 0.25;
    }
    // Objects that exist only early (left, green) or late (right, blue).
    for (cx, t, rgb) in [
        (-1.6f64, 0.3f32, [0.2, 0.85, 0.25]),
        (1.6, 1.7, [0.2, 0.3, 0.95]),
    ] {
        for _ in 0..300 {
            let p = [
                cx + rng.range(-0.35, 0.35),
                rng.range(0.6, 1.2),
                rng.range(0.05, 0.7),
            ];
            let s = rng.range(0.04, 0.07).ln() as f32;
            let mean = [p[0] as f32, p[1] as f32, p[2] as f32, t];
            g.push(mean, [s, s, s, -1.2], 2.5, rgb.map(|v| v as f32));
        }
    }
    // Four cameras on a 100° arc, 480×360, principal point a little off centre.
    let eyes: Vec<DVec3> = (0..4)
        .map(|c| {
            let angle = (-50.0 + 100.0 * c as f64 / 3.0f64).to_radians();
            DVec3::new(3.4 * angle.sin(), -3.4 * angle.cos(), 1.6)
        })
        .collect();
    // Large, faint "fill" Gaussians as training leaves them (metres across, centred below
    // and beside the cameras' views, far off-screen, covering much of every picture).
    for eye in &eyes {
        let forward = (DVec3::new(0.0, 0.6, 0.8) - *eye).normalize();
        let side = forward.cross(DVec3::Z).normalize();
        for _ in 0..4 {
            let p = *eye
                + forward * rng.range(1.5, 3.0)
                + side * rng.range(-2.5, 2.5)
                + DVec3::Z * rng.range(-3.5, -2.5);
            let s = rng.range(1.8, 3.0).ln() as f32;
            let mean = [p.x as f32, p.y as f32, p.z as f32, 1.0];
            let grey = rng.range(0.45, 0.65) as f32;
            g.push(
                mean,
                [s, s, 0.8 * s, 1.5],
                rng.range(-2.0, -1.4) as f32,
                [grey, grey * 0.95, grey * 0.85],
            );
        }
    }
    let cameras = (0..4)
        .map(|c| {
            let eye = eyes[c];
            let mut intrinsics = Intrinsics::from_hfov(480, 360, 68.0);
            intrinsics.cx -= 0.6;
            intrinsics.cy += 0.4;
            Camera {
                name: format!("cam{c}"),
                intrinsics,
                distortion: Distortion::None,
                world_to_camera: WorldToCamera::look_at(eye, DVec3::new(0.0, 0.6, 0.8), DVec3::Z)
                    .unwrap(),
            }
        })
        .collect();
    (g, CameraSet::new(cameras))
}

/// Multiply the opacity of every Gaussian in `viewer/model.4dgs` by `factor`: an export
/// with a deliberately wrong opacity.
fn break_opacity(viewer: &Path, factor: f32) {
    let path = viewer.join("model.4dgs");
    let mut bytes = std::fs::read(&path).unwrap();
    let (header, _) = web4d::decode(&bytes).unwrap();
    let len = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let start = (12 + len).div_ceil(16) * 16;
    for record in bytes[start..]
        .chunks_exact_mut(header.texels * 16)
        .take(header.count)
    {
        let at = 7 * 4 + 2; // word 7, high half: σ(o)
        let o = half::f16::from_le_bytes([record[at], record[at + 1]]).to_f32();
        record[at..at + 2].copy_from_slice(&half::f16::from_f32(o * factor).to_le_bytes());
    }
    std::fs::write(&path, bytes).unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

fn keep(png: &Path, name: &str, engine: &image::RgbImage) {
    if let Some(dir) = std::env::var_os("SPLAT4D_KEEP_SHOTS") {
        let shot = image::open(png).unwrap().to_rgb8();
        let _ = std::fs::create_dir_all(&dir);
        let _ = side_by_side(&[&shot, engine]).save(Path::new(&dir).join(name));
    }
}

#[test]
fn viewer_matches_the_engine_at_cameras_times_and_a_novel_view_and_plays_the_splatv() {
    let Some(browser) = Browser::find() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (model, cameras) = demo_like_scene();
    let times = even_times(&model, 25);
    // Trained on a colour (`[train] background`): the page must draw it behind the
    // splats as the engine does. A blue unlike the scene, so that lost coverage shows.
    let background = [0.15, 0.45, 0.85];
    let opts = ExportOptions {
        model4d: false,
        splatv: true,
        viewer_bundle: Some(browser.bundle.clone()),
        background,
        ..Default::default()
    };
    export_all(&model, &cameras, &times, dir.path(), &opts, &NoProgress).unwrap();
    // The same export with every opacity at 40 %: what the page shows must differ.
    copy_dir(&dir.path().join("viewer"), &dir.path().join("broken"));
    break_opacity(&dir.path().join("broken"), 0.4);
    let port = serve(dir.path().to_path_buf());

    let last = times.len() - 1;
    let mid = last / 2;
    let shots_dir = dir.path().join("shots");
    std::fs::create_dir_all(&shots_dir).unwrap();
    // A viewpoint no camera had: above and between cameras 0 and 1, nearer the room.
    let novel = {
        let (a, b) = (
            cameras.cameras[0].world_to_camera.centre(),
            cameras.cameras[1].world_to_camera.centre(),
        );
        let eye = 0.5 * (a + b) * 0.8 + DVec3::new(0.0, 0.0, 0.7);
        let mut cam = cameras.cameras[0].clone();
        cam.name = "novel".into();
        cam.world_to_camera =
            WorldToCamera::look_at(eye, DVec3::new(0.2, 0.8, 0.7), DVec3::Z).unwrap();
        cam
    };
    let pose = {
        let w = &novel.world_to_camera;
        let q = glam::DQuat::from_mat3(&w.rotation()).normalize();
        let t = w.translation;
        format!("{},{},{},{},{},{},{}", q.w, q.x, q.y, q.z, t[0], t[1], t[2])
    };
    // A moment between two export steps: the page slices at any time.
    let between = 0.37;
    let t_between = times[0] + between * (times[last] - times[0]);
    // (what, page, query, camera, model time)
    let mut cases: Vec<(String, &str, String, Camera, f64)> = Vec::new();
    let cam = |k: usize| cameras.cameras[k].clone();
    for f in [0, mid, last] {
        cases.push((
            format!("viewer cam0 frame {f}"),
            "viewer/index.html",
            format!("camera=0&frame={f}"),
            cam(0),
            times[f],
        ));
    }
    cases.push((
        format!("viewer cam3 frame {mid}"),
        "viewer/index.html",
        format!("camera=3&frame={mid}"),
        cam(3),
        times[mid],
    ));
    cases.push((
        format!("viewer cam1 frame 0 → {last} in the page"),
        "viewer/index.html",
        format!("camera=1&frame=0&goto={last}"),
        cam(1),
        times[last],
    ));
    cases.push((
        format!("viewer cam2 t {between}"),
        "viewer/index.html",
        format!("camera=2&t={between}"),
        cam(2),
        t_between,
    ));
    for f in [mid, last] {
        cases.push((
            format!("viewer novel view frame {f}"),
            "viewer/index.html",
            format!("camera=0&pose={pose}&frame={f}"),
            novel.clone(),
            times[f],
        ));
    }
    for f in [0, mid, last] {
        cases.push((
            format!("splatv cam0 frame {f}"),
            "viewer/splatv.html",
            format!("camera=0&frame={f}"),
            cam(0),
            times[f],
        ));
    }
    for f in [0, mid, last] {
        cases.push((
            format!("broken opacity cam0 frame {f}"),
            "broken/index.html",
            format!("camera=0&frame={f}"),
            cam(0),
            times[f],
        ));
    }
    let shots: Vec<(String, PathBuf)> = cases
        .iter()
        .enumerate()
        .map(|(n, (_, folder, query, _, _))| {
            (
                format!("http://127.0.0.1:{port}/{folder}?ui=0&play=0&{query}"),
                shots_dir.join(format!("shot{n:02}.png")),
            )
        })
        .collect();
    let size = {
        let i = &cameras.cameras[0].intrinsics;
        (i.width, i.height)
    };
    browser.screenshots(&shots_dir.join("profile"), size, &shots);

    let mut report = Vec::new();
    let mut failures = Vec::new();
    let key_times = [0, mid, last].map(|f| times[f]);
    let cam0_renders: Vec<image::RgbImage> = key_times
        .iter()
        .map(|&t| engine_render(&model, &cameras.cameras[0], t, background))
        .collect();
    for ((what, _, _, cam, t), (_, png)) in cases.iter().zip(&shots) {
        let engine = engine_render(&model, cam, *t, background);
        let shot = image::open(png).expect("screenshot PNG").to_rgb8();
        let db = psnr(&shot, &engine);
        keep(
            png,
            &format!("{}.png", what.replace([' ', '→'], "_")),
            &engine,
        );
        report.push(format!("{what}: {db:.2} dB"));
        let ok = if what.starts_with("broken") {
            db < FLOOR_DB
        } else if what.starts_with("splatv") {
            // The clip is mapped onto the player's [0, 1]: this moment, not another one.
            let others: Vec<f64> = key_times
                .iter()
                .zip(&cam0_renders)
                .filter(|(k, _)| *k != t)
                .map(|(_, r)| psnr(&shot, r))
                .collect();
            report.push(format!(
                "  (against the other two moments: {others:.2?} dB)"
            ));
            db >= SPLATV_FLOOR_DB && others.iter().all(|o| db > o + 1.0)
        } else {
            db >= FLOOR_DB
        };
        if !ok {
            failures.push(format!("{what}: {db:.2} dB"));
        }
    }
    eprintln!(
        "viewer against the engine (PSNR):\n  {}",
        report.join("\n  ")
    );
    assert!(
        failures.is_empty(),
        "viewer does not match the engine (floor {FLOOR_DB} dB; .splatv {SPLATV_FLOOR_DB} dB and closest to its own moment; a broken opacity must fall below {FLOOR_DB} dB): {failures:?}\nall: {report:#?}"
    );
}

/// A static grey backdrop, a red blob on the left early (t ≈ 0.1) and a blue blob on the
/// right late (t ≈ 0.9). World z is up; the camera looks along +y.
fn moving_scene() -> Gaussians<f32> {
    let mut g = grey_wall(1.0);
    for (cx, t, rgb) in [
        (-0.7f32, 0.1f32, [0.95, 0.1, 0.1]),
        (0.7, 0.9, [0.1, 0.2, 0.95]),
    ] {
        for i in 0..8 {
            for k in 0..8 {
                let x = cx - 0.35 + 0.7 * i as f32 / 7.0;
                let z = -0.35 + 0.7 * k as f32 / 7.0;
                g.push([x, 0.0, z, t], [-2.2, -2.2, -2.2, -1.6], 3.0, rgb);
            }
        }
    }
    g
}

/// A still grey wall (240 Gaussians) at y = 0.8 in a clip of `seconds`, colour at DC.
fn grey_wall(seconds: f64) -> Gaussians<f32> {
    let mut g = Gaussians::<f32>::new(
        ColourDegrees::FULL,
        TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: seconds,
        },
    );
    g.active = ColourDegrees::DC;
    for i in 0..20 {
        for k in 0..12 {
            let x = -1.5 + 3.0 * i as f32 / 19.0;
            let z = -1.0 + 2.0 * k as f32 / 11.0;
            g.push(
                [x, 0.8, z, 0.5],
                [-2.0, -2.5, -2.0, 3.0],
                2.0,
                [0.55, 0.55, 0.5],
            );
        }
    }
    g
}

fn two_cameras() -> CameraSet {
    let cam = |name: &str, eye: DVec3| Camera {
        name: name.into(),
        intrinsics: Intrinsics::from_hfov(640, 480, 60.0),
        distortion: Distortion::None,
        world_to_camera: WorldToCamera::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap(),
    };
    CameraSet::new(vec![
        cam("cam0", DVec3::new(0.0, -4.0, 0.3)),
        cam("cam1", DVec3::new(1.0, -3.8, 0.2)),
    ])
}

/// Counts of pixels in the canvas area (the top and bottom UI strips left out) that are
/// far from the black background, strongly red, and strongly blue.
fn census(img: &image::RgbImage) -> (usize, usize, usize) {
    let (w, h) = img.dimensions();
    let (mut lit, mut red, mut blue) = (0, 0, 0);
    for y in 40..h.saturating_sub(90) {
        for x in 0..w {
            let [r, g, b] = img.get_pixel(x, y).0.map(|v| v as i32);
            if r + g + b > 60 {
                lit += 1;
            }
            if r > 120 && r > g + 60 && r > b + 60 {
                red += 1;
            }
            if b > 120 && b > r + 60 && b > g + 40 {
                blue += 1;
            }
        }
    }
    (lit, red, blue)
}

#[test]
fn viewer_shows_the_scene_and_changes_with_time() {
    let Some(browser) = Browser::find() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model = moving_scene();
    let times: Vec<f64> = (0..5).map(|k| k as f64 / 4.0).collect();
    let opts = ExportOptions {
        frames: false,
        model4d: false,
        splatv: false,
        viewer_bundle: Some(browser.bundle.clone()),
        ..Default::default()
    };
    let report = export_all(
        &model,
        &two_cameras(),
        &times,
        dir.path(),
        &opts,
        &NoProgress,
    )
    .unwrap();
    let index = report.viewer_index.unwrap();
    assert!(index.is_file());
    let port = serve(dir.path().join("viewer"));

    let shots = dir.path().join("shots");
    std::fs::create_dir_all(&shots).unwrap();
    // Frame 0, frame 4, and frame 4 reached from frame 0 inside one page (?goto), with the
    // page's controls showing.
    let pairs: Vec<(String, PathBuf)> = ["frame=0", "frame=4", "frame=0&goto=4"]
        .iter()
        .enumerate()
        .map(|(k, q)| {
            (
                format!("http://127.0.0.1:{port}/index.html?{q}&play=0"),
                shots.join(format!("shot{k}.png")),
            )
        })
        .collect();
    browser.screenshots(&shots.join("profile"), (640, 480), &pairs);
    let mut results = Vec::new();
    for (frame, (_, png)) in [0, 4, 4].iter().zip(&pairs) {
        let img = image::open(png).expect("screenshot PNG").to_rgb8();
        let c = census(&img);
        eprintln!("frame {frame}: {c:?} (lit, red, blue pixels)");
        results.push((img, c));
    }
    let total = {
        let (w, h) = results[0].0.dimensions();
        (w * h) as usize
    };
    let ((a, ca), (b, cb)) = (&results[0], &results[1]);
    assert!(
        ca.0 > total / 20 && cb.0 > total / 20,
        "canvas looks blank: {ca:?} {cb:?}"
    );
    // Early: the red blob, no blue one; late: the other way round.
    assert!(
        ca.1 > 500 && ca.2 < ca.1 / 10,
        "frame 0 should show red: {ca:?}"
    );
    assert!(
        cb.2 > 500 && cb.1 < cb.2 / 10,
        "frame 4 should show blue: {cb:?}"
    );
    assert_eq!(
        results[2].1, *cb,
        "the frame reached in the page is frame 4"
    );
    let diff: u64 = a
        .pixels()
        .zip(b.pixels())
        .map(|(p, q)| {
            (0..3)
                .map(|k| (p.0[k] as i64 - q.0[k] as i64).unsigned_abs())
                .sum::<u64>()
        })
        .sum();
    assert!(
        diff as f64 / total as f64 > 5.0,
        "screenshots barely differ: {diff}"
    );
}

/// A 12-second clip: the grey wall throughout and, in each second, a blob that lives
/// about a second, red on the left in even seconds and blue on the right in odd ones.
fn long_scene() -> Gaussians<f32> {
    let mut g = grey_wall(12.0);
    for second in 0..12 {
        let (cx, rgb) = if second % 2 == 0 {
            (-0.7f32, [0.95, 0.1, 0.1])
        } else {
            (0.7, [0.1, 0.2, 0.95])
        };
        for i in 0..6 {
            for k in 0..6 {
                let x = cx - 0.3 + 0.6 * i as f32 / 5.0;
                let z = -0.3 + 0.6 * k as f32 / 5.0;
                g.push(
                    [x, 0.0, z, second as f32 + 0.5],
                    [-2.2, -2.2, -2.2, -1.3],
                    3.0,
                    rgb,
                );
            }
        }
    }
    g
}

#[test]
fn a_long_clip_plays_from_time_segments_as_from_one_file() {
    let Some(browser) = Browser::find() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model = long_scene();
    let cameras = two_cameras();
    let times: Vec<f64> = (0..=48).map(|k| k as f64 / 4.0).collect();
    for (name, segment_seconds) in [("segments", 2.0), ("one", 0.0)] {
        let opts = ExportOptions {
            gltf: false,
            model4d: false,
            segment_seconds,
            viewer_bundle: Some(browser.bundle.clone()),
            ..Default::default()
        };
        export_all(
            &model,
            &cameras,
            &times,
            &dir.path().join(name),
            &opts,
            &NoProgress,
        )
        .unwrap();
    }
    let scene: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.path().join("segments/viewer/scene.json")).unwrap(),
    )
    .unwrap();
    let segments = scene["segments"]
        .as_array()
        .expect("scene.json lists segments");
    assert_eq!(segments.len(), 6, "12 s in 2-s segments");
    assert_eq!(
        scene["model"]["gaussians"], 240,
        "the wall alone is drawn throughout"
    );
    let one: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("one/viewer/scene.json")).unwrap())
            .unwrap();
    assert!(one.get("segments").is_none());
    let port = serve(dir.path().to_path_buf());

    // Frames in a segment's middle, at its boundaries, the clip's ends, and one reached by
    // stepping inside the page from the start (segments loaded and dropped on the way).
    let cases: Vec<(String, f64)> = [
        ("frame=2", 0.5),
        ("frame=16", 4.0),
        ("frame=17", 4.25),
        ("frame=26", 6.5),
        ("frame=48", 12.0),
        ("frame=0&goto=38", 9.5),
    ]
    .iter()
    .map(|&(q, t)| (q.to_string(), t))
    .collect();
    let shots_dir = dir.path().join("shots");
    std::fs::create_dir_all(&shots_dir).unwrap();
    let mut pairs = Vec::new();
    for folder in ["segments", "one"] {
        for (n, (q, _)) in cases.iter().enumerate() {
            pairs.push((
                format!("http://127.0.0.1:{port}/{folder}/viewer/index.html?ui=0&play=0&{q}"),
                shots_dir.join(format!("{folder}{n}.png")),
            ));
        }
    }
    browser.screenshots(&shots_dir.join("profile"), (640, 480), &pairs);
    let mut failures = Vec::new();
    for (n, (q, t)) in cases.iter().enumerate() {
        let seg = image::open(shots_dir.join(format!("segments{n}.png")))
            .unwrap()
            .to_rgb8();
        let whole = image::open(shots_dir.join(format!("one{n}.png")))
            .unwrap()
            .to_rgb8();
        let engine = engine_render(&model, &cameras.cameras[0], *t, [0.0; 3]);
        keep(
            &shots_dir.join(format!("segments{n}.png")),
            &format!("segments_{n}.png"),
            &engine,
        );
        let state: serde_json::Value = serde_json::from_slice(
            &std::fs::read(shots_dir.join(format!("segments{n}.png.json"))).unwrap(),
        )
        .unwrap();
        let held = state["segments"].as_array().map_or(0, |a| a.len());
        let (a, b) = (psnr(&seg, &engine), psnr(&seg, &whole));
        eprintln!(
            "{q} (t = {t}): {a:.2} dB against the engine, {b:.2} dB against one file; {held} segments held"
        );
        if a < FLOOR_DB || b < FLOOR_DB || !(1..=3).contains(&held) {
            failures.push(format!("{q}: {a:.2} / {b:.2} dB, {held} segments"));
        }
    }
    assert!(
        failures.is_empty(),
        "segmented playback differs or holds too much: {failures:?}"
    );
}

/// The viewer's JavaScript unit tests (`viewer/test/unit/`, Node's test runner): pose
/// conversions in every branch, orbiting without roll at a kept distance, the depth sort
/// against a direct cull and sort.
#[test]
fn viewer_javascript_unit_tests_pass() {
    let Some(browser) = Browser::find() else {
        return;
    };
    let viewer = Path::new(env!("CARGO_MANIFEST_DIR")).join("viewer");
    let out = std::process::Command::new(&browser.node)
        .args(["--test", "test/unit/"])
        .current_dir(&viewer)
        .output()
        .expect("start node");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("# fail 0"),
        "viewer unit tests failed:\n{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Lowest PSNR (dB) of the page against the engine where a learned backdrop shows: the
/// page samples its texture baked to 8 bits with the GPU's bilinear filter.
const BACKDROP_FLOOR_DB: f64 = 38.0;

#[test]
fn viewer_draws_the_learned_backdrop_as_the_engine_does() {
    use splat4d::render::RenderBackend;
    use splat4d::render::backdrop::Backdrop;
    let Some(browser) = Browser::find() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model = moving_scene();
    let cameras = two_cameras();
    // A sphere 6 units out, textured with smooth colour waves on its finest level only
    // (so the baked texture is that level), around the grey wall of splats.
    let mut backdrop =
        Backdrop::around(&cameras.cameras, &[[0.0, 6.0, 0.0]], [0.0; 3], 64).expect("a backdrop");
    let finest = backdrop.levels.last_mut().unwrap();
    let w = finest.width;
    for (i, t) in finest.texels.iter_mut().enumerate() {
        let (u, v) = ((i % w) as f32 / w as f32, (i / w) as f32 / (w / 2) as f32);
        let a = std::f32::consts::TAU * u;
        let b = std::f32::consts::PI * v;
        *t = [
            0.5 + 0.4 * (3.0 * a).sin() * b.sin(),
            0.5 + 0.4 * (2.0 * b).cos(),
            0.5 + 0.4 * (a + b).sin(),
        ];
    }
    let times = [0.0, 1.0];
    let opts = ExportOptions {
        frames: false,
        model4d: false,
        splatv: false,
        gltf: false,
        viewer_bundle: Some(browser.bundle.clone()),
        backdrop: Some(backdrop.clone()),
        ..Default::default()
    };
    export_all(&model, &cameras, &times, dir.path(), &opts, &NoProgress).unwrap();
    let port = serve(dir.path().join("viewer"));
    let shots_dir = dir.path().join("shots");
    std::fs::create_dir_all(&shots_dir).unwrap();
    let shots: Vec<(String, PathBuf)> = (0..2)
        .map(|k| {
            (
                format!("http://127.0.0.1:{port}/index.html?ui=0&play=0&camera={k}&frame=0"),
                shots_dir.join(format!("backdrop{k}.png")),
            )
        })
        .collect();
    let i = &cameras.cameras[0].intrinsics;
    browser.screenshots(&shots_dir.join("profile"), (i.width, i.height), &shots);
    for (k, (_, png)) in shots.iter().enumerate() {
        let cam = &cameras.cameras[k];
        let mut r = splat4d::CpuBackend
            .render(&model, cam, 0.0, &Default::default())
            .expect("engine render");
        backdrop.draw(cam, &mut r);
        let px = r
            .rgb
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8);
        let engine = image::RgbImage::from_raw(r.width, r.height, px.collect()).unwrap();
        let flat = engine_render(&model, cam, 0.0, [0.0; 3]);
        let shot = image::open(png).expect("screenshot PNG").to_rgb8();
        keep(png, &format!("backdrop_cam{k}.png"), &engine);
        let (db, db_flat) = (psnr(&shot, &engine), psnr(&shot, &flat));
        eprintln!("cam{k}: backdrop {db:.2} dB, against the flat background {db_flat:.2} dB");
        assert!(
            db >= BACKDROP_FLOOR_DB && db_flat < db - 10.0,
            "cam{k}: the page's backdrop is {db:.2} dB from the engine's (floor {BACKDROP_FLOOR_DB}), {db_flat:.2} dB from a flat background"
        );
    }
}
