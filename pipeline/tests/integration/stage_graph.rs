//! The real pipeline's stage declarations: every capture file a stage reads is one of its
//! inputs (so replacing it reruns the stage), and every stage declares the outputs that
//! prove it ran. The stages' work is replaced here by a stand-in that writes the declared
//! outputs, so these tests run no ffmpeg, COLMAP or training.

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};

use common::make_capture;
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::{Pipeline, RunSummary, Selection, State};
use pipeline::stage_def::StageDef;
use pipeline::{open_capture, stages};

/// The real stage `name`, its upstream stages dropped and its work replaced by writing
/// the first alternative of each declared output.
fn stand_in(name: &str) -> StageDef {
    let mut stage = stages::pipeline()
        .stages
        .into_iter()
        .find(|s| s.name == name)
        .expect("a stage of the pipeline");
    stage.after.clear();
    let outputs = stage.outputs.clone();
    stage.run = Some(Box::new(move |ctx, _| {
        for output in &outputs {
            let first = output.any_of[0];
            let path = match first.strip_suffix('/') {
                Some(folder) => ctx.output(folder).join("000000.png"),
                None => ctx.output(first),
            };
            fs::create_dir_all(path.parent().unwrap())?;
            fs::write(path, "stand-in")?;
        }
        Ok(())
    }));
    stage
}

fn run(pipeline: &Pipeline, root: &Path) -> RunSummary {
    let (capture, config) = open_capture(root).unwrap();
    pipeline
        .run(
            &capture,
            &config,
            &Selection::default(),
            &Reporter::new(OutputMode::Quiet),
        )
        .unwrap()
}

/// The state and details `status` shows for the first stage.
fn status(pipeline: &Pipeline, root: &Path) -> (State, Vec<String>) {
    let (capture, config) = open_capture(root).unwrap();
    let row = pipeline.status(&capture, &config).unwrap().remove(0);
    (row.state, row.details)
}

fn write(root: &Path, file: &str, bytes: &[u8]) {
    let path = root.join(file);
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    fs::write(path, bytes).unwrap();
}

/// A capture of 4 cameras with `capture.toml` = `settings` and the extra `files`
/// (capture-relative path, contents).
fn capture_with(settings: &str, files: &[(&str, &[u8])]) -> tempfile::TempDir {
    let tmp = tempfile::tempdir().unwrap();
    make_capture(tmp.path(), 4, 0);
    write(tmp.path(), "capture.toml", settings.as_bytes());
    for (file, bytes) in files {
        write(tmp.path(), file, bytes);
    }
    tmp
}

/// Bring `stage` up to date, write `file` (capture-relative) anew with `bytes`, and check
/// that `status` names the change and the next run reruns the stage.
fn rewriting_reruns(root: &Path, stage: &str, file: &str, bytes: &[u8]) {
    let p = Pipeline {
        stages: vec![stand_in(stage)],
    };
    let first = run(&p, root);
    assert!(first.failed.is_none(), "{first:?}");
    assert_eq!(run(&p, root).skipped, [stage], "unchanged: up to date");
    write(root, file, bytes);
    let (state, details) = status(&p, root);
    assert_eq!(state, State::Stale, "{details:?}");
    assert!(
        details.iter().any(|d| d.contains(&format!("input {file}"))),
        "{details:?}"
    );
    assert_eq!(run(&p, root).ran, [stage]);
}

#[test]
fn replacing_the_init_model_reruns_init() {
    let model = "models/mast3r.onnx";
    let tmp = capture_with(
        "[init]\nmodel = \"models/mast3r.onnx\"\n",
        &[(model, b"onnx weights v1")],
    );
    rewriting_reruns(tmp.path(), "init", model, b"onnx weights v2, retrained");
}

