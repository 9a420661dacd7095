//! Fuzzed readers of user files: COLMAP models (binary and text), calibration files
//! (OpenCV JSON and YAML, Pose2Sim TOML) and `cameras.json`. Damaged copies of valid files
//! (`shared_types::fuzz`) must give an error or a value, never a panic, an abort or an
//! allocation a length field asked for. `PROPTEST_CASES` sets the number of cases.

use std::path::{Path, PathBuf};

use calib::colmap::ColmapModel;
use calib::import::{import_calibration, import_lenses};
use calib::poses::PosesFile;
use proptest::prelude::*;
use shared_types::fuzz::{self, damaged, within_budget};

fn fixture(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(relative)
}

fn read(relative: &str) -> Vec<u8> {
    std::fs::read(fixture(relative)).unwrap()
}

/// A COLMAP model folder (binary or text) with `file` replaced by `bytes`, read back.
fn colmap_with(format: &str, file: &str, bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    for name in ["cameras", "images", "points3D"] {
        let name = format!("{name}.{format}");
        std::fs::copy(
            fixture(&format!("colmap/tiny/{format}/{name}")),
            dir.path().join(&name),
        )
        .unwrap();
    }
    std::fs::write(dir.path().join(file), bytes).unwrap();
    within_budget(|| ColmapModel::read(dir.path()))
}

/// OpenCV-style JSON and FileStorage YAML as calibration tools write them.
const OPENCV_JSON: &str = r#"{"units": "mm", "cameras": {"cam0": {"K": [[500, 0, 320], [0, 501, 240], [0, 0, 1]], "dist": [-0.1, 0.01, 0, 0, 0], "R": [[0, -1, 0], [1, 0, 0], [0, 0, 1]], "t": [2000, -1000, 500], "size": [640, 480]}, "cam1": {"camera_matrix": [[480, 0, 330], [0, 480, 250], [0, 0, 1]], "distCoeffs": [0.02, 0, 0, 0], "rvec": [0, 0.4, 0], "tvec": [[-300], [0], [2100]], "image_width": 640, "image_height": 480}}}"#;
const OPENCV_YAML: &str = "%YAML:1.0\n---\ncameras:\n  gopro0:\n    model: fisheye\n    image_width: 1920\n    image_height: 1080\n    camera_matrix: !!opencv-matrix\n      rows: 3\n      cols: 3\n      dt: d\n      data: [ 900., 0., 960., 0., 900., 540., 0., 0., 1. ]\n    distortion_coefficients: !!opencv-matrix\n      rows: 4\n      cols: 1\n      dt: d\n      data: [ 0.05, -0.01, 0.002, 0. ]\n    rvec: [ 0., 0., 0. ]\n    tvec: [ 0., 0., 2. ]\n  gopro1:\n    model: fisheye\n    image_width: 1920\n    image_height: 1080\n    camera_matrix: { rows: 3, cols: 3, dt: d, data: [ 900., 0., 960., 0., 900., 540., 0., 0., 1. ] }\n    distortion_coefficients: [ 0.05, -0.01, 0.002, 0. ]\n    rvec: [ 0., 0.5, 0. ]\n    tvec: [ -1., 0., 2. ]\n";

/// `bytes` as the calibration file `name`, imported as a calibration and as lenses.
fn calibration_with(name: &str, bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    within_budget(|| import_calibration(&path))?;
    within_budget(|| import_lenses(&path))
}

proptest! {
    #![proptest_config(fuzz::config(1))]

    #[test]
    fn colmap_binary_cameras(bytes in damaged(read("colmap/tiny/bin/cameras.bin"))) {
        colmap_with("bin", "cameras.bin", &bytes)?;
    }

    #[test]
    fn colmap_binary_images(bytes in damaged(read("colmap/tiny/bin/images.bin"))) {
        colmap_with("bin", "images.bin", &bytes)?;
    }

    #[test]
    fn colmap_binary_points(bytes in damaged(read("colmap/tiny/bin/points3D.bin"))) {
        colmap_with("bin", "points3D.bin", &bytes)?;
    }

    #[test]
    fn colmap_text_cameras(bytes in damaged(read("colmap/tiny/txt/cameras.txt"))) {
        colmap_with("txt", "cameras.txt", &bytes)?;
    }

    #[test]
    fn colmap_text_images(bytes in damaged(read("colmap/tiny/txt/images.txt"))) {
        colmap_with("txt", "images.txt", &bytes)?;
    }

    #[test]
    fn colmap_text_points(bytes in damaged(read("colmap/tiny/txt/points3D.txt"))) {
        colmap_with("txt", "points3D.txt", &bytes)?;
    }

    #[test]
    fn opencv_json(bytes in damaged(OPENCV_JSON.as_bytes().to_vec())) {
        calibration_with("calibration.json", &bytes)?;
    }

    #[test]
    fn opencv_yaml(bytes in damaged(OPENCV_YAML.as_bytes().to_vec())) {
        calibration_with("calibration.yaml", &bytes)?;
    }

    #[test]
    fn pose2sim_toml(bytes in damaged(read("calibration/pose2sim_Calib_scene.toml"))) {
        calibration_with("Calib_scene.toml", &bytes)?;
    }

    #[test]
    fn poses_cameras_json(bytes in damaged(cameras_json())) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cameras.json");
        std::fs::write(&path, &bytes).unwrap();
        within_budget(|| PosesFile::read(&path))?;
    }
}

/// A `cameras.json` as the poses stage writes it: the OpenCV JSON's cameras.
fn cameras_json() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("calibration.json");
    std::fs::write(&path, OPENCV_JSON).unwrap();
    serde_json::to_vec_pretty(&import_calibration(&path).unwrap()).unwrap()
}
