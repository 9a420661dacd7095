//! COLMAP model IO: round trips in both formats, every camera model, non-contiguous IDs,
//! corrupt files, a committed model written by the real COLMAP 3.8, and (when the `colmap`
//! binary is installed) COLMAP reading the files we write.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use calib::colmap::{
    CameraModel, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint3D, INVALID_POINT3D_ID,
    ModelError, ModelFormat, Point2D, TrackElement, binary,
};

/// A consistent model: every camera model (COLMAP 3.8's when `colmap38_only`), sparse IDs,
/// tracks that point at 2D points that point back.
fn sample_model(colmap38_only: bool) -> ColmapModel {
    let mut m = ColmapModel::default();
    let models: Vec<CameraModel> = CameraModel::ALL
        .into_iter()
        .filter(|c| !colmap38_only || *c != CameraModel::RadTanThinPrismFisheye)
        .collect();
    for (i, model) in models.iter().enumerate() {
        let id = 3 + 1000 * i as u32;
        let params = (0..model.num_params())
            .map(|k| {
                if k < 4 {
                    300.0 + k as f64 * 0.1
                } else {
                    1e-3 * (k as f64 - 5.5)
                }
            })
            .collect();
        m.cameras.insert(
            id,
            ColmapCamera::new(id, *model, 640 + i as u64, 480, params).unwrap(),
        );
    }
    let cam_ids: Vec<u32> = m.cameras.keys().copied().collect();
    let image_ids = [7u32, 8, 4_000_000_000];
    for (k, &id) in image_ids.iter().enumerate() {
        let q = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.1 * k as f64, -0.2, 0.3 + k as f64)
            .normalize();
        let points2d = (0..6)
            .map(|j| Point2D {
                xy: [10.5 + j as f64 / 3.0, 20.25 - k as f64 * 1e-9],
                point3d_id: INVALID_POINT3D_ID,
            })
            .collect();
        m.images.insert(
            id,
            ColmapImage {
                id,
                qvec: [q.w, q.x, q.y, q.z],
                tvec: [0.1 * k as f64, -1.0 / 3.0, 2.0 + k as f64],
                camera_id: cam_ids[k % cam_ids.len()],
                name: format!("video/cam{k}/frame {k}.png").replace(' ', "_"),
                points2d,
            },
        );
    }
    for (j, pid) in [1u64, 99, 1 << 40].into_iter().enumerate() {
        let track: Vec<TrackElement> = image_ids
            .iter()
            .map(|&image_id| TrackElement {
                image_id,
                point2d_idx: (2 * j) as u32,
            })
            .collect();
        for t in &track {
            m.images.get_mut(&t.image_id).unwrap().points2d[t.point2d_idx as usize].point3d_id =
                pid;
        }
        m.points3d.insert(
            pid,
            ColmapPoint3D {
                id: pid,
                xyz: [j as f64 * 0.1, -2.0 / 7.0, 1e-17],
                rgb: [j as u8 * 100, 7, 255],
                error: 0.123456789 * (j as f64 + 1.0),
                track,
            },
        );
    }
    m
}

#[test]
fn round_trips_in_both_formats_bit_exactly() {
    let m = sample_model(false);
    let tmp = tempfile::tempdir().unwrap();
    for format in [ModelFormat::Binary, ModelFormat::Text] {
        let dir = tmp.path().join(format.extension());
        m.write(&dir, format).unwrap();
        assert_eq!(ColmapModel::detect_format(&dir), Some(format));
        assert_eq!(ColmapModel::read(&dir).unwrap(), m, "{format:?}");
    }
    // bin → model → txt → model → bin gives the same bytes.
    let back = ColmapModel::read(&tmp.path().join("txt")).unwrap();
    back.write(&tmp.path().join("bin2"), ModelFormat::Binary)
        .unwrap();
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        assert_eq!(
            std::fs::read(tmp.path().join("bin").join(f)).unwrap(),
            std::fs::read(tmp.path().join("bin2").join(f)).unwrap(),
            "{f}"
        );
    }
}

#[test]
fn corrupt_and_missing_files_are_errors_that_name_the_file() {
    let m = sample_model(false);
    let tmp = tempfile::tempdir().unwrap();
    m.write(tmp.path(), ModelFormat::Binary).unwrap();
    let images = tmp.path().join("images.bin");
    let bytes = std::fs::read(&images).unwrap();
    for cut in [3, 20, bytes.len() / 2, bytes.len() - 1] {
        std::fs::write(&images, &bytes[..cut]).unwrap();
        let e = binary::read_images(&images).unwrap_err();
        assert!(
            matches!(e, ModelError::Malformed { .. }) && e.to_string().contains("images.bin"),
            "{e}"
        );
    }
    // A huge count must not allocate.
    let mut huge = bytes.clone();
    huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(&images, &huge).unwrap();
    assert!(binary::read_images(&images).is_err());

    let txt = tmp.path().join("txt");
    m.write(&txt, ModelFormat::Text).unwrap();
    let cams = txt.join("cameras.txt");
    std::fs::write(&cams, "1 OPENCV 640 480 1 2 3\n").unwrap();
    let e = ColmapModel::read(&txt).unwrap_err();
    assert!(
        matches!(
            e,
            ModelError::ParamCount {
                got: 3,
                expected: 8,
                ..
            }
        ),
        "{e}"
    );
    std::fs::write(&cams, "1 BROWN 640 480 1 2 3\n").unwrap();
    assert!(matches!(
        ColmapModel::read(&txt).unwrap_err(),
        ModelError::UnknownCameraModel { .. }
    ));
    let e = ColmapModel::read(&tmp.path().join("nothing")).unwrap_err();
    assert!(e.to_string().contains("sparse/0"), "{e}");
}

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/colmap/tiny")
}

