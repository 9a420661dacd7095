//! The poses stage on a rendered scene with known cameras, solved by the real COLMAP.

use crate::common;

use calib::poses::{self, PosesConfig, PosesError, PosesFile, PosesInputs};
use shared_types::{CameraSet, Distortion, NoProgress};

#[test]
fn solves_the_rendered_rig_within_half_a_degree() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    // The video cameras have a real lens (barrel distortion); COLMAP solves it (RADIAL).
    let lens = Distortion::radial_tangential(-0.12, 0.03, 0.0, 0.0, 0.0);
    let rig = common::render_rig_with_lens(&tmp.path().join("capture"), 8, (480, 360), lens);
    let inputs = PosesInputs {
        video_frames: rig.video_paths.clone(),
        stills: rig.still_paths.clone(),
        working_size: Some((320, 240)),
        config: PosesConfig::default(),
        known_lenses: Default::default(),
    };
    let out_dir = tmp.path().join("work/poses");
    let progress = common::RecordingProgress::default();
    let out = match poses::solve(&inputs, &out_dir, &progress) {
        Ok(o) => o,
        Err(e) => panic!("{e}"),
    };
    let cams = &out.file.set.cameras;
    eprintln!("source: {:?}", out.file.source);
    assert_eq!(
        cams.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(),
        ["cam0", "cam1", "cam2", "cam3"]
    );
    let (_, errors, radius) = calib::similarity::compare(cams, &rig.video).unwrap();
    for e in &errors {
        eprintln!(
            "{}: rotation {:.4}°, centre {:.4}% of radius",
            e.name,
            e.rotation_deg,
            100.0 * e.centre / radius
        );
        assert!(e.rotation_deg < 0.5, "{e:?}");
        assert!(e.centre < 0.01 * radius, "{e:?}");
    }
    // Intrinsics scaled to the working size: truth is hfov 70° at 480 px → fx at 320 px.
    let truth_fx = rig.video[0].intrinsics.scaled_to(320, 240).fx;
    for c in cams {
        assert_eq!((c.intrinsics.width, c.intrinsics.height), (320, 240));
        assert!((c.intrinsics.fx / truth_fx - 1.0).abs() < 0.01, "{c:?}");
    }
    // COLMAP's progress reached the Progress sink, step by step.
    let messages = progress.messages.lock().unwrap().clone();
    assert_eq!(
        messages.first().map(String::as_str),
        Some("start 3 COLMAP steps")
    );
    assert!(
        messages
            .iter()
            .any(|m| m.starts_with("feature_extractor: Processed file [12/12]")),
        "{messages:?}"
    );
    assert!(
        messages
            .iter()
            .any(|m| m.starts_with("mapper: Registering image")),
        "{messages:?}"
    );
    assert_eq!(
        progress.advanced.load(std::sync::atomic::Ordering::Relaxed),
        3
    );
    for c in cams {
        let Distortion::Opencv { k1, k2, .. } = c.distortion else {
            panic!("{:?}", c.distortion)
        };
        assert!(
            (k1 + 0.12).abs() < 0.02 && (k2 - 0.03).abs() < 0.03,
            "{:?}",
            c.distortion
        );
    }
    // Normalised: video cameras at mean distance 1 from the origin.
    let mean_r = cams
        .iter()
        .map(|c| c.world_to_camera.centre().length())
        .sum::<f64>()
        / 4.0;
    assert!((mean_r - 1.0).abs() < 1e-9, "{mean_r}");
    // cameras.json reads as a plain CameraSet too; points file is there.
    let set: CameraSet =
        serde_json::from_str(&std::fs::read_to_string(&out.cameras_json).unwrap()).unwrap();
    assert_eq!(set.cameras.len(), cams.len());
    for (a, b) in set.cameras.iter().zip(cams) {
        assert_eq!(a.name, b.name);
        assert!((a.world_to_camera.centre() - b.world_to_camera.centre()).length() < 1e-12);
        assert!((a.intrinsics.fx - b.intrinsics.fx).abs() < 1e-9);
    }
    assert!(out.file.num_points > 100);
    assert!(out.points_ply.as_ref().unwrap().is_file());
    // The stills are posed too, named by their files, in the same normalised frame: the
    // video cameras' similarity to the truth puts each still where it was filmed.
    let file_name = |p: &std::path::Path| p.file_name().unwrap().to_string_lossy().into_owned();
    let mut stills = PosesFile::read(&out.cameras_json).unwrap().stills;
    stills.sort_by(|a, b| a.name.cmp(&b.name));
    let mut names: Vec<String> = rig.still_paths.iter().map(|p| file_name(p)).collect();
    names.sort();
    assert_eq!(
        stills.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
        names
    );
    let (similarity, _, radius) = calib::similarity::compare(cams, &rig.video).unwrap();
    for (path, truth) in rig.still_paths.iter().zip(&rig.stills) {
        let still = stills.iter().find(|c| c.name == file_name(path)).unwrap();
        assert_eq!(
            (still.intrinsics.width, still.intrinsics.height),
            (480, 360)
        );
        let error = (similarity.apply(still.world_to_camera.centre())
            - truth.world_to_camera.centre())
        .length();
        assert!(error < 0.02 * radius, "{}: {error}", still.name);
    }
}

