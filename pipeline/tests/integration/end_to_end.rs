//! The real stages on a simulated capture: ingest → sync → frames, with the offsets found
//! checked against the simulator's ground truth, and reruns checked on real outputs.

use crate::common;

use common::fixture;
use std::fs;
use std::path::Path;

use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::{RunSummary, Selection};
use pipeline::{open_capture, simulate, stages};

fn run(root: &Path, sel: Selection) -> RunSummary {
    common::run_stages(root, sel)
}

fn to(stage: &str) -> Selection {
    Selection {
        to: Some(stage.into()),
        ..Default::default()
    }
}

#[test]
fn simulated_audio_capture_is_ingested_synchronised_and_aligned() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let scene = rig::sim::Scene::from_file(&fixture("sync-audio.toml")).unwrap();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    // Simulating again into the same folder must refuse, leaving the capture intact.
    let before = fs::read(root.join("raw/cam1/GX010001.MP4")).unwrap();
    assert!(simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).is_err());
    assert_eq!(
        fs::read(root.join("raw/cam1/GX010001.MP4")).unwrap(),
        before
    );

    let summary = run(&root, to("frames"));
    assert_eq!(summary.ran, ["ingest", "sync", "frames"], "{summary:?}");
    assert!(summary.failed.is_none());

    // Offsets: the simulator says when each camera's frame 0 happened in scene time.
    let truth: rig::sim::OffsetsFile =
        serde_json::from_str(&fs::read_to_string(root.join("groundtruth/offsets.json")).unwrap())
            .unwrap();
    let sync = rig::sync::SyncResult::read_json(&root.join("work/sync/sync.json")).unwrap();
    let errors = pipeline::bench::sync::offset_errors(&truth, &sync).unwrap();
    assert_eq!(errors.len(), 4);
    for (name, error) in errors {
        // The scene has acoustic path delays on (cameras 3–4 m from the clap): a few ms.
        assert!(error.abs() < 0.012, "{name}: offset error {error} s");
    }

    // Frames: every camera has an image per aligned frame, at the capture's size.
    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    assert!(index.frames.len() >= 10, "{} frames", index.frames.len());
    for frame in &index.frames {
        for view in &frame.views {
            assert!(
                root.join("work/frames").join(&view.file).is_file(),
                "{}",
                view.file
            );
            assert!(view.residual_s.abs() <= 0.5 / index.fps + 1e-9);
        }
    }

    // Unchanged → everything skipped; a frames setting → only frames reruns.
    assert_eq!(
        run(&root, to("frames")).skipped,
        ["ingest", "sync", "frames"]
    );
    fs::write(root.join("capture.toml"), "[frames]\nlong_side = 80\n").unwrap();
    let (capture, config) = open_capture(&root).unwrap();
    let rows = stages::pipeline().status(&capture, &config).unwrap();
    assert!(
        rows[2]
            .details
            .iter()
            .any(|d| d.contains("frames.long_side changed: 960 → 80")),
        "{:?}",
        rows[2]
    );
    let summary = run(&root, to("frames"));
    assert_eq!(summary.skipped, ["ingest", "sync"]);
    assert_eq!(summary.ran, ["frames"]);
    let img = image::open(
        root.join("work/frames")
            .join(&index.frames[0].views[0].file),
    )
    .unwrap();
    assert_eq!(img.width().max(img.height()), 80);
}

