//! A real held-out check: CMU Panoptic's five HD views (`../shared/data/panoptic-5view`)
//! made into a capture by `scripts/panoptic-capture.sh` (four image-sequence cameras train,
//! the fifth is held out, Panoptic's own calibration in centimetres), run through every
//! stage that leads to `eval`. The held-out PSNR must stay near what the pipeline reaches
//! (BENCHMARKS.md, "panoptic-5view: plane-sweep init"). The held-out camera
//! is 68° from the nearest training camera; the plane-sweep init, 4C4D's decay and the
//! learned backdrop (faded to the training frames' mean colour) lift it from grey fog
//! (13.4 dB) to 20.23 dB, above a flat image of that colour (15.6 dB).

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

use pipeline::runner::Selection;

/// Held-out PSNR floor (dB) at the fixture's settings; measured 20.23 dB (BENCHMARKS.md;
/// 20.05 with the neural decay, 19.75 with it on the mean colour alone, 18.22 while densification ran to the last step).
const HELDOUT_PSNR_FLOOR: f64 = 19.6;
/// Training-view PSNR floor (dB) at the fixture's settings; measured 31.15 dB.
const TRAIN_PSNR_FLOOR: f64 = 29.0;

fn data_dir() -> Option<PathBuf> {
    let rel = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/panoptic-5view");
    let found = [rel, PathBuf::from("/work/shared/data/panoptic-5view")]
        .into_iter()
        .find(|p| p.join("camera_parameters.json").is_file());
    if found.is_none() {
        if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
            panic!("panoptic-5view is absent under CI=true: ../shared/data must hold it");
        }
        eprintln!("skipping: panoptic-5view is absent (real data, not part of the repository)");
    }
    found
}

/// The capture, made by the script users run, at the fixture's settings.
fn make_capture(data: &Path, root: &Path) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/panoptic-capture.sh");
    let out = Command::new("bash")
        .arg(&script)
        .arg(data)
        .arg(root)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn panoptic_five_views_train_on_four_and_are_measured_on_the_fifth() {
    let Some(data) = data_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("panoptic");
    make_capture(&data, &root);
    let summary = common::run_stages(
        &root,
        Selection {
            to: Some("train".into()),
            ..Default::default()
        },
    );
    assert!(summary.failed.is_none(), "{summary:?}");
    let summary = common::run_stages(
        &root,
        Selection {
            only: Some("eval".into()),
            ..Default::default()
        },
    );
    assert_eq!(summary.ran, ["eval"], "{summary:?}");
    let work = root.join("work");

    // Ingest: five image-sequence cameras, five moments one second apart.
    let streams = json(&work.join("ingest/streams.json"));
    for camera in streams["cameras"].as_array().unwrap() {
        assert_eq!(camera["kind"], "images", "{}", camera["name"]);
        assert_eq!(camera["video"]["width"], 1920);
        let times: Vec<f64> = camera["timestamps"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t.as_f64().unwrap())
            .collect();
        assert_eq!(times, [0.0, 1.0, 2.0, 3.0, 4.0]);
    }
    assert_eq!(json(&work.join("sync/sync.json"))["method"], "timestamps");
    let frames = rig::frames::FramesIndex::read_json(&work.join("frames/frames.json")).unwrap();
    assert_eq!(frames.frames.len(), 5);
    assert_eq!(
        (frames.cameras[0].width, frames.cameras[0].height),
        (480, 270)
    );

    // Poses: Panoptic's centimetres became metres; the cameras sit on the dome, a few
    // metres apart, before the pipeline's normalisation.
    let poses = calib::poses::PosesFile::read(&work.join("poses/cameras.json")).unwrap();
    assert_eq!(poses.set.cameras.len(), 4);
    let scale = poses.normalisation.scale;
    let centres: Vec<_> = poses
        .set
        .cameras
        .iter()
        .map(|c| c.world_to_camera.centre() / scale)
        .collect();
    let widest = centres
        .iter()
        .flat_map(|a| centres.iter().map(move |b| (*a - *b).length()))
        .fold(0.0, f64::max);
    assert!((3.0..8.0).contains(&widest), "widest pair {widest} m");

    // init.json names its cloud relative to work/init/ (the stage ran in a temporary folder).
    let init = json(&work.join("init/init.json"));
    assert_eq!(init["output"], "points.ply");
    // The plane sweep gave thousands of points at each of the five moments (17 would have
    // been triangulated), so no random cloud was added.
    assert_eq!(init["source"], "swept", "{init:#}");
    let sweeps = init["sweeps"].as_array().unwrap();
    assert_eq!(sweeps.len(), 5);
    for sweep in sweeps {
        assert!(sweep["points"].as_u64().unwrap() >= 5000, "{sweep}");
    }
    assert!(init["fallbacks"].as_array().unwrap().is_empty(), "{init:#}");

    // Eval: five held-out views of cam4, at least as good as measured.
    let metrics = json(&work.join("eval/metrics.json"));
    let psnr = |set: &str| metrics[set]["mean"]["psnr"].as_f64().unwrap();
    assert_eq!(metrics["heldout"]["frames"], 5);
    let (held, train) = (psnr("heldout"), psnr("train"));
    eprintln!("panoptic-5view: held-out {held:.2} dB, training views {train:.2} dB");
    assert!(held >= HELDOUT_PSNR_FLOOR, "held-out {held:.2} dB");
    assert!(train >= TRAIN_PSNR_FLOOR, "training views {train:.2} dB");
}
