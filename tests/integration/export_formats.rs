//! Export formats: a 3DGS frame renders like the 4D model at its time, the 4D PLY
//! re-imports bit-exactly, `.splatv` decodes to what was written and moves like the
//! model, and `export_all` writes the documented tree.

#![allow(clippy::needless_range_loop)]

use crate::common;

use common::{SceneSpec, camera, random_scene};
use glam::{DMat3, DQuat, DVec3};
use splat4d::export::splatv::{self, SplatvCamera};
use splat4d::export::{
    ExportError, ExportOptions, Splat3d, bake_frame, export_all, read_frame_ply, read_model_ply,
    write_frame_ply, write_model_ply,
};
use splat4d::math::rotation4d::rotation;
use splat4d::math::slice::slice;
use splat4d::render::RenderOptions;
use splat4d::render::cpu::render_with;
use splat4d::{CameraSet, ColourDegrees, Gaussians, NoProgress, TimeMapping};

fn model(seed: u64, count: usize) -> Gaussians<f32> {
    let mut m = random_scene(
        seed,
        SceneSpec {
            count,
            ..Default::default()
        },
    )
    .cast::<f32>();
    m.time = TimeMapping {
        start_seconds: 0.1 + 0.2,
        units_per_second: 30.0 / 29.97,
        duration: 1.0,
    };
    m
}

/// The exported 3D Gaussians as a 4D model that is static in time (temporal scale at the
/// engine's maximum, time centre `t`), so the engine's renderer can draw them.
fn static_model(splats: &[Splat3d], t: f64, sh_degree: u32) -> Gaussians<f64> {
    let cap = ColourDegrees {
        spatial: 3,
        temporal: 0,
    };
    let mut g = Gaussians::<f64>::new(cap, TimeMapping::default());
    g.active = ColourDegrees {
        spatial: sh_degree,
        temporal: 0,
    };
    for s in splats {
        let [w, x, y, z] = s.rotation.map(|v| v as f64);
        let r3 = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize());
        // The engine's convention: ql = qr = q is the 3D rotation q, time untouched.
        let (ql, qr) = ([w, x, y, z], [w, x, y, z]);
        let (r4, _) = rotation(ql, qr);
        for a in 0..3 {
            for b in 0..3 {
                assert!((r4[a][b] - r3.col(b)[a]).abs() < 1e-9, "rotation embedding");
            }
            assert!(r4[a][3].abs() < 1e-9 && r4[3][a].abs() < 1e-9);
        }
        let p = s.position.map(|v| v as f64);
        let ls = s.log_scale.map(|v| v as f64);
        let i = g.push(
            [p[0], p[1], p[2], t],
            [ls[0], ls[1], ls[2], 12.0],
            s.opacity_logit as f64,
            [0.5; 3],
        );
        g.rot_left[i] = ql;
        g.rot_right[i] = qr;
        for k in 0..16 {
            for c in 0..3 {
                g.colours[(i * 16 + k) * 3 + c] = s.sh[k][c] as f64;
            }
        }
    }
    g
}

fn psnr(a: &[f64], b: &[f64]) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64;
    10.0 * (1.0 / mse.max(1e-20)).log10()
}

#[test]
fn frame_ply_renders_like_the_4d_model() {
    let m = model(11, 60);
    let cam = camera(96, 72);
    let dir = tempfile::tempdir().unwrap();
    for t in [0.35, 0.5, 0.62] {
        let frame = bake_frame(&m, t, 1.0 / 255.0);
        assert!(frame.dropped < m.len() && !frame.splats.is_empty());
        let p = dir.path().join("frame.ply");
        write_frame_ply(&frame, &p).unwrap();
        let back = read_frame_ply(&p).unwrap();
        assert_eq!(back, frame.splats, "PLY frame round trip");
        let opts = RenderOptions::<f64>::default();
        let want = render_with(&m.cast::<f64>(), &cam, t, &opts).unwrap();
        let got = render_with(&static_model(&back, t, 3), &cam, t, &opts).unwrap();
        let db = psnr(&want.rgb, &got.rgb);
        eprintln!("t = {t}: exported frame vs 4D render {db:.1} dB");
        // Only differences: the SH view direction (to the sliced instead of the canonical
        // mean) and float32 storage.
        assert!(db > 40.0, "t = {t}: PSNR {db:.1} dB");
        let covered = want.alpha.iter().filter(|a| **a > 0.1).count();
        assert!(covered > 200, "scene should cover the image, {covered} px");
    }
}