/// No audio anywhere → `auto` falls back to the flash; the rolling shutter (declared in
/// capture.toml) times it below a frame; a camera with dropped frames still gets one image
/// per aligned frame, the nearest it has, with the residual recorded.
#[test]
fn simulated_flash_capture_with_dropped_frames_is_synchronised() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let text = fs::read_to_string(fixture("sync-flash.toml"))
        .unwrap()
        .replacen("offset = 0.2\n", "offset = 0.2\ndropped = [3, 4, 20]\n", 1);
    assert!(text.contains("dropped"));
    let scene = rig::sim::Scene::from_toml_str(&text, "sync-flash.toml + dropped frames").unwrap();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    fs::write(
        root.join("capture.toml"),
        "[sync]\nreadout_s = 0.0266\nexposure_s = 0.004\n",
    )
    .unwrap();
    let summary = run(&root, to("frames"));
    assert_eq!(summary.ran, ["ingest", "sync", "frames"], "{summary:?}");

    let truth: rig::sim::OffsetsFile =
        serde_json::from_str(&fs::read_to_string(root.join("groundtruth/offsets.json")).unwrap())
            .unwrap();
    assert_eq!(truth.cameras[2].dropped_frames, [3, 4, 20]);
    let sync = rig::sync::SyncResult::read_json(&root.join("work/sync/sync.json")).unwrap();
    assert_eq!(sync.method, rig::sync::SyncMethod::Flash);
    let errors = pipeline::bench::sync::offset_errors(&truth, &sync).unwrap();
    assert_eq!(errors.len(), 4);
    for (name, error) in errors {
        println!("flash sync {name}: error {:.3} ms", error * 1e3);
        // A frame is 33 ms; H.264 and 120 rows leave about a millisecond.
        assert!(error.abs() < 0.003, "{name}: error {error} s");
    }

    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    let period = 1.0 / index.fps;
    let mut stand_ins = 0;
    for frame in &index.frames {
        let view = &frame.views[2];
        assert!(root.join("work/frames").join(&view.file).is_file());
        // The camera frame shown (its file time is frame / fps) is one the file has.
        let camera_frame = ((view.timestamp_s - sync.cameras[2].offset_s) * 30.0).round() as u32;
        assert!(
            !truth.cameras[2].dropped_frames.contains(&camera_frame),
            "{view:?}"
        );
        assert!(view.residual_s.abs() <= period + 1e-9, "{view:?}");
        if view.residual_s.abs() > 0.5 * period + 1e-9 {
            stand_ins += 1;
        }
    }
    assert!(
        stand_ins >= 1,
        "a dropped frame must be replaced by a neighbour"
    );
}

/// The pose acceptance check on a simulated capture: COLMAP on the first frame of the 4
/// video cameras plus 8 stills of `poses.toml`, compared with the ground truth after a
/// similarity alignment. (It used to converge to degenerate solves: the room's texture
/// tile repeated, SIFT matched copies of it; the simulator now lays non-periodic spots
/// over every texture, and the poses stage rejects implausible lenses and retries.)
#[test]
fn simulated_static_capture_gets_poses_from_colmap() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let scene = rig::sim::Scene::from_file(&fixture("poses.toml")).unwrap();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    // A static scene with no clap or flash: the cameras' own timestamps are the timeline.
    fs::write(
        root.join("capture.toml"),
        "[sync]\nmethod = \"timestamps\"\n",
    )
    .unwrap();
    let summary = run(&root, to("poses"));
    assert_eq!(
        summary.ran,
        ["ingest", "sync", "frames", "poses"],
        "{summary:?}"
    );

    let solved = calib::poses::PosesFile::read(&root.join("work/poses/cameras.json")).unwrap();
    let truth: shared_types::CameraSet =
        serde_json::from_str(&fs::read_to_string(root.join("groundtruth/cameras.json")).unwrap())
            .unwrap();
    let video: Vec<_> = truth
        .cameras
        .iter()
        .filter(|c| c.name.starts_with("cam"))
        .cloned()
        .collect();
    assert_eq!(solved.set.cameras.len(), 4);
    common::assert_poses_close(&solved.set.cameras, &video);
    // The engine sees the frames' size.
    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    assert_eq!(
        solved.set.cameras[0].intrinsics.width,
        index.cameras[0].width
    );

    // The true depth as exported point maps, aligned to the solved poses: every
    // pair accepted, its ray scale agreeing with COLMAP's sparse points.
    let maps = simulate::write_truth_pointmaps(&root).unwrap();
    assert_eq!(fs::read_dir(&maps).unwrap().count(), 6);
    let mut toml = fs::read_to_string(root.join("capture.toml")).unwrap();
    toml.push_str("[init]\npointmaps = \"pointmaps\"\n");
    fs::write(root.join("capture.toml"), toml).unwrap();
    let summary = run(
        &root,
        Selection {
            only: Some("init".into()),
            ..Default::default()
        },
    );
    assert_eq!(summary.ran, ["init"], "{summary:?}");
    let report: pointinit::InitReport =
        serde_json::from_str(&fs::read_to_string(root.join("work/init/init.json")).unwrap())
            .unwrap();
    assert_eq!(report.source, pointinit::UsedSource::Npy, "{report:#?}");
    assert_eq!(report.pairs.len(), 6);
    for p in &report.pairs {
        assert!(p.accepted, "{p:?}");
        let (ray, sparse) = (p.ray_scale.unwrap(), p.sparse_scale.unwrap());
        assert!((ray / sparse - 1.0).abs() < 0.05, "{p:?}");
    }
}
