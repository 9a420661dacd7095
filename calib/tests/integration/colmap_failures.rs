//! Failures as users meet them, with the real COLMAP: each a clear error that names the
//! images and what to try, and no `cameras.json` left behind.

use crate::common;

use std::path::{Path, PathBuf};

use calib::poses::{self, PosesConfig, PosesError, PosesInputs};
use shared_types::NoProgress;

fn noise_set(dir: &Path, n: usize, seed0: u64, size: (u32, u32)) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    (0..n)
        .map(|i| {
            let p = dir.join(format!("n{i}.png"));
            common::noise_image(&p, size, seed0 + 10 * i as u64);
            p
        })
        .collect()
}

#[test]
fn unrelated_images_give_no_initial_pair_with_a_per_image_report() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let video: Vec<(String, PathBuf)> = noise_set(&tmp.path().join("v"), 4, 100, (240, 180))
        .into_iter()
        .enumerate()
        .map(|(i, p)| (format!("cam{i}"), p))
        .collect();
    let stills = noise_set(&tmp.path().join("s"), 4, 500, (240, 180));
    let inputs = PosesInputs {
        video_frames: video,
        stills,
        working_size: None,
        config: PosesConfig::default(),
        known_lenses: Default::default(),
    };
    let out_dir = tmp.path().join("poses");
    std::fs::create_dir_all(&out_dir).unwrap();
    std::fs::write(out_dir.join("cameras.json"), "{}").unwrap(); // a previous run's result
    let e = poses::solve(&inputs, &out_dir, &NoProgress).unwrap_err();
    let msg = e.to_string();
    eprintln!("{msg}");
    assert!(matches!(e, PosesError::NoInitialPair { .. }), "{msg}");
    assert!(
        msg.contains("video/cam2.png")
            && msg.contains("What to try")
            && msg.contains("more stills"),
        "{msg}"
    );
    assert!(!out_dir.join("cameras.json").exists());
}

#[test]
fn a_video_camera_that_sees_something_else_is_named() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let rig = common::render_rig(&tmp.path().join("capture"), 6, (320, 240));
    let mut video = rig.video_paths.clone();
    let stray = tmp.path().join("stray.png");
    common::noise_image(&stray, (320, 240), 77);
    video[3].1 = stray;
    let config = PosesConfig {
        colmap: calib::colmap_runner::ColmapConfig {
            init_min_num_inliers: 50,
            ..Default::default()
        },
        ..Default::default()
    };
    let inputs = PosesInputs {
        video_frames: video,
        stills: rig.still_paths.clone(),
        working_size: None,
        config,
        known_lenses: Default::default(),
    };
    let out_dir = tmp.path().join("poses");
    let e = poses::solve(&inputs, &out_dir, &NoProgress).unwrap_err();
    let msg = e.to_string();
    eprintln!("{msg}");
    match &e {
        PosesError::VideoNotRegistered { missing, diagnosis } => {
            assert_eq!(missing, &["cam3".to_string()]);
            let cam3 = diagnosis
                .images
                .iter()
                .find(|i| i.video_camera.as_deref() == Some("cam3"))
                .unwrap();
            assert!(cam3.keypoints > 200 && cam3.model.is_none());
            assert!(
                diagnosis
                    .images
                    .iter()
                    .filter(|i| i.model.is_some())
                    .count()
                    >= 8
            );
        }
        other => panic!("{other}"),
    }
    assert!(msg.contains("match no other image well"), "{msg}");
    assert!(!out_dir.join("cameras.json").exists());
}

#[test]
fn colmap_failing_or_crashing_is_reported_with_its_log() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let rig = common::render_rig(&tmp.path().join("capture"), 4, (160, 120));
    let out_dir = tmp.path().join("poses");

    // COLMAP refusing its options (exit code 1).
    let mut config = PosesConfig::default();
    config.colmap.max_image_size = 0;
    let inputs = PosesInputs {
        video_frames: rig.video_paths.clone(),
        stills: rig.still_paths.clone(),
        working_size: None,
        config,
        known_lenses: Default::default(),
    };
    let e = poses::solve(&inputs, &out_dir, &NoProgress).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("feature_extractor failed (exit code 1)") && msg.contains("max_image_size"),
        "{msg}"
    );
    assert!(msg.contains("feature_extractor_all.log"), "{msg}");

    // COLMAP killed mid-run (as by the OOM killer): the real binary, killed by SIGKILL.
    let real = calib::colmap_runner::find_colmap(None).unwrap();
    let wrapper = tmp.path().join("colmap-killed");
    std::fs::write(
        &wrapper,
        format!(
            "#!/bin/sh\n(sleep 0.05; kill -KILL $$) &\nexec {} \"$@\"\n",
            real.display()
        ),
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&wrapper, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let mut inputs = inputs;
    inputs.config = PosesConfig::default();
    inputs.config.colmap.binary = Some(wrapper);
    let e = poses::solve(&inputs, &out_dir, &NoProgress).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("crashed (killed by signal 9)"), "{msg}");
    assert!(!out_dir.join("cameras.json").exists());
}
