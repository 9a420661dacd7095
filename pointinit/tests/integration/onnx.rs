//! The ONNX path of point init on the fixture model `fixtures/onnx/pointmap_tiny.onnx`
//! (made by `fixtures/onnx/make_pointmap_fixture.py`), whose output is a known function of
//! its input: with `c = mean(rgb) / 255` of a pixel of either 32×24 image, its point is
//! `(1 + c) · ray`, the ray of a pinhole with f = 32 px centred on the image, in image 1's
//! camera frame (image 2's camera sits at x = 0.5 there, same rotation), and its confidence
//! `1 + 4c`.

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec2, DVec3};
use image::RgbImage;
use pointinit::npy::OutputNames;
use pointinit::onnx::{ModelConfig, OnnxError, PointMapModel};
use pointinit::{
    InitConfig, InitError, InitInputs, Moment, Source, UsedSource, ViewImage, run_init,
};
use shared_types::{Camera, CameraSet, Intrinsics, NoProgress, WorldToCamera};

const W: u32 = 32;
const H: u32 = 24;
const BASELINE: f64 = 0.5;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/onnx/pointmap_tiny.onnx")
}

fn config() -> ModelConfig {
    ModelConfig {
        input_size: [W, H],
        ..ModelConfig::default()
    }
}

fn test_image(seed: u32) -> RgbImage {
    RgbImage::from_fn(W, H, |x, y| {
        let h = (x * 73 + y * 151 + seed * 977).wrapping_mul(2_654_435_761);
        image::Rgb([(h >> 24) as u8, (h >> 16) as u8, (x * 8 + y) as u8])
    })
}

/// The fixture's depth for a pixel of colour `c`: `1 + mean(c)/255`.
fn fixture_z(c: &image::Rgb<u8>) -> f64 {
    1.0 + (c[0] as f64 + c[1] as f64 + c[2] as f64) / (3.0 * 255.0)
}

fn ray(x: u32, y: u32) -> DVec3 {
    DVec3::new(
        (x as f64 + 0.5 - 16.0) / 32.0,
        (y as f64 + 0.5 - 12.0) / 32.0,
        1.0,
    )
}

#[test]
fn fixture_output_is_the_known_function_of_its_input() {
    let model = PointMapModel::load(&fixture(), &config()).unwrap();
    let (a, b) = (test_image(1), test_image(2));
    let maps = model.run(&a, &b).unwrap();
    for (map, img, offset) in [
        (&maps.first, &a, DVec3::ZERO),
        (&maps.second, &b, DVec3::new(BASELINE, 0.0, 0.0)),
    ] {
        assert_eq!((map.width, map.height), (W as usize, H as usize));
        let conf = map.confidence.as_ref().unwrap();
        for (x, y, c) in img.enumerate_pixels() {
            let i = (y * W + x) as usize;
            let want = fixture_z(c) * ray(x, y) + offset;
            let got = DVec3::new(
                map.points[i][0] as f64,
                map.points[i][1] as f64,
                map.points[i][2] as f64,
            );
            assert!((got - want).length() < 1e-5, "{x},{y}: {got} vs {want}");
            let want_conf = 1.0 + 4.0 * (fixture_z(c) - 1.0);
            assert!((conf[i] as f64 - want_conf).abs() < 1e-5);
        }
    }
}

/// Two cameras posed like the fixture assumes (same rotation, the second `scale·0.5` to
/// the right of the first), intrinsics of the fixture (f = 32 px at 32×24).
fn fixture_rig(scale: f64) -> CameraSet {
    let k = Intrinsics {
        width: W,
        height: H,
        fx: 32.0,
        fy: 32.0,
        cx: 16.0,
        cy: 12.0,
    };
    let eye = DVec3::new(0.3, -3.0, 1.2);
    let w2c = WorldToCamera::look_at(eye, DVec3::new(0.0, 0.0, 0.8), DVec3::Z).unwrap();
    let r: DMat3 = w2c.rotation();
    let eye2 = eye + scale * BASELINE * (r.transpose() * DVec3::X);
    let cam = |name: &str, w2c| Camera {
        name: name.into(),
        intrinsics: k,
        distortion: Default::default(),
        world_to_camera: w2c,
    };
    CameraSet::new(vec![
        cam("cam0", w2c),
        cam("cam1", WorldToCamera::from_parts(r, -(r * eye2))),
    ])
}

