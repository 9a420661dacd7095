//! Helpers shared by the pipeline's integration tests.
#![allow(dead_code)]

pub mod demo;

use std::fs;
use std::path::{Path, PathBuf};

/// The first bytes of an MP4 file (`ftyp` box): enough for layout validation, which only
/// looks at the container signature.
pub const MP4_HEADER: &[u8] = b"\x00\x00\x00\x18ftypmp42\x00\x00\x00\x00mp42isom";

/// A capture directory with `cameras` camera folders holding one GoPro-named video each,
/// and `stills` photos.
pub fn make_capture(root: &Path, cameras: usize, stills: usize) -> PathBuf {
    for i in 0..cameras {
        let dir = root.join("raw").join(format!("cam{i}"));
        fs::create_dir_all(&dir).unwrap();
        let mut bytes = MP4_HEADER.to_vec();
        bytes.extend_from_slice(format!("camera {i}").as_bytes());
        fs::write(dir.join("GX010001.MP4"), bytes).unwrap();
    }
    if stills > 0 {
        let dir = root.join("stills");
        fs::create_dir_all(&dir).unwrap();
        for i in 0..stills {
            fs::write(
                dir.join(format!("still_{i:02}.jpg")),
                b"\xff\xd8\xff\xe0 not really decoded",
            )
            .unwrap();
        }
    }
    root.to_path_buf()
}

/// Every file and folder under `root`, relative, sorted.
pub fn tree(root: &Path) -> Vec<String> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
        if let Ok(entries) = fs::read_dir(dir) {
            for e in entries.flatten() {
                let p = e.path();
                out.push(p.strip_prefix(root).unwrap().to_string_lossy().into_owned());
                if p.is_dir() {
                    walk(root, &p, out);
                }
            }
        }
    }
    let mut out = Vec::new();
    walk(root, root, &mut out);
    out.sort();
    out
}

/// Every stage cheap: clock sync, random initial points, 10 training iterations, two
/// rendered PNG frames (no MP4), one held-out view per camera, one export step.
pub const CHEAP: &str = "[sync]\nmethod = \"timestamps\"\n[init]\nsource = \"random\"\n\
    [train]\niterations = 10\nbatch_size = 1\ncheckpoint_every = 0\n\
    [train.densify]\nfrom_iteration = 4\nuntil_iteration = 8\nevery = 4\nopacity_reset_every = 0\n\
    [render]\nframes = 2\nvideo = false\n[eval]\nheldout_per_camera = 1\n[export]\nsteps = 1\nviewer = false\n";

/// The tiny simulated capture (4 cameras, 160×120, 15 frames, its true calibration) with
/// `settings` as capture.toml.
pub fn tiny_capture(root: &Path, settings: &str) -> PathBuf {
    let scene = rig::sim::Scene::from_file(&fixture("tiny.toml")).unwrap();
    let quiet = pipeline::report::Reporter::new(pipeline::report::OutputMode::Quiet);
    pipeline::simulate::simulate_into(&scene, root, &quiet).unwrap();
    pipeline::simulate::write_truth_calibration(root).unwrap();
    std::fs::write(root.join("capture.toml"), settings).unwrap();
    root.to_path_buf()
}

/// A copy of the folder `from` (files and subfolders) at `to`.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

/// A file of the repository's `fixtures/` folder.
pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(name)
}

/// Just `stage`, forced or not.
pub fn only(stage: &str, force: bool) -> pipeline::runner::Selection {
    pipeline::runner::Selection {
        only: Some(stage.into()),
        force,
        ..Default::default()
    }
}

/// Run the real pipeline's `selection` on a capture directory, quietly.
pub fn run_stages(
    root: &Path,
    selection: pipeline::runner::Selection,
) -> pipeline::runner::RunSummary {
    let (capture, config) = pipeline::open_capture(root).unwrap();
    pipeline::stages::pipeline()
        .run(
            &capture,
            &config,
            &selection,
            &pipeline::report::Reporter::new(pipeline::report::OutputMode::Quiet),
        )
        .unwrap()
}

/// The pose accuracy bound: every solved camera within 0.5° and 1 % of the rig
/// radius of the truth after a similarity alignment (errors printed).
pub fn assert_poses_close(solved: &[shared_types::Camera], truth: &[shared_types::Camera]) {
    let (_, errors, radius) = calib::similarity::compare(solved, truth).unwrap();
    assert_eq!(errors.len(), solved.len());
    for e in &errors {
        eprintln!(
            "{}: rotation {:.3}°, centre {:.3}% of the rig radius",
            e.name,
            e.rotation_deg,
            100.0 * e.centre / radius
        );
        assert!(e.rotation_deg < 0.5, "{}: {}°", e.name, e.rotation_deg);
        assert!(
            e.centre < 0.01 * radius,
            "{}: {} of radius {radius}",
            e.name,
            e.centre
        );
    }
}

/// Whether the real `colmap` binary is here. Without it a test skips with a message, except
/// under `CI=true`, where scripts/setup.sh installs COLMAP and its absence is a failure.
pub fn colmap_available() -> bool {
    match calib::colmap_runner::find_colmap(None) {
        Ok(_) => true,
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") => {
            panic!("COLMAP is missing under CI=true (scripts/setup.sh installs it): {e}")
        }
        Err(e) => {
            eprintln!("skipping: {e}");
            false
        }
    }
}