#[test]
fn frames_drop_gaussians_outside_their_time() {
    let m = model(5, 40);
    let early = bake_frame(&m, -3.0, 1.0 / 255.0);
    assert_eq!(early.splats.len(), 0);
    assert_eq!(early.dropped, 40);
    let mid = bake_frame(&m, 0.5, 1.0 / 255.0);
    assert!(mid.splats.len() > 20);
}

#[test]
fn model4d_ply_reimports_bit_exactly() {
    let dir = tempfile::tempdir().unwrap();
    for degrees in [ColourDegrees::FULL, ColourDegrees::DC] {
        let mut m = random_scene(
            3,
            SceneSpec {
                count: 25,
                degrees,
                ..Default::default()
            },
        )
        .cast::<f32>();
        m.time = TimeMapping {
            start_seconds: 1.0 / 3.0,
            units_per_second: 0.1 + 0.2,
            duration: 9.966_666_666_666_667,
        };
        m.active = ColourDegrees {
            spatial: degrees.spatial.min(2),
            temporal: degrees.temporal.min(1),
        };
        m.opacity_logits[0] = f32::MIN_POSITIVE / 4.0; // subnormal
        m.log_scales[1][3] = -0.0;
        let p = dir.path().join("model4d.ply");
        write_model_ply(&m, &p).unwrap();
        let back = read_model_ply(&p).unwrap();
        let bits4 = |v: &Vec<[f32; 4]>| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        let bits = |v: &Vec<f32>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits4(&back.means), bits4(&m.means));
        assert_eq!(bits4(&back.log_scales), bits4(&m.log_scales));
        assert_eq!(bits4(&back.rot_left), bits4(&m.rot_left));
        assert_eq!(bits4(&back.rot_right), bits4(&m.rot_right));
        assert_eq!(bits(&back.opacity_logits), bits(&m.opacity_logits));
        assert_eq!(bits(&back.colours), bits(&m.colours));
        assert_eq!(back.capacity, m.capacity);
        assert_eq!(back.active, m.active);
        assert_eq!(back.time, m.time);
    }
    // Not a 4D model: a typed error naming the file.
    let frame = bake_frame(&model(2, 5), 0.5, 0.0);
    let p = dir.path().join("frame.ply");
    write_frame_ply(&frame, &p).unwrap();
    let err = read_model_ply(&p).unwrap_err();
    assert!(matches!(err, ExportError::Format { .. }));
    assert!(err.to_string().contains("frame.ply"), "{err}");
}

