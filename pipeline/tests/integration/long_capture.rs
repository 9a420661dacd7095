//! The long simulated capture (`fixtures/demo-long.toml`, a figure walking a loop for
//! 60 s) cut to 10 s and shrunk to 160×120 so that it runs in CI: with the default
//! `[chunks]` (5 s) the clip trains as two chunks, each loading only its own window of
//! frames, and render and eval draw the whole clip from the merged model.

use crate::common;

use std::fs;

use pipeline::chunks::runner::ChunksRecord;
use pipeline::runner::Selection;

/// The long scene, `seconds` long at 160×120 without supersampling.
pub fn long_scene(seconds: f64) -> rig::sim::Scene {
    let path = common::fixture("demo-long.toml");
    let text = fs::read_to_string(&path)
        .unwrap()
        .replace("duration = 60.0", &format!("duration = {seconds}"))
        .replace("supersample = 2", "supersample = 1")
        .replace("width = 480\nheight = 360", "width = 160\nheight = 120");
    rig::sim::Scene::from_toml_str(&text, &path.display().to_string()).unwrap()
}

const SETTINGS: &str = "[sync]\nmethod = \"timestamps\"\n\
    [init]\nmoments = 2\nsweep_size = 64\nsweep_max_planes = 64\nsweep_stills = false\n\
    [train]\niterations = 10\nbatch_size = 1\ncheckpoint_every = 0\n\
    [train.densify]\nfrom_iteration = 2\nuntil_iteration = 8\nevery = 3\nopacity_reset_every = 0\n\
    [render]\nframes = 4\nvideo = false\n[eval]\nheldout_per_camera = 2\n[export]\nsteps = 2\nviewer = false\n";

#[test]
fn ten_seconds_train_as_two_chunks_of_their_own_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("long");
    let quiet = pipeline::report::Reporter::new(pipeline::report::OutputMode::Quiet);
    pipeline::simulate::simulate_into(&long_scene(10.0), &root, &quiet).unwrap();
    pipeline::simulate::write_truth_calibration(&root).unwrap();
    fs::write(root.join("capture.toml"), SETTINGS).unwrap();
    let summary = common::run_stages(&root, Selection::default());
    assert!(summary.failed.is_none(), "{summary:?}");

    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    assert!(index.frames.len() >= 148, "{} frames", index.frames.len());
    let record: ChunksRecord =
        serde_json::from_str(&fs::read_to_string(root.join("work/train/chunks.json")).unwrap())
            .unwrap();
    assert_eq!(record.chunks.len(), 2);
    // Each chunk held its half of the clip and half a second (7–8 frames) of the other.
    let half = index.frames.len() / 2;
    for c in &record.chunks {
        let frames = c.window.1 - c.window.0;
        assert!(frames <= half + 9 && frames >= half, "{c:?}");
        assert!(c.kept > 0, "{c:?}");
    }
    let metrics: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/eval/metrics.json")).unwrap())
            .unwrap();
    eprintln!("{metrics}");
    let rgb = fs::read_dir(root.join("work/render/rgb")).unwrap().count();
    assert_eq!(rgb, 4);
}