fn write_images(dir: &Path) -> Vec<ViewImage> {
    (0..2)
        .map(|k| {
            let path = dir.join(format!("cam{k}.png"));
            test_image(k + 1).save(&path).unwrap();
            ViewImage {
                camera: format!("cam{k}"),
                path,
                time: 0.25 * k as f64,
            }
        })
        .collect()
}

fn init_config(model: PathBuf) -> InitConfig {
    InitConfig {
        source: Source::Onnx,
        model: Some(model),
        input_size: [W, H],
        min_confidence: 1.0,
        voxel_size: 0.0,
        ..InitConfig::default()
    }
}

#[test]
fn the_whole_path_recovers_the_scale_and_the_predicted_points() {
    let tmp = tempfile::tempdir().unwrap();
    let scale = 2.7;
    let cameras = fixture_rig(scale);
    let inputs = InitInputs {
        cameras: cameras.clone(),
        images: write_images(tmp.path()),
        sparse: None,
        moments: vec![],
        plate_frames: Vec::new(),
        stills: Vec::new(),
    };
    let out = tmp.path().join("init");
    let report = run_init(&inputs, &init_config(fixture()), &out, &NoProgress).unwrap();
    eprintln!("{report:#?}");
    assert_eq!(report.source, UsedSource::Onnx);
    assert_eq!(report.pairs.len(), 1);
    let pair = &report.pairs[0];
    assert!(pair.accepted, "{pair:?}");
    assert!((pair.scale.unwrap() / scale - 1.0).abs() < 1e-5, "{pair:?}");
    assert!(pair.residual.unwrap() < 1e-4);
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    let n = (W * H) as usize;
    assert_eq!(cloud.xyz.len(), 2 * n);
    let times = cloud.time.unwrap();
    for (v, cam) in cameras.cameras.iter().enumerate() {
        let img = test_image(v as u32 + 1);
        for (x, y, c) in img.enumerate_pixels() {
            let i = v * n + (y * W + x) as usize;
            let want = cam
                .world_to_camera
                .inverse_apply(scale * fixture_z(c) * ray(x, y));
            let got = DVec3::from_array(cloud.xyz[i].map(|v| v as f64));
            assert!((got - want).length() < 1e-4 * scale, "{v} {x},{y}");
            assert_eq!(cloud.rgb[i], c.0);
            assert_eq!(times[i], 0.25 * v as f32);
        }
    }
    // The projection of each point is its own pixel in its camera.
    let p = DVec3::from_array(cloud.xyz[5].map(|v| v as f64));
    let (px, _) = cameras.cameras[0].project(p).unwrap();
    assert!((px - DVec2::new(5.5, 0.5)).length() < 1e-3);
}

#[test]
fn the_model_runs_at_each_moment_and_a_still_scene_is_static() {
    let tmp = tempfile::tempdir().unwrap();
    let cameras = fixture_rig(1.0);
    let images = write_images(tmp.path());
    // The same frames at two moments: every point is seen at both, so all are static,
    // living over the span between the moments.
    let moment = |frame: usize, time: f64| Moment {
        frame,
        time,
        views: images
            .iter()
            .map(|v| ViewImage { time, ..v.clone() })
            .collect(),
    };
    let inputs = InitInputs {
        cameras,
        images: images.clone(),
        sparse: None,
        moments: vec![moment(0, 0.0), moment(9, 1.0)],
        plate_frames: Vec::new(),
        stills: Vec::new(),
    };
    let out = tmp.path().join("init");
    let config = InitConfig {
        moments: 2,
        ..init_config(fixture())
    };
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Onnx);
    let frames: Vec<_> = report.pairs.iter().map(|p| p.frame).collect();
    assert_eq!(frames, [Some(0), Some(9)]);
    assert!(report.pairs.iter().all(|p| p.accepted));
    let s = report.statics;
    assert_eq!(s.static_tagged, 2 * 2 * (W * H) as usize, "{s:?}");
    assert_eq!(s.dynamic_points, 0, "{s:?}");
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    assert_eq!(cloud.xyz.len(), s.static_points);
    assert!(cloud.time.unwrap().iter().all(|t| *t == 0.5));
    assert!(cloud.time_span.unwrap().iter().all(|t| *t == 1.0));
}