#[test]
fn reads_the_committed_model_written_by_colmap_3_8() {
    let bin = ColmapModel::read(&fixture_dir().join("bin")).unwrap();
    let txt = ColmapModel::read(&fixture_dir().join("txt")).unwrap();
    // COLMAP writes text with 17 significant digits: the two files hold the same numbers.
    assert_eq!(bin, txt);
    assert_eq!(bin.images.len(), 4);
    assert!(bin.points3d.len() > 50, "{}", bin.points3d.len());
    for p in bin.points3d.values() {
        assert!(p.track.len() >= 2);
        for t in &p.track {
            assert_eq!(
                bin.images[&t.image_id].points2d[t.point2d_idx as usize].point3d_id,
                p.id
            );
        }
    }
    for i in bin.images.values() {
        let q = i.qvec;
        assert!(((q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0).abs() < 1e-9);
        assert!(bin.cameras.contains_key(&i.camera_id));
    }
    // Our writer reproduces COLMAP's binary files up to record order.
    let tmp = tempfile::tempdir().unwrap();
    bin.write(tmp.path(), ModelFormat::Binary).unwrap();
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        let (mut a, mut b) = (
            std::fs::read(fixture_dir().join("bin").join(f)).unwrap(),
            std::fs::read(tmp.path().join(f)).unwrap(),
        );
        assert_eq!(a.len(), b.len(), "{f}");
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "{f}");
    }
}

fn model_converter(input: &Path, output: &Path, output_type: &str) {
    std::fs::create_dir_all(output).unwrap();
    let bin = calib::colmap_runner::find_colmap(None).unwrap();
    let out = Command::new(bin)
        .args(["model_converter", "--input_path"])
        .arg(input)
        .arg("--output_path")
        .arg(output)
        .args(["--output_type", output_type])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn colmap_reads_what_we_write_in_both_formats() {
    if !common::colmap_available() {
        return;
    }
    let m = sample_model(true);
    let tmp = tempfile::tempdir().unwrap();
    m.write(&tmp.path().join("ours_bin"), ModelFormat::Binary)
        .unwrap();
    model_converter(
        &tmp.path().join("ours_bin"),
        &tmp.path().join("colmap_txt"),
        "TXT",
    );
    assert_eq!(
        ColmapModel::read(&tmp.path().join("colmap_txt")).unwrap(),
        m
    );
    m.write(&tmp.path().join("ours_txt"), ModelFormat::Text)
        .unwrap();
    model_converter(
        &tmp.path().join("ours_txt"),
        &tmp.path().join("colmap_bin"),
        "BIN",
    );
    assert_eq!(
        ColmapModel::read(&tmp.path().join("colmap_bin")).unwrap(),
        m
    );
}

/// Regenerates `fixtures/colmap/tiny/` with the real COLMAP:
/// `REGENERATE_COLMAP_FIXTURE=1 cargo test -p calib --test integration -- --ignored colmap_model_io::`.
#[test]
#[ignore = "maintenance: rewrites fixtures/colmap/tiny/ with the real COLMAP (set REGENERATE_COLMAP_FIXTURE=1)"]
fn regenerate_fixture() {
    if std::env::var_os("REGENERATE_COLMAP_FIXTURE").is_none() || !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (video, stills) = common::rig(4, (320, 240));
    let cams = [
        video[0].clone(),
        video[1].clone(),
        video[2].clone(),
        stills[1].clone(),
    ];
    let paths = common::render_to(tmp.path(), &cams);
    let frames: Vec<(String, PathBuf)> = cams
        .iter()
        .zip(&paths)
        .map(|(c, p)| (c.name.clone(), p.clone()))
        .collect();
    let ws = calib::colmap_runner::Workspace::create(
        &tmp.path().join("ws"),
        &frames,
        &[],
        calib::colmap_runner::StillsCameras::Shared,
        calib::colmap_runner::VideoCameras::Separate,
    )
    .unwrap();
    let config = calib::colmap_runner::ColmapConfig {
        init_min_num_inliers: 30,
        ..Default::default()
    };
    let bin = calib::colmap_runner::find_colmap(None).unwrap();
    let run = ws.run(&bin, &config, &shared_types::NoProgress).unwrap();
    let (model_dir, _) = &run.models[0];
    let dst = fixture_dir();
    let _ = std::fs::remove_dir_all(&dst);
    std::fs::create_dir_all(dst.join("bin")).unwrap();
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        std::fs::copy(model_dir.join(f), dst.join("bin").join(f)).unwrap();
    }
    model_converter(&dst.join("bin"), &dst.join("txt"), "TXT");
}
