//! Pose2Sim's `Calib_scene.toml`: the committed fixture (`fixtures/calibration/`, four
//! portrait cameras calibrated at 1088×1920 around a 3.5 m circle, in the format Pose2Sim
//! writes) imports, its cameras project world points exactly where OpenCV's
//! `projectPoints` puts them from the file's own numbers (Rodrigues rotation,
//! translation, K, distortions), and through the poses stage's import (codec padding
//! cropped to the 1080×1920 videos, then the 540×960 working size) the projections only
//! scale by one half.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use calib::import::{find_calibration, import_calibration};
use calib::poses::{CaptureCamera, write_imported};
use glam::{DVec2, DVec3};
use opencv::calib3d;
use opencv::core::{Mat, Point2d, Point3d, Vector};
use opencv::prelude::*;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/calibration/pose2sim_Calib_scene.toml")
}

/// World points around the scene centre (a person-sized volume, metres).
fn world_points() -> Vec<DVec3> {
    let mut pts = Vec::new();
    for i in 0..5 {
        for j in 0..5 {
            for k in 0..4 {
                pts.push(DVec3::new(
                    -0.6 + 0.3 * i as f64,
                    -0.6 + 0.3 * j as f64,
                    0.1 + 0.5 * k as f64,
                ));
            }
        }
    }
    pts
}

/// `cv::projectPoints` with a camera table of the file, read here independently of the
/// importer.
fn opencv_projection(table: &toml::Value, pts: &[DVec3]) -> Vec<DVec2> {
    let nums = |key: &str| -> Vec<f64> {
        fn flat(v: &toml::Value, out: &mut Vec<f64>) {
            match v {
                toml::Value::Array(a) => a.iter().for_each(|x| flat(x, out)),
                toml::Value::Float(f) => out.push(*f),
                toml::Value::Integer(i) => out.push(*i as f64),
                _ => panic!("not a number: {v}"),
            }
        }
        let mut out = Vec::new();
        flat(&table[key], &mut out);
        out
    };
    let k = Mat::from_slice(&nums("matrix"))
        .unwrap()
        .reshape(1, 3)
        .unwrap()
        .try_clone()
        .unwrap();
    let d = Mat::from_slice(&nums("distortions"))
        .unwrap()
        .try_clone()
        .unwrap();
    let r = Mat::from_slice(&nums("rotation"))
        .unwrap()
        .try_clone()
        .unwrap();
    let t = Mat::from_slice(&nums("translation"))
        .unwrap()
        .try_clone()
        .unwrap();
    let object: Vector<Point3d> = pts.iter().map(|p| Point3d::new(p.x, p.y, p.z)).collect();
    let mut image: Vector<Point2d> = Vector::new();
    calib3d::project_points_def(&object, &r, &t, &k, &d, &mut image).unwrap();
    image.iter().map(|p| DVec2::new(p.x, p.y)).collect()
}

#[test]
fn pose2sim_calibration_imports_and_projects_like_opencv() {
    let path = fixture();
    let set = import_calibration(&path).unwrap();
    let names: Vec<&str> = set.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["cam_01", "cam_02", "cam_03", "cam_04"]);
    let file: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let pts = world_points();
    let mut worst = 0.0f64;
    for cam in &set.cameras {
        assert_eq!((cam.intrinsics.width, cam.intrinsics.height), (1088, 1920));
        // Cameras on the 3.5 m circle, 1.5 m high, looking at the scene centre.
        let c = cam.world_to_camera.centre();
        assert!(
            (c.truncate().length() - 3.5).abs() < 1e-4 && (c.z - 1.5).abs() < 1e-4,
            "{c}"
        );
        let (centre, _) = cam.project(DVec3::new(0.0, 0.0, 0.9)).unwrap();
        assert!((centre - DVec2::new(cam.intrinsics.cx, cam.intrinsics.cy)).length() < 1.0);
        let cv = opencv_projection(&file[&cam.name], &pts);
        for (p, q) in pts.iter().zip(&cv) {
            let (ours, _) = cam.project(*p).unwrap();
            // Ours puts pixel centres at integer + 0.5, OpenCV at the integer.
            worst = worst.max((ours - DVec2::splat(0.5) - *q).length());
        }
    }
    eprintln!("Pose2Sim fixture: worst |ours − cv::projectPoints| = {worst:.2e} px");
    assert!(worst < 1e-9, "{worst} px");
}

#[test]
fn pose2sim_calibration_through_the_poses_import_with_codec_padding() {
    let tmp = tempfile::tempdir().unwrap();
    let capture = tmp.path();
    std::fs::copy(fixture(), capture.join("Calib_scene.toml")).unwrap();
    let path = find_calibration(capture).expect("Calib_scene.toml is a calibration name");
    let set = import_calibration(&path).unwrap();
    // Videos are 1080×1920 (the calibration tool saw H.264's 1088 coded columns); frames
    // are extracted at 540×960. Folders are cam0..cam3, the calibration says cam_01..cam_04.
    let folders: Vec<CaptureCamera> = (0..4)
        .map(|i| CaptureCamera {
            name: format!("cam{i}"),
            recorded: Some((1080, 1920)),
            working: (540, 960),
        })
        .collect();
    let out_dir = capture.join("work/poses");
    let e = write_imported(&set, &path, &out_dir, &folders, &BTreeMap::new(), 1.0)
        .unwrap_err()
        .to_string();
    for part in [
        "Calib_scene.toml",
        "cam_01, cam_02",
        "cam0, cam1",
        "[poses]",
    ] {
        assert!(e.contains(part), "{part}: {e}");
    }
    assert!(!out_dir.join("cameras.json").exists());
    let names: BTreeMap<String, String> = (0..4)
        .map(|i| (format!("cam{i}"), format!("cam_0{}", i + 1)))
        .collect();
    let out = write_imported(&set, &path, &out_dir, &folders, &names, 1.0).unwrap();
    let norm = out.file.normalisation;
    for (i, cam) in out.file.set.cameras.iter().enumerate() {
        assert_eq!(cam.name, format!("cam{i}"));
        assert_eq!((cam.intrinsics.width, cam.intrinsics.height), (540, 960));
        let original = &set.cameras[i];
        // The crop keeps pixel coordinates; the resize halves them.
        for p in world_points() {
            let (a, _) = original.project(p).unwrap();
            let (b, _) = cam.project(norm.apply(p)).unwrap();
            assert!((a * 0.5 - b).length() < 1e-9, "{}: {a} vs {b}", cam.name);
        }
    }
}