#[test]
fn splatv_decodes_to_what_was_written_and_moves_like_the_model() {
    let mut m = model(21, 50);
    // A sequence longer than one model unit: the `.splatv` stores times as fractions of
    // it (players run τ over [0, 1]), so every time and velocity below is rescaled.
    m.time.duration = 1.6;
    let cams = CameraSet::new(vec![camera(64, 48)]);
    let scams: Vec<SplatvCamera> = cams
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| SplatvCamera::from_camera(i, c))
        .collect();
    let splats = splatv::splats_from_model(&m, None);
    assert_eq!(splats.len(), m.len());
    let bytes = splatv::encode(&splats, &scams);
    let (back, back_cams) = splatv::decode(&bytes).unwrap();
    assert_eq!(back_cams.len(), 1);
    let (a, b) = (&back_cams[0], &scams[0]);
    assert_eq!(
        (&a.img_name, a.width, a.height),
        (&b.img_name, b.width, b.height)
    );
    let flat =
        |c: &SplatvCamera| [c.position.to_vec(), c.rotation.concat(), vec![c.fx, c.fy]].concat();
    for (x, y) in flat(a).iter().zip(flat(b)) {
        assert!((x - y).abs() < 1e-12, "camera {x} vs {y}");
    }
    assert_eq!(back.len(), splats.len());
    let half = |a: f32, b: f32| (a - b).abs() <= 1e-3 * a.abs().max(b.abs()) + 1e-6;
    for (a, b) in splats.iter().zip(&back) {
        assert_eq!(a.position, b.position);
        assert_eq!(a.rgba, b.rgba);
        for k in 0..4 {
            assert!(half(a.rotation[k], b.rotation[k]));
        }
        for k in 0..3 {
            assert!(half(a.scale[k], b.scale[k]) && half(a.velocity[k], b.velocity[k]));
        }
        assert!(half(a.t_centre, b.t_centre) && half(a.t_scale, b.t_scale));
    }
    // The decoded motion follows the model's slices.
    let mut checked = 0;
    for (i, s) in back.iter().enumerate() {
        let f = |a: [f32; 4]| a.map(|x| x as f64);
        for t in [0.3, 0.5, 0.7] {
            let Some((sl, _)) = slice::<f64>(
                f(m.means[i]),
                f(m.log_scales[i]),
                f(m.rot_left[i]),
                f(m.rot_right[i]),
                t,
            ) else {
                continue;
            };
            let dt = t / m.time.duration - s.t_centre as f64;
            for k in 0..3 {
                let p = s.position[k] as f64 + s.velocity[k] as f64 * dt;
                assert!(
                    (p - sl.mean[k]).abs() < 2e-3,
                    "position {p} vs {}",
                    sl.mean[k]
                );
            }
            let w = (-(dt / s.t_scale as f64).powi(2)).exp();
            assert!((w - sl.omega).abs() < 5e-3, "weight {w} vs {}", sl.omega);
            checked += 1;
        }
    }
    assert!(checked > 50);
    // The whole sequence lies in the player's [0, 1].
    assert!(back.iter().all(|s| (0.0..=1.0).contains(&s.t_centre)));
    assert!(splatv::decode(&bytes[..100]).is_err());
    assert!(splatv::decode(b"not a splatv file").is_err());
}

#[test]
fn export_all_writes_the_documented_tree() {
    let m = model(8, 30);
    let cams = CameraSet::new(vec![camera(64, 48)]);
    let dir = tempfile::tempdir().unwrap();
    let opts = ExportOptions {
        viewer: false,
        ..Default::default()
    };
    let times = splat4d::export::even_times(&m, 4);
    assert_eq!(times, vec![0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
    let report = export_all(&m, &cams, &times, dir.path(), &opts, &NoProgress).unwrap();
    assert_eq!(report.frames.len(), 4);
    for (k, f) in report.frames.iter().enumerate() {
        assert_eq!(f.path, dir.path().join(format!("frames/{k:04}.ply")));
        assert_eq!(read_frame_ply(&f.path).unwrap().len(), f.kept);
        assert_eq!(f.kept + f.dropped, 30);
    }
    assert!(read_model_ply(&dir.path().join("model4d.ply")).is_ok());
    let bytes = std::fs::read(dir.path().join("scene.splatv")).unwrap();
    assert_eq!(
        splatv::decode(&bytes).unwrap().0.len(),
        report.splatv_splats
    );
    let leftovers: Vec<_> = walk(dir.path())
        .into_iter()
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().contains(".tmp"))
        })
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    // A missing viewer bundle is a clear error naming the fix.
    let opts = ExportOptions {
        viewer_bundle: Some(dir.path().join("no-such-bundle")),
        ..Default::default()
    };
    let err = export_all(&m, &cams, &times, dir.path(), &opts, &NoProgress).unwrap_err();
    assert!(matches!(err, ExportError::ViewerBundleMissing { .. }));
    assert!(err.to_string().contains("scripts/setup.sh"), "{err}");
}