fn inputs_for(rig: &common::RenderedRig) -> PosesInputs {
    PosesInputs {
        video_frames: rig.video_paths.clone(),
        stills: rig.still_paths.clone(),
        working_size: None,
        config: PosesConfig::default(),
        known_lenses: Default::default(),
    }
}

#[test]
fn bad_inputs_are_refused_before_colmap_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let rig = common::render_rig(&tmp.path().join("capture"), 4, (160, 120));
    let out_dir = tmp.path().join("poses");

    let mut few = inputs_for(&rig);
    few.stills.truncate(2);
    let e = poses::solve(&few, &out_dir, &NoProgress).unwrap_err();
    assert!(
        matches!(e, PosesError::TooFewStills { got: 2, min: 4 }),
        "{e}"
    );

    let mut blank = inputs_for(&rig);
    let blank_path = tmp.path().join("blank.png");
    common::blank(&blank_path, (160, 120));
    blank.video_frames[2].1 = blank_path.clone();
    let e = poses::solve(&blank, &out_dir, &NoProgress).unwrap_err();
    assert!(
        matches!(&e, PosesError::BlankImage { path, .. } if *path == blank_path),
        "{e}"
    );
    assert!(e.to_string().contains("blank.png"));

    let mut sizes = inputs_for(&rig);
    let odd = tmp.path().join("odd.png");
    common::noise_image(&odd, (200, 120), 3);
    sizes.stills[1] = odd;
    let e = poses::solve(&sizes, &out_dir, &NoProgress).unwrap_err();
    assert!(matches!(e, PosesError::StillSizesDiffer { .. }), "{e}");
    assert!(e.to_string().contains("per_image"));

    let mut missing = inputs_for(&rig);
    missing.config.colmap.binary = Some(tmp.path().join("no/such/colmap"));
    let e = poses::solve(&missing, &out_dir, &NoProgress).unwrap_err();
    assert!(e.to_string().contains("apt-get install colmap"), "{e}");

    assert!(!out_dir.join("cameras.json").exists());
}