#[test]
fn wrong_names_and_shapes_are_typed_errors() {
    // Input size the model was not made for: its constant grid cannot broadcast. tract
    // may notice when loading or only when running; either way a typed error.
    let c = ModelConfig {
        input_size: [64, 48],
        ..config()
    };
    match PointMapModel::load(&fixture(), &c) {
        Err(e) => assert!(matches!(e, OnnxError::Load { .. }), "{e}"),
        Ok(m) => {
            let e = m.run(&test_image(1), &test_image(2)).unwrap_err();
            eprintln!("{e}");
            assert!(
                matches!(e, OnnxError::Run { .. } | OnnxError::OutputShape { .. }),
                "{e}"
            );
        }
    }
    // Unknown output name.
    let mut c = config();
    c.output_names.pts1 = "points".into();
    let e = PointMapModel::load(&fixture(), &c).unwrap_err();
    assert!(matches!(e, OnnxError::Load { .. }), "{e}");
    assert!(e.to_string().contains("output_names"));
    // Unknown input name.
    let mut c = config();
    c.input_names[1] = "image_2".into();
    let e = PointMapModel::load(&fixture(), &c).unwrap_err();
    assert!(matches!(e, OnnxError::Load { .. }), "{e}");
    // Outputs swapped: a confidence where a point map is expected.
    let c = ModelConfig {
        output_names: OutputNames {
            pts1: "conf1".into(),
            conf1: "pts1".into(),
            ..OutputNames::default()
        },
        ..config()
    };
    let model = PointMapModel::load(&fixture(), &c).unwrap();
    let e = model.run(&test_image(1), &test_image(2)).unwrap_err();
    assert!(
        matches!(&e, OnnxError::OutputShape { name, .. } if name == "conf1"),
        "{e}"
    );
}

#[test]
fn corrupt_and_missing_models_are_typed_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(fixture()).unwrap();
    let cases: [(&str, Vec<u8>); 3] = [
        ("truncated.onnx", bytes[..bytes.len() / 2].to_vec()),
        ("text.onnx", b"this is not a model\n".to_vec()),
        (
            "flipped.onnx",
            bytes
                .iter()
                .enumerate()
                .map(|(i, b)| if i % 7 == 3 { b ^ 0x5a } else { *b })
                .collect(),
        ),
    ];
    for (name, data) in cases {
        let p = tmp.path().join(name);
        std::fs::write(&p, data).unwrap();
        let e = PointMapModel::load(&p, &config()).unwrap_err();
        assert!(matches!(e, OnnxError::Load { .. }), "{name}: {e}");
        assert!(e.to_string().contains(name));
    }
    let e = PointMapModel::load(&tmp.path().join("missing.onnx"), &config()).unwrap_err();
    assert!(matches!(e, OnnxError::Io { .. }), "{e}");
    // Through the stage: a clear error, no points file.
    let p = tmp.path().join("text.onnx");
    let inputs = InitInputs {
        cameras: fixture_rig(1.0),
        images: write_images(tmp.path()),
        sparse: None,
        moments: vec![],
        plate_frames: Vec::new(),
        stills: Vec::new(),
    };
    let out = tmp.path().join("init");
    let e = run_init(&inputs, &init_config(p), &out, &NoProgress).unwrap_err();
    assert!(matches!(e, InitError::Onnx(_)), "{e}");
    assert!(!out.join("points.ply").exists());
}
