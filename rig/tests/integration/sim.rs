//! The simulator end to end: capture layout, timing of video and audio against the
//! scene, ground-truth projection, effects that are off, bad scene files.

use crate::common;

use common::*;
use glam::DVec3;
use rig::sim::{OffsetsFile, Scene, SimError, simulate};
use shared_types::{CameraSet, Distortion, NoProgress};

fn offsets(dir: &std::path::Path) -> OffsetsFile {
    serde_json::from_slice(&std::fs::read(dir.join("groundtruth/offsets.json")).unwrap()).unwrap()
}

/// Counts progress units.
#[derive(Default)]
struct Count(std::sync::atomic::AtomicU64, std::sync::atomic::AtomicU64);

impl shared_types::Progress for Count {
    fn start(&self, total: u64, _unit: &str) {
        self.0.store(total, std::sync::atomic::Ordering::SeqCst);
    }
    fn advance(&self, n: u64) {
        self.1.fetch_add(n, std::sync::atomic::Ordering::SeqCst);
    }
    fn message(&self, _msg: &str) {}
    fn finish(&self) {}
}

#[test]
fn tiny_writes_a_capture_laid_out_like_a_real_one() {
    let scene = Scene::from_file(&fixture("tiny.toml")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let count = Count::default();
    let summary = simulate(&scene, tmp.path(), &count).unwrap();
    let (total, done) = (count.0.into_inner(), count.1.into_inner());
    assert_eq!((total, done), (4 * 15 + 15 + 8, 4 * 15 + 15 + 8));
    assert_eq!(summary.videos.len(), 4);
    assert_eq!(summary.video_frames, 4 * 15);
    let raw: Vec<_> = std::fs::read_dir(tmp.path().join("raw"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(raw.len(), 4);
    for i in 0..4 {
        let file = tmp.path().join(format!("raw/cam{i}/GX010001.MP4"));
        let bytes = std::fs::read(&file).unwrap();
        assert_eq!(&bytes[4..8], b"ftyp", "{file:?} is not an MP4");
        assert_eq!(video_pts(&file).len(), 15);
        assert!(audio(&file).is_none(), "no [audio] table: no audio stream");
    }
    for i in 0..8 {
        let p = tmp.path().join(format!("stills/still_{i:02}.jpg"));
        let img = image::open(&p).unwrap();
        assert_eq!((img.width(), img.height()), (160, 120));
    }
    let cams: CameraSet = serde_json::from_slice(
        &std::fs::read(tmp.path().join("groundtruth/cameras.json")).unwrap(),
    )
    .unwrap();
    let names: Vec<&str> = cams.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(&names[..5], ["cam0", "cam1", "cam2", "cam3", "heldout0"]);
    assert_eq!(names.len(), 13);
    assert!(cams.get("still_07").is_some());
    let o = offsets(tmp.path());
    assert_eq!(o.cameras.len(), 4);
    assert_eq!(o.cameras[2].files[0].file, "raw/cam2/GX010001.MP4");
    let (h, w, depth) = rig::sim::output::read_npy_f32(
        &std::fs::read(tmp.path().join("groundtruth/depth/cam1.npy")).unwrap(),
    )
    .unwrap();
    assert_eq!((h, w), (120, 160));
    assert!(
        depth.iter().all(|d| d.is_finite() && *d > 0.1 && *d < 15.0),
        "the room closes every view"
    );
    let ts: rig::sim::HeldoutTimestamps = serde_json::from_slice(
        &std::fs::read(
            tmp.path()
                .join("groundtruth/heldout/heldout0/timestamps.json"),
        )
        .unwrap(),
    )
    .unwrap();
    assert_eq!(ts.times_s.len(), 15);
    assert!((ts.times_s[3] - 0.2).abs() < 1e-12);
    assert!(
        tmp.path()
            .join("groundtruth/heldout/heldout0/000014.png")
            .exists()
    );
    // Moving objects appear in the masks.
    let mask = image::open(tmp.path().join("groundtruth/masks/cam0/000005.png"))
        .unwrap()
        .to_luma8();
    assert!(mask.pixels().filter(|p| p.0[0] == 255).count() > 50);
    // A second run refuses to overwrite the capture.
    assert!(matches!(
        simulate(&scene, tmp.path(), &NoProgress),
        Err(SimError::CaptureExists { .. })
    ));
}

#[test]
fn effects_that_are_off_leave_the_output_bit_identical() {
    let plain = Scene::from_file(&fixture("tiny.toml")).unwrap();
    let mut t = fixture_table("tiny.toml");
    for i in 0..4 {
        let c = video_cam(&mut t, i);
        c.insert("offset".into(), 0.0.into());
        c.insert("phase".into(), 0.0.into());
        c.insert("exposure".into(), 1.0.into());
        c.insert("dropped".into(), toml::Value::Array(vec![]));
        c.insert("distortion".into(), toml::toml! { model = "none" }.into());
    }
    t.insert(
        "audio".into(),
        toml::toml! { enabled = false clap_time = 0.5 }.into(),
    );
    t.insert(
        "flash".into(),
        toml::toml! { enabled = false time = 0.5 }.into(),
    );
    t.insert("noise".into(), toml::toml! { sigma = 0.0 }.into());
    let off = scene_of(&t, "tiny-with-effects-off");
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    simulate(&plain, a.path(), &NoProgress).unwrap();
    simulate(&off, b.path(), &NoProgress).unwrap();
    let (ta, tb) = (tree(a.path()), tree(b.path()));
    assert_eq!(ta.len(), tb.len());
    for ((na, ba), (nb, bb)) in ta.iter().zip(&tb) {
        assert_eq!(na, nb);
        assert!(ba == bb, "{na} differs");
    }
    // And the same scene and seed give the same bytes again (determinism).
    let c = tempfile::tempdir().unwrap();
    simulate(&plain, c.path(), &NoProgress).unwrap();
    assert!(tree(c.path()) == ta);
}

#[test]
fn video_timestamps_follow_offsets_drops_and_chapters() {
    let mut t = fixture_table("tiny.toml");
    {
        let c = video_cam(&mut t, 1);
        c.insert("offset".into(), 0.25.into());
        c.insert("phase".into(), 0.5.into());
        c.insert(
            "dropped".into(),
            toml::Value::Array(vec![3i64.into(), 4i64.into(), 11i64.into()]),
        );
        c.insert("chapter_frames".into(), 8i64.into());
    }
    let scene = scene_of(&t, "tiny-timing");
    let tmp = tempfile::tempdir().unwrap();
    simulate(&scene, tmp.path(), &NoProgress).unwrap();
    let o = offsets(tmp.path());
    let cam = &o.cameras[1];
    assert!((cam.start_time_s - (0.25 + 0.5 / 15.0)).abs() < 1e-12);
    assert_eq!(cam.dropped_frames, [3, 4, 11]);
    assert_eq!(cam.files.len(), 2);
    let ch1 = tmp.path().join("raw/cam1/GX010001.MP4");
    let ch2 = tmp.path().join("raw/cam1/GX020001.MP4");
    assert_eq!(cam.files[1].file, "raw/cam1/GX020001.MP4");
    let want1: Vec<f64> = [0, 1, 2, 5, 6, 7]
        .iter()
        .map(|&k| k as f64 / 15.0)
        .collect();
    let want2: Vec<f64> = [0, 1, 2, 4, 5, 6]
        .iter()
        .map(|&k| k as f64 / 15.0)
        .collect(); // frames 8..15 minus 11
    for (got, want) in [(video_pts(&ch1), want1), (video_pts(&ch2), want2)] {
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 1e-6, "pts {g} vs {w}");
        }
    }
    // The content matches the declared time: frame k of cam1 equals a clean render at
    // start_time + k/fps, and not one a frame earlier or later.
    let frames = video_frames(&ch1);
    let (_, decoded) = &frames[3]; // frame index 5
    let clean = |t: f64| -> Vec<u8> {
        let r = rig::sim::render_clean(&scene, "cam1", t).unwrap();
        r.color
            .iter()
            .flat_map(|c| c.map(|v| (v * 255.0).round() as u8))
            .collect()
    };
    let t5 = cam.start_time_s + 5.0 / 15.0;
    // Compare only where the scene changes between neighbouring frames (the moving objects).
    let (c0, cm, cp) = (clean(t5), clean(t5 - 1.0 / 15.0), clean(t5 + 1.0 / 15.0));
    let moving: Vec<usize> = (0..c0.len())
        .filter(|&i| c0[i].abs_diff(cm[i]) > 40 || c0[i].abs_diff(cp[i]) > 40)
        .collect();
    assert!(moving.len() > 100);
    let err_at = |t: f64| {
        let c = clean(t);
        moving
            .iter()
            .map(|&i| c[i].abs_diff(decoded[i]) as f64)
            .sum::<f64>()
            / moving.len() as f64
    };
    let (now, before, after) = (err_at(t5), err_at(t5 - 1.0 / 15.0), err_at(t5 + 1.0 / 15.0));
    assert!(
        now < 0.5 * before && now < 0.5 * after,
        "{now} {before} {after}"
    );
}

fn mean(rgb: &[u8]) -> f64 {
    rgb.iter().map(|&v| v as f64).sum::<f64>() / rgb.len() as f64
}

#[test]
fn exposure_and_sensor_noise_change_the_frames_they_should() {
    let plain = Scene::from_file(&fixture("tiny.toml")).unwrap();
    let mut t = fixture_table("tiny.toml");
    video_cam(&mut t, 2).insert("exposure".into(), 0.6.into());
    t.insert("noise".into(), toml::toml! { sigma = 0.03 }.into());
    let effects = scene_of(&t, "tiny-exposure-noise");
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    simulate(&plain, a.path(), &NoProgress).unwrap();
    simulate(&effects, b.path(), &NoProgress).unwrap();
    let frames = |dir: &std::path::Path, cam: usize| {
        video_frames(&dir.join(format!("raw/cam{cam}/GX010001.MP4")))
    };
    let (p2, e2) = (frames(a.path(), 2), frames(b.path(), 2));
    let ratio = mean(&e2[4].1) / mean(&p2[4].1);
    assert!(
        (ratio - 0.6).abs() < 0.03,
        "exposure 0.6 gave a brightness ratio of {ratio}"
    );
    let (p0, e0) = (frames(a.path(), 0), frames(b.path(), 0));
    let ratio0 = mean(&e0[4].1) / mean(&p0[4].1);
    assert!(
        (ratio0 - 1.0).abs() < 0.02,
        "cam0 keeps its exposure: {ratio0}"
    );
    // Noise: frames differ pixel by pixel, by about sigma (H.264 smooths some of it away).
    let diff: f64 = p0[4]
        .1
        .iter()
        .zip(&e0[4].1)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / p0[4].1.len() as f64;
    assert!(
        diff.sqrt() > 0.3 * 0.03 * 255.0,
        "rms difference {}",
        diff.sqrt()
    );
}

/// Lag (seconds) of the scene's clap in `samples`, by cross-correlation with the clap
/// waveform around `expect`, refined by parabolic interpolation.
fn clap_lag(seed: u64, rate: u32, samples: &[f32], expect: f64) -> f64 {
    let clap = rig::sim::audio::Clap::new(seed);
    let n = (rig::sim::audio::CLAP_LENGTH * rate as f64) as usize;
    let template: Vec<f64> = (0..n).map(|j| clap.at(j as f64 / rate as f64)).collect();
    let centre = (expect * rate as f64).round() as isize;
    let corr = |lag: isize| -> f64 {
        (0..n)
            .map(|j| {
                let k = lag + j as isize;
                if k < 0 || k as usize >= samples.len() {
                    0.0
                } else {
                    samples[k as usize] as f64 * template[j]
                }
            })
            .sum()
    };
    let search = (rate / 100) as isize;
    let best = (centre - search..=centre + search)
        .max_by(|&a, &b| corr(a).total_cmp(&corr(b)))
        .unwrap();
    let (l, c, r) = (corr(best - 1), corr(best), corr(best + 1));
    let frac = 0.5 * (l - r) / (l - 2.0 * c + r);
    (best as f64 + frac) / rate as f64
}

#[test]
fn audio_clap_and_frame_times_match_the_declared_offsets() {
    let scene = Scene::from_file(&fixture("sync-audio.toml")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    simulate(&scene, tmp.path(), &NoProgress).unwrap();
    let o = offsets(tmp.path());
    let truth = o.audio.clone().unwrap();
    let cams: CameraSet = serde_json::from_slice(
        &std::fs::read(tmp.path().join("groundtruth/cameras.json")).unwrap(),
    )
    .unwrap();
    for cam in &o.cameras {
        let a = cam.audio.as_ref().unwrap();
        let centre = cams.get(&cam.name).unwrap().world_to_camera.centre();
        let d = (centre - DVec3::from_array(truth.clap_position)).length();
        assert!((a.acoustic_delay_s - d / 343.0).abs() < 1e-12);
        let expect = truth.clap_time_s + d / 343.0 - cam.start_time_s;
        assert!((a.clap_file_time_s - expect).abs() < 1e-12);
        let file = tmp.path().join(&cam.files[0].file);
        let (rate, samples, first_pts) = audio(&file).unwrap();
        assert_eq!(rate, 48_000);
        assert!(
            first_pts.abs() < 1e-9,
            "audio starts with the video at file time 0, got {first_pts}"
        );
        let duration = 45.0 / 30.0;
        assert!(
            samples.len() as f64 >= duration * 48_000.0,
            "{} samples",
            samples.len()
        );
        let lag = clap_lag(scene.seed(), rate, &samples, expect);
        // Sub-sample accurate after AAC: well under 0.1 ms.
        assert!(
            (lag - expect).abs() < 1e-4,
            "{}: clap at {lag:.6} s, expected {expect:.6} s",
            cam.name
        );
        let pts = video_pts(&file);
        assert_eq!(pts.len(), 45);
        assert!((pts[44] - 44.0 / 30.0).abs() < 1e-6);
    }
}

#[test]
fn the_flash_lights_the_frames_and_rows_the_offsets_predict() {
    let scene = Scene::from_file(&fixture("sync-flash.toml")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    simulate(&scene, tmp.path(), &NoProgress).unwrap();
    let o = offsets(tmp.path());
    let fl = o.flash.clone().unwrap();
    for cam in &o.cameras {
        let frames = video_frames(&tmp.path().join(&cam.files[0].file));
        let file_time = cam.flash_file_time_s.unwrap();
        assert!((file_time - (fl.time_s - cam.start_time_s)).abs() < 1e-12);
        // Predicted gain of each row band (top / bottom half) of each frame.
        let gain = |k: usize, row: f64| {
            let a = k as f64 / o.fps + fl.readout_s * row;
            ((a + fl.shutter_s).min(file_time + fl.duration_s) - a.max(file_time)).max(0.0)
                / fl.shutter_s
        };
        let mean = |rgb: &[u8], top: bool| {
            let half = rgb.len() / 2;
            let part = if top { &rgb[..half] } else { &rgb[half..] };
            part.iter().map(|&v| v as f64).sum::<f64>() / part.len() as f64
        };
        let lit: Vec<usize> = (0..frames.len())
            .filter(|&k| gain(k, 0.25) > 0.0 || gain(k, 0.75) > 0.0)
            .collect();
        assert!(
            !lit.is_empty(),
            "{}: the flash falls inside the recording",
            cam.name
        );
        let base_top = mean(&frames[0].1, true);
        let base_bottom = mean(&frames[0].1, false);
        for (k, (_, rgb)) in frames.iter().enumerate() {
            let (top, bottom) = (mean(rgb, true) / base_top, mean(rgb, false) / base_bottom);
            let (gt, gb) = (gain(k, 0.25), gain(k, 0.75));
            if gt == 0.0 && gb == 0.0 {
                assert!(
                    (top - 1.0).abs() < 0.15 && (bottom - 1.0).abs() < 0.15,
                    "{} frame {k} lit",
                    cam.name
                );
            }
            if gt > 0.5 {
                assert!(
                    top > 1.3,
                    "{} frame {k}: top half should be lit (gain {gt}), ratio {top}",
                    cam.name
                );
            }
            if gb > 0.5 {
                assert!(
                    bottom > 1.3,
                    "{} frame {k}: bottom half should be lit (gain {gb}), ratio {bottom}",
                    cam.name
                );
            }
        }
    }
}

/// A red ball in a grey room, seen by a held-out camera with strong lens distortion.
fn marker_scene(distortion: &str) -> (Scene, DVec3) {
    // Put the ball where the held-out camera sees it far off-centre (normalised (0.6, −0.4)).
    let w2c = shared_types::WorldToCamera::look_at(
        DVec3::new(2.0, -1.0, 1.0),
        DVec3::new(0.0, 0.0, 0.8),
        DVec3::Z,
    )
    .unwrap();
    let ball = w2c.inverse_apply(DVec3::new(0.6, -0.4, 1.0) * 2.0);
    let text = format!(
        r#"
        [scene]
        duration = 0.2
        fps = 10
        seed = 3
        [background]
        kind = "room"
        texture = {{ kind = "solid", colors = [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]] }}
        [[objects]]
        shape = "sphere"
        radius = 0.04
        segments = 16
        position = [{}, {}, {}]
        texture = {{ kind = "solid", colors = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]] }}
        [render]
        ambient = 1.0
        diffuse = 0.0
        [cameras]
        width = 320
        height = 240
        hfov = 80
        [[cameras.video]]
        position = [3.0, -2.0, 1.6]
        look_at = [0.0, 0.0, 0.6]
        [[cameras.video]]
        position = [3.2, 1.2, 1.5]
        look_at = [0.0, 0.0, 0.6]
        [[cameras.video]]
        position = [-1.0, -3.3, 1.7]
        look_at = [0.0, 0.0, 0.6]
        [[cameras.video]]
        position = [1.2, -3.2, 1.2]
        look_at = [0.0, 0.0, 0.6]
        [[cameras.heldout]]
        position = [2.0, -1.0, 1.0]
        look_at = [0.0, 0.0, 0.8]
        distortion = {distortion}
        [stills]
        count = 0
        "#,
        ball.x, ball.y, ball.z
    );
    (Scene::from_toml_str(&text, "marker").unwrap(), ball)
}