#[test]
fn replacing_or_adding_a_point_map_reruns_init() {
    let tmp = capture_with(
        "[init]\npointmaps = \"maps\"\n",
        &[("maps/cam0__cam1.npz", b"maps v1")],
    );
    rewriting_reruns(tmp.path(), "init", "maps/cam0__cam1.npz", b"maps v2");
    rewriting_reruns(tmp.path(), "init", "maps/cam1__cam2.npz", b"a new pair");
}

#[test]
fn replacing_the_lpips_weights_reruns_eval() {
    let tmp = capture_with(
        "[eval]\nlpips = \"lpips.onnx\"\n",
        &[("lpips.onnx", b"alex v0.1")],
    );
    rewriting_reruns(tmp.path(), "eval", "lpips.onnx", b"vgg v0.1");
}

#[test]
fn a_render_stage_that_writes_nothing_fails() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 0);
    let mut render = stand_in("render");
    render.run = Some(Box::new(|_, _| Ok(())));
    let p = Pipeline {
        stages: vec![render],
    };
    let (stage, error) = run(&p, &root).failed.expect("a render that wrote nothing");
    assert_eq!(stage, "render");
    assert!(
        error.contains("without writing render.mp4 or a file in rgb/"),
        "{error}"
    );
    assert!(!root.join("work/render").exists());
    // An empty frames folder proves nothing either; one frame does.
    let mut render = stand_in("render");
    render.run = Some(Box::new(|ctx, _| {
        Ok(fs::create_dir_all(ctx.output("rgb"))?)
    }));
    let p = Pipeline {
        stages: vec![render],
    };
    assert!(run(&p, &root).failed.is_some());
    let p = Pipeline {
        stages: vec![stand_in("render")],
    };
    assert_eq!(run(&p, &root).ran, ["render"]);
}

#[test]
fn every_stage_declares_the_outputs_that_prove_it_ran() {
    for stage in stages::pipeline().stages {
        assert!(
            !stage.outputs.is_empty(),
            "{} declares no required output",
            stage.name
        );
    }
}

#[test]
fn every_capture_file_a_stage_reads_is_an_input() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 5, 2);
    fs::write(
        root.join("capture.toml"),
        "[capture]\nheldout = [\"cam4\"]\n[init]\nmodel = \"m.onnx\"\npointmaps = \"/abs/maps\"\n\
         [eval]\nlpips = \"w/lpips.onnx\"\n[poses]\nintrinsics = \"lenses/lens.yaml\"\n",
    )
    .unwrap();
    write(&root, "calibration.json", b"{}");
    let (capture, config) = open_capture(&root).unwrap();
    let inputs = |name: &str| -> Vec<PathBuf> {
        let p = stages::pipeline();
        let stage = p.stages.iter().find(|s| s.name == name).unwrap();
        (stage.inputs)(&capture, &config)
    };
    let video = |cam: &str| root.join("raw").join(cam).join("GX010001.MP4");
    for stage in ["ingest", "sync", "frames"] {
        for cam in ["cam0", "cam3", "cam4"] {
            assert!(inputs(stage).contains(&video(cam)), "{stage} lacks {cam}");
        }
    }
    let poses = inputs("poses");
    assert!(
        poses.contains(&root.join("stills/still_01.jpg")),
        "{poses:?}"
    );
    assert!(poses.contains(&root.join("calibration.json")), "{poses:?}");
    assert!(poses.contains(&root.join("lenses/lens.yaml")), "{poses:?}");
    assert_eq!(
        inputs("init"),
        [root.join("m.onnx"), PathBuf::from("/abs/maps")]
    );
    let eval = inputs("eval");
    assert!(eval.contains(&root.join("groundtruth")), "{eval:?}");
    assert!(eval.contains(&root.join("masks")), "{eval:?}");
    assert!(eval.contains(&root.join("w/lpips.onnx")), "{eval:?}");
    for stage in ["train", "render", "export"] {
        assert!(
            inputs(stage).is_empty(),
            "{stage} reads only upstream stages"
        );
    }
}
