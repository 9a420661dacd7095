//! `[poses] intrinsics = "lens.yaml"` end to end: the poses stage (after ingest, sync and
//! frames) on the simulated static capture of `fixtures/poses.toml`, its video cameras
//! given a radial-tangential lens, with their lenses written by OpenCV's `FileStorage` as
//! a lens calibration would be. The real COLMAP solves only the poses: the solved video
//! cameras carry exactly the file's lenses, and their poses are close to the simulator's.

use crate::common;

use std::fs;
use std::path::Path;

use opencv::core::{self as cv, Mat};
use opencv::prelude::*;
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::Selection;
use pipeline::simulate;
use shared_types::{Camera, CameraSet};

/// The simulator's video lens: barrel distortion a wide webcam might have.
const LENS: &str = "{ model = \"opencv\", k1 = -0.1, k2 = 0.02, p1 = 0.0005, p2 = -0.0003 }";

/// Writes the cameras' lenses as OpenCV's `FileStorage` YAML: per camera its image size,
/// `camera_matrix` (OpenCV's pixel centres: the principal point 0.5 px lower than the
/// engine's) and `distortion_coefficients`; no rotations or translations.
fn write_lens_file(path: &Path, cameras: &[Camera]) {
    let mut fs = cv::FileStorage::new_def(path.to_str().unwrap(), cv::FileStorage_WRITE).unwrap();
    fs.start_write_struct("cameras", cv::FileNode_MAP, "")
        .unwrap();
    for cam in cameras {
        let k = cam.intrinsics;
        let matrix = Mat::from_slice_2d(&[
            [k.fx, 0.0, k.cx - 0.5],
            [0.0, k.fy, k.cy - 0.5],
            [0.0, 0.0, 1.0],
        ])
        .unwrap();
        let values = cam.distortion.coefficients();
        let coefficients = Mat::from_slice(&values).unwrap();
        fs.start_write_struct(&cam.name, cv::FileNode_MAP, "")
            .unwrap();
        cv::write_i32(&mut fs, "image_width", k.width as i32).unwrap();
        cv::write_i32(&mut fs, "image_height", k.height as i32).unwrap();
        cv::write_mat(&mut fs, "camera_matrix", &matrix).unwrap();
        cv::write_mat(&mut fs, "distortion_coefficients", &coefficients).unwrap();
        fs.end_write_struct().unwrap();
    }
    fs.end_write_struct().unwrap();
    fs.release().unwrap();
}

#[test]
fn known_lenses_from_an_opencv_file_are_kept_and_only_the_poses_are_solved() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let mut table: toml::Table = fs::read_to_string(common::fixture("poses.toml"))
        .unwrap()
        .parse()
        .unwrap();
    // Poses use each camera's first frame: two frames are enough to sync and align.
    table["scene"]
        .as_table_mut()
        .unwrap()
        .insert("duration".into(), toml::Value::from(0.2));
    let lens: toml::Value =
        toml::from_str::<toml::Table>(&format!("d = {LENS}")).unwrap()["d"].clone();
    for cam in table["cameras"]["video"].as_array_mut().unwrap() {
        cam.as_table_mut()
            .unwrap()
            .insert("distortion".into(), lens.clone());
    }
    let scene =
        rig::sim::Scene::from_toml_str(&toml::to_string(&table).unwrap(), "poses.toml").unwrap();
    let clock = std::time::Instant::now();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    eprintln!("simulated in {:.1} s", clock.elapsed().as_secs_f64());
    let truth: CameraSet =
        serde_json::from_str(&fs::read_to_string(root.join("groundtruth/cameras.json")).unwrap())
            .unwrap();
    let video: Vec<Camera> = truth
        .cameras
        .iter()
        .filter(|c| c.name.starts_with("cam"))
        .cloned()
        .collect();
    assert_eq!(video.len(), 4);
    assert!(video.iter().all(|c| !c.distortion.is_none()));
    write_lens_file(&root.join("lens.yaml"), &video);
    assert!(
        fs::read_to_string(root.join("lens.yaml"))
            .unwrap()
            .starts_with("%YAML:1.0"),
        "written by OpenCV"
    );
    // A static scene: the cameras' own timestamps are the timeline.
    fs::write(
        root.join("capture.toml"),
        "[sync]\nmethod = \"timestamps\"\n[poses]\nintrinsics = \"lens.yaml\"\n",
    )
    .unwrap();

    let clock = std::time::Instant::now();
    let summary = common::run_stages(
        &root,
        Selection {
            to: Some("poses".into()),
            ..Default::default()
        },
    );
    assert_eq!(
        summary.ran,
        ["ingest", "sync", "frames", "poses"],
        "{summary:?}"
    );
    eprintln!("ingest to poses in {:.1} s", clock.elapsed().as_secs_f64());
    let solved = calib::poses::PosesFile::read(&root.join("work/poses/cameras.json")).unwrap();
    match &solved.source {
        calib::poses::PoseSource::Colmap {
            model_dir, timings, ..
        } => {
            eprintln!("COLMAP: {timings:?}");
            assert!(model_dir.contains("known_lenses"), "{model_dir}")
        }
        other => panic!("the poses were not solved by COLMAP: {other:?}"),
    }
    // The lenses are the file's, exactly (the frames keep the video's 640×480, so no
    // scaling): back in the engine's pixel convention, they are the simulator's.
    let file = calib::import::import_lenses(&root.join("lens.yaml")).unwrap();
    assert_eq!(solved.set.cameras.len(), 4);
    for cam in &solved.set.cameras {
        let given = file.cameras.iter().find(|c| c.name == cam.name).unwrap();
        let sim = video.iter().find(|c| c.name == cam.name).unwrap();
        assert_eq!(cam.distortion, given.distortion, "{}", cam.name);
        assert_eq!(cam.distortion, sim.distortion, "{}", cam.name);
        let k = |c: &Camera| {
            let i = c.intrinsics;
            [
                i.fx,
                i.fy,
                i.cx,
                i.cy,
                f64::from(i.width),
                f64::from(i.height),
            ]
        };
        for ((a, b), s) in k(cam).into_iter().zip(k(given)).zip(k(sim)) {
            assert!((a - b).abs() < 1e-9, "{}: {a} vs the file's {b}", cam.name);
            assert!(
                (a - s).abs() < 1e-9,
                "{}: {a} vs the simulator's {s}",
                cam.name
            );
        }
    }
    // Poses, after a similarity alignment. The bound is the known-lens solve's (docs/poses.md,
    // "Known lenses": the stills' lenses stay co-adapted, worst camera 0.1-1.0° over runs),
    // looser than a free solve's 0.5° / 1 %.
    let (_, errors, radius) = calib::similarity::compare(&solved.set.cameras, &video).unwrap();
    assert_eq!(errors.len(), 4);
    for e in &errors {
        eprintln!(
            "known lens from lens.yaml, {}: rotation {:.3}°, centre {:.3}% of the rig radius",
            e.name,
            e.rotation_deg,
            100.0 * e.centre / radius
        );
        assert!(e.rotation_deg < 1.5, "{e:?}");
        assert!(e.centre < 0.03 * radius, "{e:?}");
    }
}
