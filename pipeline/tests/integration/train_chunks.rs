//! A clip trained in time chunks (`[chunks]`): the tiny capture (1 s at 15 fps) cut into
//! three chunks of five frames with one frame of overlap. The init places its moments per
//! chunk; each chunk trains on its own frames (the later ones on the first chunk's static
//! scene, frozen) into its own folder; a stop in the middle keeps its checkpoint, and the
//! next run continues to exactly the model of an uninterrupted run, and of one that trains
//! the later chunks two at once; the static scene's
//! opacities train on the cameras' static plates of the clip; the merged model is
//! the static scene plus each chunk's moving Gaussians of its own time, and render and
//! eval draw the whole clip from it.

use crate::common;

use std::fs;

use pipeline::chunks::plan::ChunkPlan;
use pipeline::chunks::runner::{ChunksRecord, STATIC_FILE};
use pipeline::chunks::static_scene;
use pipeline::interrupt;
use pipeline::runner::Selection;

const SETTINGS: &str = "[sync]\nmethod = \"timestamps\"\n[init]\nmoments = 2\nsweep_size = 64\nsweep_max_planes = 64\n\
    [train]\niterations = 12\nbatch_size = 1\ncheckpoint_every = 4\ndegree_every = 4\n\
    [train.densify]\nfrom_iteration = 2\nuntil_iteration = 10\nevery = 4\nopacity_reset_every = 0\n\
    [chunks]\nseconds = 0.34\noverlap_seconds = 0.07\n\
    [render]\nframes = 3\nvideo = false\n[eval]\nheldout_per_camera = 1\n[export]\nsteps = 1\nviewer = false\n";

#[test]
fn a_clip_in_three_chunks_trains_resumes_identically_and_renders_as_one() {
    let tmp = tempfile::tempdir().unwrap();
    let root = common::tiny_capture(&tmp.path().join("capture"), SETTINGS);
    let to_init = common::run_stages(
        &root,
        Selection {
            to: Some("init".into()),
            ..Default::default()
        },
    );
    assert!(to_init.failed.is_none(), "{to_init:?}");

    // Two moments in each chunk's own frames, in the middles of its halves: evenly spaced
    // over the clip, none a frame from another at a boundary.
    let init: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/init/init.json")).unwrap())
            .unwrap();
    let swept: Vec<u64> = init["sweeps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["frame"].as_u64().unwrap())
        .collect();
    assert_eq!(swept, [1, 3, 6, 8, 11, 13], "{init}");

    // A stop after the first iteration keeps the first chunk's checkpoint.
    interrupt::request_stop();
    let stopped = common::run_stages(&root, common::only("train", false));
    let (stage, error) = stopped.failed.expect("stopped");
    assert_eq!(stage, "train");
    assert!(
        error.contains("run the same `pipeline run` again"),
        "{error}"
    );
    assert!(root.join("work/.train.partial/chunks/000/ckpt").is_dir());
    assert!(!root.join("work/.train.partial/chunks/001").exists());

    let resumed = common::run_stages(&root, common::only("train", false));
    assert_eq!(resumed.ran, ["train"], "{resumed:?}");
    let train = root.join("work/train");
    let resumed_model = fs::read(train.join("model.bin")).unwrap();

    let record: ChunksRecord =
        serde_json::from_str(&fs::read_to_string(train.join("chunks.json")).unwrap()).unwrap();
    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    assert_eq!(index.frames.len(), 15);
    let config = pipeline::CaptureConfig::load(&root).unwrap();
    assert_eq!(record.plan, ChunkPlan::of_index(&index, &config.chunks));
    let windows: Vec<_> = record.chunks.iter().map(|c| c.window).collect();
    assert_eq!(windows, [(0, 6), (4, 11), (9, 15)]);
    let scene = splat4d::load_model(&train.join(STATIC_FILE)).unwrap();
    assert!(!scene.is_empty());
    assert_eq!(record.static_gaussians, scene.len());
    // The first chunk's still Gaussians, frozen, then 300 steps on the plates that train
    // only their opacities: every other parameter is the frozen one's.
    let shared: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(train.join("chunks/shared.json")).unwrap())
            .unwrap();
    let drift = shared["max_drift"].as_f64().unwrap();
    let first = splat4d::load_model(&train.join("chunks/000/model.bin")).unwrap();
    let times = record.chunks[0].times;
    let (still, _) = static_scene::split(&first, times, drift);
    let frozen = static_scene::freeze(&first, &still, 0.5 * (times.0 + times.1));
    assert_eq!(frozen.len(), scene.len());
    assert_eq!(frozen.means, scene.means);
    assert_eq!(frozen.log_scales, scene.log_scales);
    assert_eq!(frozen.rot_left, scene.rot_left);
    assert_eq!(frozen.colours, scene.colours);
    let changed = frozen
        .opacity_logits
        .iter()
        .zip(&scene.opacity_logits)
        .filter(|(a, b)| a != b)
        .count();
    assert!(
        changed > scene.len() / 2,
        "{changed} of {} opacities trained",
        scene.len()
    );
    let plate_log = fs::read_to_string(train.join("chunks/static/log.csv")).unwrap();
    assert!(
        plate_log.lines().last().unwrap().starts_with("300,"),
        "{plate_log}"
    );
    let model = splat4d::load_model(&train.join("model.bin")).unwrap();
    let kept: usize = record.chunks.iter().map(|c| c.kept).sum();
    assert_eq!(model.len(), scene.len() + kept);
    assert_eq!(model.means[..scene.len()], scene.means[..]);
    for c in &record.chunks {
        assert_eq!(c.iterations, 12, "{c:?}");
        assert!(c.kept > 0 && c.kept <= c.gaussians, "{c:?}");
        assert!(c.final_psnr.is_some_and(f64::is_finite), "{c:?}");
    }
    // The moving Gaussians, chunk by chunk, each within the time its chunk owns.
    let mut at = scene.len();
    for (c, chunk) in record.chunks.iter().zip(&record.plan.chunks) {
        for i in at..at + c.kept {
            assert!(chunk.owns_time(model.means[i][3] as f64), "{i} in {c:?}");
        }
        at += c.kept;
    }
    let log = fs::read_to_string(train.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 1 + 3 * 12);
    assert!(log.lines().last().unwrap().starts_with("36,"), "{log}");

    // An uninterrupted run trains exactly that model.
    let fresh = common::run_stages(&root, common::only("train", true));
    assert_eq!(fresh.ran, ["train"]);
    assert_eq!(fs::read(train.join("model.bin")).unwrap(), resumed_model);

    // The later chunks trained two at once (threads sharing the CPU, as lanes share GPUs)
    // give that model byte for byte: the setting is not a stage parameter.
    let toml = root.join("capture.toml");
    let text = fs::read_to_string(&toml).unwrap();
    fs::write(&toml, format!("{text}\n[engine]\nchunks_at_once = 2\n")).unwrap();
    let side_by_side = common::run_stages(&root, common::only("train", true));
    assert_eq!(side_by_side.ran, ["train"], "{side_by_side:?}");
    assert_eq!(fs::read(train.join("model.bin")).unwrap(), resumed_model);
    let up_to_date = common::run_stages(&root, common::only("train", false));
    assert!(up_to_date.ran.is_empty(), "{up_to_date:?}");

    // Render and eval draw the whole clip from the merged model.
    let rest = common::run_stages(&root, Selection::default());
    assert!(rest.failed.is_none(), "{rest:?}");
    let metrics: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/eval/metrics.json")).unwrap())
            .unwrap();
    eprintln!("{metrics}");
    assert!(root.join("work/render").is_dir());
}