#[test]
fn viewer_export_copies_the_bundle_and_writes_equal_size_frames() {
    let m = model(9, 40);
    let cams = CameraSet::new(vec![camera(64, 48)]);
    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("bundle");
    std::fs::create_dir_all(bundle.join("assets")).unwrap();
    std::fs::write(bundle.join("index.html"), "<html></html>").unwrap();
    std::fs::write(bundle.join("assets/a.js"), "x").unwrap();
    let out = dir.path().join("export");
    let opts = ExportOptions {
        frames: false,
        model4d: false,
        splatv: false,
        viewer_bundle: Some(bundle),
        viewer_max_frames: 3,
        background: [0.25, 0.5, 0.75],
        ..Default::default()
    };
    let times = splat4d::export::even_times(&m, 7);
    let report = export_all(&m, &cams, &times, &out, &opts, &NoProgress).unwrap();
    let v = out.join("viewer");
    assert_eq!(report.viewer_index, Some(v.join("index.html")));
    assert!(v.join("assets/a.js").is_file());
    let scene: serde_json::Value =
        serde_json::from_slice(&std::fs::read(v.join("scene.json")).unwrap()).unwrap();
    let frames = scene["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 3);
    let ts: Vec<f64> = frames.iter().map(|f| f["t"].as_f64().unwrap()).collect();
    assert_eq!(ts, vec![times[0], times[3], times[6]]);
    let rows = scene["rows"].as_u64().unwrap() as usize;
    assert!(rows > 0 && rows <= m.len());
    // The page draws the training background behind the splats.
    let background: Vec<f64> = scene["background"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(background, opts.background.map(f64::from).to_vec());
    for f in frames {
        // One size and one row order for all frames; rows a frame does not draw are
        // transparent.
        let bytes = std::fs::read(v.join(f["file"].as_str().unwrap())).unwrap();
        assert_eq!(bytes.len(), 32 * rows);
        let drawn = bytes.chunks_exact(32).filter(|r| r[27] > 0).count();
        let splats = f["splats"].as_u64().unwrap() as usize;
        assert!(drawn <= splats && splats <= rows, "{drawn} {splats} {rows}");
        // The colours seen from each training camera, RGB per row.
        let colours = f["colours"].as_array().unwrap();
        assert_eq!(colours.len(), 1);
        let rgb = std::fs::read(v.join(colours[0].as_str().unwrap())).unwrap();
        assert_eq!(rgb.len(), 3 * rows);
    }
    // The training camera in viewer space sees the viewer-space points where the engine's
    // camera sees the world points.
    let space = &scene["space"];
    let vec3 =
        |v: &serde_json::Value| DVec3::from_array(serde_json::from_value(v.clone()).unwrap());
    let quat = |v: &serde_json::Value| {
        let q: [f64; 4] = serde_json::from_value(v.clone()).unwrap();
        DQuat::from_xyzw(q[0], q[1], q[2], q[3])
    };
    let (centre, to_viewer) = (vec3(&space["centre"]), quat(&space["rotation"]));
    let cam = &scene["cameras"][0];
    let (position, cam_to_viewer) = (vec3(&cam["position"]), quat(&cam["rotation"]));
    assert_eq!(cam["name"], "test");
    assert_eq!(cam["fx"].as_f64().unwrap(), cams.cameras[0].intrinsics.fx);
    assert!(
        (position.length() - 4.0).abs() < 0.5,
        "camera to the scene centre {position}"
    );
    for mean in &m.means {
        let world = DVec3::new(mean[0] as f64, mean[1] as f64, mean[2] as f64);
        let seen = cams.cameras[0].world_to_camera.apply(world);
        let viewer = to_viewer * (world - centre);
        let seen_in_viewer = cam_to_viewer.inverse() * (viewer - position);
        assert!(
            (seen - seen_in_viewer).length() < 1e-9,
            "{seen} vs {seen_in_viewer}"
        );
    }
    // The cameras' up direction is −y in viewer space (gsplat's orbit controls).
    let up = cam_to_viewer * DVec3::NEG_Y;
    assert!(up.y < -0.9, "camera up in viewer space {up}");
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}