#[test]
fn workspace_gives_each_video_camera_its_own_folder() {
    use calib::colmap_runner::{StillsCameras, Workspace};
    let tmp = tempfile::tempdir().unwrap();
    let rig = common::render_rig(&tmp.path().join("capture"), 2, (64, 48));
    for (mode, still) in [
        (StillsCameras::Shared, "stills/001_still1.png"),
        (StillsCameras::PerImage, "stills/001/001_still1.png"),
    ] {
        let ws = Workspace::create(
            &tmp.path().join("ws"),
            &rig.video_paths,
            &rig.still_paths,
            mode,
            calib::colmap_runner::VideoCameras::Separate,
        )
        .unwrap();
        let names: Vec<&str> = ws.images.iter().map(|i| i.colmap_name.as_str()).collect();
        assert_eq!(
            names[..4],
            [
                "video/cam0/cam0.png",
                "video/cam1/cam1.png",
                "video/cam2/cam2.png",
                "video/cam3/cam3.png"
            ]
        );
        assert_eq!(names[5], still);
        assert!(ws.image_dir().join(still).is_file());
    }
}

#[test]
fn fisheye_video_cameras_solve_with_opencv_fisheye() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let lens = Distortion::Fisheye {
        k1: 0.08,
        k2: -0.02,
        k3: 0.0,
        k4: 0.0,
    };
    let rig = common::render_rig_with_lens(&tmp.path().join("capture"), 8, (480, 360), lens);
    let mut config = PosesConfig::default();
    config.colmap.camera_model = calib::colmap::CameraModel::OpencvFisheye;
    // Four identical cameras in the same lens mode: one shared lens, fitted from 4 views.
    // (One image per camera leaves 8 fisheye intrinsics to a single view: rotation errors
    // up to ~1.2° were seen that way.)
    config.colmap.video_cameras = calib::colmap_runner::VideoCameras::Shared;
    // The lens's focal length is known (datasheet): a prior, checked against the solve.
    config.colmap.video_focal_px = Some(rig.video[0].intrinsics.fx);
    let inputs = PosesInputs {
        video_frames: rig.video_paths.clone(),
        stills: rig.still_paths.clone(),
        working_size: None,
        config,
        known_lenses: Default::default(),
    };
    let out = poses::solve(&inputs, &tmp.path().join("poses"), &NoProgress)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("source: {:?}", out.file.source);
    let cams = &out.file.set.cameras;
    let (_, errors, radius) = calib::similarity::compare(cams, &rig.video).unwrap();
    for (e, c) in errors.iter().zip(cams) {
        eprintln!(
            "{}: rotation {:.4}°, centre {:.4}% of radius, {:?}",
            e.name,
            e.rotation_deg,
            100.0 * e.centre / radius,
            c.distortion
        );
        assert!(e.rotation_deg < 0.5 && e.centre < 0.01 * radius, "{e:?}");
        assert!(
            matches!(c.distortion, Distortion::Fisheye { .. }),
            "{:?}",
            c.distortion
        );
        // The k's trade off against each other; the lens mapping itself must match: rays in
        // the camera frame land on the same pixels.
        let truth = &rig.video[0];
        let (mut worst, mut sum_sq, mut n) = (0.0f64, 0.0f64, 0usize);
        for y in (0..=360).step_by(30) {
            for x in (0..=480).step_by(30) {
                let px = glam::DVec2::new(x as f64, y as f64);
                let ray = truth
                    .distortion
                    .undistort(truth.intrinsics.to_normalised(px));
                let solved = c.intrinsics.to_pixels(c.distortion.distort(ray));
                let err = (solved - px).length();
                worst = worst.max(err);
                sum_sq += err * err;
                n += 1;
            }
        }
        let rms = (sum_sq / n as f64).sqrt();
        eprintln!(
            "{}: lens mapping error rms {rms:.2} px, worst {worst:.2} px",
            c.name
        );
        // The solve is repeatable on one machine (`deterministic`), not across CPUs: SIFT and
        // bundle adjustment take other SIMD paths. On this project's dev machine seeds 0-5
        // gave rms 0.44-0.70 px, worst (a corner) 0.74-1.15 px; one CI machine gave rms
        // 2.14 px, worst 3.21 px (k's 0.012/0.251/-0.351/0.085, poses still within 0.24°).
        // Four images leave the lens's outer rim weakly constrained. Dropping the lens
        // (k = 0) would be ~16 px off at the corners, so these bounds still catch a lost lens.
        assert!(rms < 3.0 && worst < 5.0, "rms {rms}, worst {worst}");
    }
    // All four share one lens; the stills were solved with their own (RADIAL) camera.
    assert!(cams.iter().all(|c| c.distortion == cams[0].distortion));
    assert!(
        tmp.path()
            .join("poses/colmap/logs/feature_extractor_video.log")
            .is_file()
    );
    assert!(
        tmp.path()
            .join("poses/colmap/logs/feature_extractor_stills.log")
            .is_file()
    );
}