#[test]
fn a_point_projected_by_the_ground_truth_camera_lands_on_its_rendered_pixel() {
    for distortion in [
        r#"{ model = "opencv", k1 = -0.3, k2 = 0.1, p1 = 0.002, p2 = -0.001 }"#,
        r#"{ model = "fisheye", k1 = 0.05, k2 = -0.02, k3 = 0.0, k4 = 0.0 }"#,
        r#"{ model = "none" }"#,
    ] {
        let (scene, ball) = marker_scene(distortion);
        let tmp = tempfile::tempdir().unwrap();
        simulate(&scene, tmp.path(), &NoProgress).unwrap();
        let cams: CameraSet = serde_json::from_slice(
            &std::fs::read(tmp.path().join("groundtruth/cameras.json")).unwrap(),
        )
        .unwrap();
        let cam = cams.get("heldout0").unwrap();
        assert_eq!(cam.distortion.is_none(), distortion.contains("none"));
        let (p, _) = cam.project(ball).unwrap();
        // The ball sits far off-centre, where the distortion moves it by many pixels.
        if let Distortion::Opencv { .. } = cam.distortion {
            let pinhole = shared_types::Camera {
                distortion: Distortion::None,
                ..cam.clone()
            };
            assert!((pinhole.project(ball).unwrap().0 - p).length() > 5.0);
        }
        let img = image::open(tmp.path().join("groundtruth/heldout/heldout0/000000.png"))
            .unwrap()
            .to_rgb8();
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for (x, y, px) in img.enumerate_pixels() {
            let [r, g, _] = px.0;
            if r > 150 && g < 100 {
                let wgt = (r as f64 - g as f64) / 255.0;
                sx += (x as f64 + 0.5) * wgt;
                sy += (y as f64 + 0.5) * wgt;
                n += wgt;
            }
        }
        assert!(n > 3.0, "{distortion}: ball not visible");
        let centroid = glam::DVec2::new(sx / n, sy / n);
        assert!(
            (centroid - p).length() < 0.75,
            "{distortion}: ball at {centroid}, projected {p}"
        );
    }
}