/// `[poses] intrinsics`: the video cameras' lenses are given; COLMAP solves the poses only,
/// and the lenses come out exactly as given (no refinement), the poses as accurate.
#[test]
fn known_lenses_are_kept_exactly_and_only_poses_are_solved() {
    if !common::colmap_available() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let lens = Distortion::radial_tangential(-0.12, 0.03, 0.0, 0.0, 0.0);
    let rig = common::render_rig_with_lens(&tmp.path().join("capture"), 8, (480, 360), lens);
    let known: std::collections::BTreeMap<String, _> = rig
        .video
        .iter()
        .map(|c| (c.name.clone(), (c.intrinsics, c.distortion)))
        .collect();
    // COLMAP's CPU matcher is not repeatable (its approximate nearest-neighbour search
    // gives a few matches more or fewer per pair from run to run, measured), so the mapper
    // sees slightly different tracks each time; about one run in thirty it settles in a
    // local minimum with one camera far off. A second seed must then succeed: two such
    // runs in a row would be a real regression.
    let solve = |seed: u32| {
        let mut inputs = PosesInputs {
            known_lenses: known.clone(),
            ..inputs_for(&rig)
        };
        inputs.config.colmap.random_seed = seed;
        let out = poses::solve(
            &inputs,
            &tmp.path().join(format!("poses{seed}")),
            &NoProgress,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let (_, errors, radius) =
            calib::similarity::compare(&out.file.set.cameras, &rig.video).unwrap();
        (out, errors, radius)
    };
    // Looser than the free-lens solve (0.5°, 1 %): the final bundle adjustment keeps the
    // stills' lenses where the mapper left them (co-adapted to the video lens it refined),
    // which biases the poses. Measured over 32 runs with the shared known lens and the
    // median fit check (docs/poses.md): worst camera 0.02–0.34°.
    let accurate = |errors: &[calib::similarity::PoseError], radius: f64| {
        errors
            .iter()
            .all(|e| e.rotation_deg < 1.5 && e.centre < 0.03 * radius)
    };
    let (mut out, mut errors, mut radius) = solve(0);
    if !accurate(&errors, radius) {
        eprintln!("seed 0 settled in a local minimum: {errors:?}; trying seed 100");
        (out, errors, radius) = solve(100);
    }
    let cams = &out.file.set.cameras;
    for c in cams {
        let (intrinsics, distortion) = known[&c.name];
        assert_eq!(c.distortion, distortion, "{}", c.name);
        for (a, b) in [
            (c.intrinsics.fx, intrinsics.fx),
            (c.intrinsics.fy, intrinsics.fy),
            (c.intrinsics.cx, intrinsics.cx),
            (c.intrinsics.cy, intrinsics.cy),
        ] {
            assert!((a - b).abs() < 1e-9, "{}: {a} vs {b}", c.name);
        }
    }
    for e in &errors {
        eprintln!(
            "known lens, {}: rotation {:.4}°, centre {:.4}% of radius",
            e.name,
            e.rotation_deg,
            100.0 * e.centre / radius
        );
    }
    assert!(accurate(&errors, radius), "{errors:?}");
    match &out.file.source {
        poses::PoseSource::Colmap { model_dir, .. } => {
            assert!(model_dir.contains("known_lenses"), "{model_dir}")
        }
        other => panic!("{other:?}"),
    }
}