#[test]
fn ground_truth_depth_matches_projected_points() {
    let scene = Scene::from_file(&fixture("tiny.toml")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    simulate(&scene, tmp.path(), &NoProgress).unwrap();
    let cams: CameraSet = serde_json::from_slice(
        &std::fs::read(tmp.path().join("groundtruth/cameras.json")).unwrap(),
    )
    .unwrap();
    let mut checked = 0;
    for name in ["cam0", "cam1", "cam2", "cam3"] {
        let cam = cams.get(name).unwrap();
        let (h, w, depth) = rig::sim::output::read_npy_f32(
            &std::fs::read(tmp.path().join(format!("groundtruth/depth/{name}.npy"))).unwrap(),
        )
        .unwrap();
        // Points on the room's back-left walls and the floor far from every object.
        let mut points = Vec::new();
        for a in [-3.0, -1.5, 0.0, 1.5, 3.0] {
            for z in [0.5, 1.5, 2.5] {
                points.extend([DVec3::new(-4.0, a, z), DVec3::new(a, 4.0, z)]);
            }
            points.extend([DVec3::new(a, 2.5, 0.0), DVec3::new(-2.5, a, 0.0)]);
        }
        for p in points {
            let Some((px, z)) = cam.project(p) else {
                continue;
            };
            // Skip points whose line of sight passes the objects near the room's centre.
            let (c, dir) = (
                cam.world_to_camera.centre(),
                (p - cam.world_to_camera.centre()),
            );
            let closest = |q: DVec3| {
                let s = ((q - c).dot(dir) / dir.length_squared()).clamp(0.0, 1.0);
                (c + dir * s - q).length()
            };
            if closest(DVec3::new(0.0, 0.0, 0.6)) < 1.4 || closest(DVec3::new(0.0, 0.8, 1.2)) < 0.8
            {
                continue;
            }
            let (i, j) = (px.x.floor() as isize, px.y.floor() as isize);
            if i < 1 || j < 1 || i as usize >= w - 1 || j as usize >= h - 1 {
                continue;
            }
            let d = depth[j as usize * w + i as usize] as f64;
            assert!(
                (d - z).abs() < 0.02 * z,
                "{name}: depth {d} at {px}, point z {z}"
            );
            // The pixel ray through the projection comes back to the point.
            let ray = cam.pixel_ray(px);
            assert!(
                ray.cross((p - cam.world_to_camera.centre()).normalize())
                    .length()
                    < 1e-9
            );
            checked += 1;
        }
    }
    assert!(checked >= 20, "only {checked} points checked");
}

fn bad(text: &str) -> String {
    match Scene::from_toml_str(text, "bad.toml") {
        Ok(_) => panic!("accepted a bad scene"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_scene_files_give_clear_errors() {
    let tiny = std::fs::read_to_string(fixture("tiny.toml")).unwrap();
    let e = bad(&tiny.replace("seed = 7", "seed = 7\ncolour = 3"));
    assert!(e.contains("bad.toml") && e.contains("colour"), "{e}");
    let e = bad(&tiny.replace("fps = 15", "fps = 0"));
    assert!(e.contains("fps") && e.contains("bad.toml"), "{e}");
    assert!(bad(&tiny.replace("fps = 15", "fps = 23.5")).contains("NTSC"));
    let ntsc = Scene::from_toml_str(&tiny.replace("fps = 15", "fps = 29.97"), "ntsc.toml").unwrap();
    assert_eq!(ntsc.fps(), 30000.0 / 1001.0);
    let e = bad(&tiny.replacen("look_at = [0.0, 0.0, 0.6]", "look_at = [3.0, -2.0, 1.6]", 1));
    assert!(e.contains("cam0") && e.contains("looks at nothing"), "{e}");
    // Outside an empty world, looking away from the objects.
    let mut t = fixture_table("tiny.toml");
    t["background"]
        .as_table_mut()
        .unwrap()
        .insert("kind".into(), "none".into());
    video_cam(&mut t, 2).insert(
        "look_at".into(),
        toml::Value::Array(vec![(-5.0).into(), (-9.0).into(), 1.7.into()]),
    );
    let e = bad(&toml::to_string(&t).unwrap());
    assert!(e.contains("cam2") && e.contains("looks at nothing"), "{e}");
    let mut t = fixture_table("tiny.toml");
    t["cameras"]["video"].as_array_mut().unwrap().pop();
    let e = bad(&toml::to_string(&t).unwrap());
    assert!(
        e.contains("3 video cameras") && e.contains("exactly 4"),
        "{e}"
    );
    let e = bad(&tiny.replace("shape = \"sphere\"", "shape = \"torus\""));
    assert!(e.contains("torus"), "{e}");
    let mut t = fixture_table("tiny.toml");
    video_cam(&mut t, 0).insert(
        "distortion".into(),
        toml::toml! { model = "opencv" k1 = -3.0 k2 = 0.0 p1 = 0.0 p2 = 0.0 }.into(),
    );
    let mut t2 = t.clone();
    let e = bad(&toml::to_string(&t).unwrap());
    assert!(e.contains("cam0") && e.contains("distortion"), "{e}");
    video_cam(&mut t2, 0).insert("dropped".into(), toml::Value::Array(vec![0i64.into()]));
    assert!(bad(&toml::to_string(&t2).unwrap()).contains("cam0"));
    let e = Scene::from_file(std::path::Path::new("/nonexistent/scene.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/scene.toml"), "{e}");
}

#[test]
fn every_fixture_is_a_valid_scene() {
    for name in [
        "tiny.toml",
        "sync-audio.toml",
        "sync-flash.toml",
        "poses.toml",
        "demo.toml",
    ] {
        let s = Scene::from_file(&fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(s.video_cameras().count(), 4);
        assert_eq!(
            s.cameras
                .iter()
                .filter(|c| c.role == rig::sim::CameraRole::Still)
                .count(),
            8,
            "{name}"
        );
    }
    let demo = Scene::from_file(&fixture("demo.toml")).unwrap();
    assert_eq!(
        demo.cameras
            .iter()
            .filter(|c| c.role == rig::sim::CameraRole::Heldout)
            .count(),
        4
    );
    // The demo's video cameras span 100–120° around the figure.
    let dirs: Vec<f64> = demo
        .video_cameras()
        .map(|c| {
            let p = c.camera.world_to_camera.centre();
            p.y.atan2(p.x).to_degrees()
        })
        .collect();
    let span = dirs.iter().cloned().fold(f64::MIN, f64::max)
        - dirs.iter().cloned().fold(f64::MAX, f64::min);
    assert!((100.0..=120.0).contains(&span), "span {span}");
}

#[test]
fn inline_meshes_and_a_dome_render_where_declared() {
    let mut t = fixture_table("tiny.toml");
    let bg = t["background"].as_table_mut().unwrap();
    bg.insert("kind".into(), "dome".into());
    bg.insert("radius".into(), 6.0.into());
    // A 1 m square of two triangles standing at the origin, facing +x.
    let mesh: toml::Table = toml::toml! {
        shape = "mesh"
        vertices = [[0.0, -0.5, 0.2], [0.0, 0.5, 0.2], [0.0, 0.5, 1.2], [0.0, -0.5, 1.2]]
        triangles = [[0, 1, 2], [0, 2, 3]]
        texture = { kind = "solid", colors = [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]] }
    };
    t["objects"].as_array_mut().unwrap().push(mesh.into());
    let scene = scene_of(&t, "tiny-mesh-dome");
    let r = rig::sim::render_clean(&scene, "cam1", 0.0).unwrap();
    let mesh_id = 2 + 3; // background 1, three tiny objects, then the mesh
    let cam = &scene.cameras[1].camera;
    let (centre, _) = cam.project(DVec3::new(0.0, 0.0, 0.7)).unwrap();
    let k = centre.y.floor() as usize * r.width + centre.x.floor() as usize;
    assert_eq!(r.id[k], mesh_id as u16, "the mesh's centre is on its pixel");
    assert!(r.color[k][2] > 0.3 && r.color[k][0] < 0.05);
    assert!(
        r.id.iter().filter(|&&i| i == 1).count() > r.id.len() / 3,
        "the dome fills the background"
    );
    assert!(r.id.iter().all(|&i| i != 0), "the dome closes the view");
}

#[test]
fn heldout_cameras_can_be_filmed_as_videos() {
    let scene = Scene::from_file(&fixture("heldout-real.toml"))
        .unwrap()
        .with_heldout_videos(true);
    let dir = tempfile::tempdir().unwrap();
    let summary = simulate(&scene, dir.path(), &NoProgress).unwrap();
    let frames = scene.frames_per_camera() as usize;
    assert_eq!(
        summary.video_frames as usize,
        6 * frames,
        "4 rig cameras + 2 filmed held-out cameras"
    );
    let offsets: OffsetsFile = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("groundtruth/offsets.json")).unwrap(),
    )
    .unwrap();
    let names: Vec<&str> = offsets.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        names,
        ["cam0", "cam1", "cam2", "cam3", "heldout0", "heldout1"]
    );
    for name in ["heldout0", "heldout1"] {
        let video = dir.path().join("raw").join(name).join("GX010001.MP4");
        let decoded = video_frames(&video);
        assert_eq!(decoded.len(), frames, "{name}");
        for (k, (t, _)) in decoded.iter().enumerate() {
            assert!(
                (t - k as f64 / scene.fps()).abs() < 1e-6,
                "{name} frame {k} at {t}"
            );
        }
        // The filmed frame 0 shows what the clean ground-truth frame 0 shows (sensor noise,
        // H.264 and the tone of the rig's exposure aside).
        let truth = image::open(
            dir.path()
                .join("groundtruth/heldout")
                .join(name)
                .join("000000.png"),
        )
        .unwrap()
        .to_rgb8();
        let (_, rgb) = &decoded[0];
        assert_eq!(rgb.len(), truth.as_raw().len());
        let mse = rgb
            .iter()
            .zip(truth.as_raw())
            .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
            .sum::<f64>()
            / rgb.len() as f64;
        let psnr = 10.0 * (255.0f64 * 255.0 / mse).log10();
        assert!(psnr > 25.0, "{name}: filmed vs truth frame 0 {psnr:.1} dB");
    }
    // Without the option, held-out cameras stay ground truth only.
    let dir = tempfile::tempdir().unwrap();
    simulate(&scene.with_heldout_videos(false), dir.path(), &NoProgress).unwrap();
    assert!(!dir.path().join("raw/heldout0").exists());
}

#[test]
fn closest_point_on_a_triangle_in_every_region() {
    use glam::DVec3;
    let tri = [DVec3::ZERO, DVec3::X, DVec3::Y];
    let c = |p: DVec3| rig::sim::closest_on_triangle(p, tri);
    // Above the face, beyond a vertex, beside each edge.
    assert!((c(DVec3::new(0.2, 0.3, 5.0)) - DVec3::new(0.2, 0.3, 0.0)).length() < 1e-12);
    assert_eq!(c(DVec3::new(-1.0, -1.0, 0.0)), DVec3::ZERO);
    assert!((c(DVec3::new(0.5, -2.0, 1.0)) - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-12);
    assert!((c(DVec3::new(-2.0, 0.5, 0.0)) - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-12);
    assert!((c(DVec3::new(1.0, 1.0, 0.0)) - DVec3::new(0.5, 0.5, 0.0)).length() < 1e-12);
}
