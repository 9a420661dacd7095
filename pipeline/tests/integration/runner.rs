//! The stage engine: skip when unchanged, rerun on a parameter/input change and
//! downstream, atomic outputs on failure, `status` states and reasons, the lock.

use crate::common;

use std::fs;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::Context;
use common::make_capture;
use pipeline::config::CaptureConfig;
use pipeline::lock::CaptureLock;
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::{Pipeline, Selection, State};
use pipeline::stage_def::StageDef;
use pipeline::{Capture, open_capture};

/// Counts of how often each fake stage ran, and a switch to make `b` fail midway.
#[derive(Default)]
struct Probe {
    a: AtomicUsize,
    b: AtomicUsize,
    c: AtomicUsize,
    fail_b: AtomicBool,
}

/// a reads raw/cam0's video and a parameter; b reads a's output; c reads b's output.
fn fake_pipeline(probe: Arc<Probe>) -> Pipeline {
    let (pa, pb, pc) = (probe.clone(), probe.clone(), probe);
    Pipeline {
        stages: vec![
            StageDef::new("a", "first")
                .inputs(|c: &Capture, _: &CaptureConfig| c.cameras[0].videos.clone())
                .params(|_| serde_json::json!({"scale": std::env::var("UNUSED").ok()}))
                .outputs(&["a.txt"])
                .run(move |ctx, config| {
                    pa.a.fetch_add(1, Ordering::SeqCst);
                    let video = fs::read(&ctx.capture.cameras[0].videos[0])?;
                    let scale = config.capture.cameras;
                    fs::write(
                        ctx.output("a.txt"),
                        format!("{} bytes, {scale} cameras", video.len()),
                    )?;
                    Ok(())
                }),
            StageDef::new("b", "second")
                .after(&["a"])
                .outputs(&["b.txt"])
                .run(move |ctx, _| {
                    pb.b.fetch_add(1, Ordering::SeqCst);
                    let a = fs::read_to_string(ctx.stage_dir("a").join("a.txt"))
                        .context("reading a.txt")?;
                    fs::create_dir_all(ctx.output("sub"))?;
                    fs::write(ctx.output("sub/part.txt"), "half")?;
                    if pb.fail_b.load(Ordering::SeqCst) {
                        anyhow::bail!("simulated failure midway");
                    }
                    fs::write(ctx.output("b.txt"), format!("b of [{a}]"))?;
                    Ok(())
                }),
            StageDef::new("c", "third")
                .after(&["b"])
                .outputs(&["c.txt"])
                .run(move |ctx, _| {
                    pc.c.fetch_add(1, Ordering::SeqCst);
                    let b = fs::read_to_string(ctx.stage_dir("b").join("b.txt"))?;
                    fs::write(ctx.output("c.txt"), b.to_uppercase())?;
                    Ok(())
                }),
            StageDef::new("d", "not written yet").after(&["c"]),
        ],
    }
}

fn counts(p: &Probe) -> (usize, usize, usize) {
    (
        p.a.load(Ordering::SeqCst),
        p.b.load(Ordering::SeqCst),
        p.c.load(Ordering::SeqCst),
    )
}

fn setup() -> (tempfile::TempDir, Arc<Probe>, Pipeline) {
    let tmp = tempfile::tempdir().unwrap();
    make_capture(tmp.path(), 4, 0);
    let probe = Arc::new(Probe::default());
    let pipeline = fake_pipeline(probe.clone());
    (tmp, probe, pipeline)
}

fn run(pipeline: &Pipeline, root: &Path, sel: Selection) -> pipeline::runner::RunSummary {
    let (capture, config) = open_capture(root).unwrap();
    pipeline
        .run(&capture, &config, &sel, &Reporter::new(OutputMode::Quiet))
        .unwrap()
}

fn states(pipeline: &Pipeline, root: &Path) -> Vec<(String, State, Vec<String>)> {
    let (capture, config) = open_capture(root).unwrap();
    pipeline
        .status(&capture, &config)
        .unwrap()
        .into_iter()
        .map(|r| (r.stage, r.state, r.details))
        .collect()
}

fn upto(stage: &str) -> Selection {
    Selection {
        to: Some(stage.into()),
        ..Default::default()
    }
}

#[test]
fn runs_in_order_then_skips_when_unchanged() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    assert!(
        states(&p, root)
            .iter()
            .all(|(_, s, _)| *s == State::Missing)
    );
    let summary = run(&p, root, upto("c"));
    assert_eq!(summary.ran, ["a", "b", "c"]);
    assert!(summary.complete());
    assert_eq!(
        fs::read_to_string(root.join("work/c/c.txt")).unwrap(),
        "B OF [32 BYTES, 4 CAMERAS]"
    );
    let manifest: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/b/stage.json")).unwrap()).unwrap();
    assert_eq!(manifest["stage"], "b");
    assert!(manifest["inputs"]["stage:a"]["hash"].is_string());
    assert!(manifest["outputs"]["sub/part.txt"]["hash"].is_string());
    assert!(manifest["tool_versions"]["pipeline"].is_string());
    assert!(manifest["duration_s"].as_f64().unwrap() >= 0.0);

    let again = run(&p, root, upto("c"));
    assert_eq!(again.skipped, ["a", "b", "c"]);
    assert_eq!(counts(&probe), (1, 1, 1));
    let st = states(&p, root);
    assert_eq!(st[0].1, State::Done);
    assert_eq!(st[2].1, State::Done);
    assert_eq!(st[3].1, State::Missing);
    assert!(st[3].2.iter().any(|d| d.contains("not implemented")));
}

#[test]
fn an_input_change_reruns_the_stage_and_everything_downstream() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    fs::write(
        root.join("raw/cam0/GX010001.MP4"),
        [common::MP4_HEADER, b"new footage!"].concat(),
    )
    .unwrap();
    let st = states(&p, root);
    assert_eq!(st[0].1, State::Stale);
    assert!(
        st[0]
            .2
            .iter()
            .any(|d| d.contains("input raw/cam0/GX010001.MP4 changed")),
        "{:?}",
        st[0].2
    );
    assert_eq!(st[1].1, State::Stale);
    assert!(
        st[1].2.iter().any(|d| d.contains("upstream `a` is stale")),
        "{:?}",
        st[1].2
    );
    assert_eq!(st[2].1, State::Stale);
    let summary = run(&p, root, upto("c"));
    assert_eq!(summary.ran, ["a", "b", "c"]);
    assert_eq!(counts(&probe), (2, 2, 2));
    assert!(
        fs::read_to_string(root.join("work/c/c.txt"))
            .unwrap()
            .contains("36 BYTES")
    );
}

#[test]
fn an_input_of_another_camera_does_not_rerun_a() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    // Same size, new mtime and content: hashed again, and still unchanged for `a`.
    fs::write(
        root.join("raw/cam1/GX010001.MP4"),
        [common::MP4_HEADER, b"camera 9"].concat(),
    )
    .unwrap();
    assert_eq!(run(&p, root, upto("c")).skipped, ["a", "b", "c"]);
    assert_eq!(counts(&probe), (1, 1, 1));
}

#[test]
fn a_parameter_change_is_named_and_reruns_downstream() {
    let (tmp, probe, _) = setup();
    let root = tmp.path();
    // A pipeline whose stage `a` takes the capture section as parameters.
    let mut p = fake_pipeline(probe.clone());
    p.stages[0].params = Box::new(|c: &CaptureConfig| c.section("capture"));
    run(&p, root, upto("c"));
    // Add a fifth camera and tell capture.toml about it: `a`'s parameter changes.
    make_capture(root, 5, 0);
    fs::write(root.join("capture.toml"), "[capture]\ncameras = 5\n").unwrap();
    let st = states(&p, root);
    assert_eq!(st[0].1, State::Stale);
    assert!(
        st[0]
            .2
            .iter()
            .any(|d| d == "parameter a.cameras changed: 4 → 5"),
        "{:?}",
        st[0].2
    );
    let summary = run(&p, root, upto("c"));
    assert_eq!(
        summary.ran,
        ["a", "b", "c"],
        "a's output changed, so b and c rerun"
    );
    assert_eq!(counts(&probe), (2, 2, 2));
}

#[test]
fn force_and_only_select_stages() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    let s = run(
        &p,
        root,
        Selection {
            only: Some("b".into()),
            force: true,
            ..Default::default()
        },
    );
    assert_eq!(s.ran, ["b"]);
    assert_eq!(counts(&probe), (1, 2, 1));
    // b's outputs are identical, so c (which reads them) is still up to date.
    let s = run(
        &p,
        root,
        Selection {
            from: Some("b".into()),
            to: Some("c".into()),
            ..Default::default()
        },
    );
    assert_eq!(s.skipped, ["b", "c"]);
}

#[test]
fn a_stage_needing_an_unrun_upstream_says_what_to_run() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    let s = run(
        &p,
        root,
        Selection {
            only: Some("c".into()),
            ..Default::default()
        },
    );
    let (stage, error) = s.failed.unwrap();
    assert_eq!(stage, "c");
    assert!(
        error.contains("`b`, which has not run") && error.contains("--to b"),
        "{error}"
    );
    assert_eq!(counts(&probe), (0, 0, 0));
}

#[test]
fn unimplemented_stages_are_reported_and_block_downstream_only() {
    let (tmp, _probe, p) = setup();
    let s = run(&p, tmp.path(), Selection::default());
    assert_eq!(s.ran, ["a", "b", "c"]);
    assert_eq!(s.not_implemented, ["d"]);
    assert!(!s.complete());
}

#[test]
fn a_failure_midway_keeps_the_previous_outputs() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    let good_b = fs::read_to_string(root.join("work/b/b.txt")).unwrap();
    let good_manifest = fs::read_to_string(root.join("work/b/stage.json")).unwrap();

    probe.fail_b.store(true, Ordering::SeqCst);
    let s = run(
        &p,
        root,
        Selection {
            force: true,
            ..upto("c")
        },
    );
    assert_eq!(s.failed.as_ref().unwrap().0, "b");
    assert!(
        s.failed
            .as_ref()
            .unwrap()
            .1
            .contains("simulated failure midway")
    );
    assert_eq!(s.ran, ["a"]);
    assert_eq!(counts(&probe), (2, 2, 1), "c must not run after b failed");
    // The old, complete outputs are untouched and no half-written folder looks finished.
    assert_eq!(
        fs::read_to_string(root.join("work/b/b.txt")).unwrap(),
        good_b
    );
    assert_eq!(
        fs::read_to_string(root.join("work/b/stage.json")).unwrap(),
        good_manifest
    );
    assert!(!root.join("work/.b.partial").exists());
    let st = states(&p, root);
    assert_eq!(st[1].1, State::Failed);
    assert!(
        st[1].2[0].contains("simulated failure midway")
            && st[1].2[0].contains("previous outputs are kept")
    );

    // Fixed: the next run reruns b (its failure record is cleared) and c is up to date
    // again because b's outputs are identical.
    probe.fail_b.store(false, Ordering::SeqCst);
    let s = run(&p, root, upto("c"));
    assert_eq!(s.skipped, ["a", "b", "c"]);
    assert_eq!(states(&p, root)[1].1, State::Done);
}

#[test]
fn a_failure_on_first_run_leaves_nothing_that_looks_finished() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    probe.fail_b.store(true, Ordering::SeqCst);
    let s = run(&p, root, upto("c"));
    assert_eq!(s.failed.unwrap().0, "b");
    assert!(!root.join("work/b").exists());
    assert_eq!(states(&p, root)[1].1, State::Failed);
}

#[test]
fn a_missing_output_makes_the_stage_stale() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    fs::remove_file(root.join("work/b/sub/part.txt")).unwrap();
    let st = states(&p, root);
    assert_eq!(st[1].1, State::Stale);
    assert!(
        st[1]
            .2
            .iter()
            .any(|d| d.contains("output sub/part.txt is missing"))
    );
    run(&p, root, upto("c"));
    assert_eq!(counts(&probe), (1, 2, 1));
    assert!(root.join("work/b/sub/part.txt").exists());
}

#[test]
fn an_interrupted_run_shows_as_failed() {
    let (tmp, _probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    // What a killed process leaves behind: a "running" record and no lock holder.
    let record = pipeline::manifest::RunRecord {
        state: pipeline::manifest::RunState::Running,
        pid: 999_999,
        started: chrono::Utc::now(),
        error: None,
        duration_s: None,
    };
    record.write(&root.join("work"), "c").unwrap();
    let st = states(&p, root);
    assert_eq!(st[2].1, State::Failed);
    assert!(st[2].2[0].contains("interrupted"), "{:?}", st[2].2);
}

#[test]
fn an_interrupted_swap_is_recovered() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    run(&p, root, upto("c"));
    // Killed between moving the old outputs aside and moving the new ones in.
    fs::rename(root.join("work/b"), root.join("work/.b.old")).unwrap();
    let s = run(&p, root, upto("c"));
    assert_eq!(s.skipped, ["a", "b", "c"], "the old outputs are put back");
    assert_eq!(counts(&probe), (1, 1, 1));
    assert!(!root.join("work/.b.old").exists());
}

#[test]
fn a_second_run_on_the_same_capture_is_refused() {
    let (tmp, probe, p) = setup();
    let root = tmp.path();
    let (capture, config) = open_capture(root).unwrap();
    let held = CaptureLock::acquire(&capture.work_dir()).unwrap();
    assert!(CaptureLock::is_held(&capture.work_dir()));
    let err = p
        .run(
            &capture,
            &config,
            &Selection::default(),
            &Reporter::new(OutputMode::Quiet),
        )
        .unwrap_err();
    let msg = format!("{err:#}");
    assert!(
        msg.contains("locked by another `pipeline` run")
            && msg.contains(&format!(
                "pid {} on {}",
                std::process::id(),
                std::fs::read_to_string("/proc/sys/kernel/hostname")
                    .unwrap()
                    .trim()
            )),
        "{msg}"
    );
    assert_eq!(counts(&probe), (0, 0, 0));
    drop(held);
    assert!(!CaptureLock::is_held(&capture.work_dir()));
    assert_eq!(run(&p, root, upto("c")).ran, ["a", "b", "c"]);
}

#[test]
fn a_panicking_stage_is_recorded_as_failed() {
    let tmp = tempfile::tempdir().unwrap();
    make_capture(tmp.path(), 4, 0);
    let p = Pipeline {
        stages: vec![StageDef::new("boom", "panics").run(|_, _| panic!("bug in stage"))],
    };
    let s = run(&p, tmp.path(), Selection::default());
    assert!(s.failed.unwrap().1.contains("bug in stage"));
    assert_eq!(states(&p, tmp.path())[0].1, State::Failed);
}

#[test]
fn a_stage_that_forgets_an_output_fails() {
    let tmp = tempfile::tempdir().unwrap();
    make_capture(tmp.path(), 4, 0);
    let p = Pipeline {
        stages: vec![
            StageDef::new("lazy", "writes nothing")
                .outputs(&["result.json"])
                .run(|_, _| Ok(())),
        ],
    };
    let s = run(&p, tmp.path(), Selection::default());
    assert!(s.failed.unwrap().1.contains("without writing result.json"));
    assert!(!tmp.path().join("work/lazy").exists());
}

/// A resumable stage that counts in `progress.txt`, failing once it has counted to 2 unless
/// `done` is set; it records whether the runner told it to resume.
fn resumable_pipeline(done: Arc<AtomicBool>, resumed: Arc<AtomicUsize>) -> Pipeline {
    Pipeline {
        stages: vec![
            StageDef::new("t", "resumable")
                .params(|c| serde_json::json!({"cameras": c.capture.cameras}))
                .outputs(&["model.txt"])
                .resumable()
                .run(move |ctx, _| {
                    let path = ctx.output("progress.txt");
                    let count: u32 = fs::read_to_string(&path)
                        .ok()
                        .and_then(|s| s.parse().ok())
                        .unwrap_or(0);
                    if ctx.resume {
                        resumed.fetch_add(1, Ordering::SeqCst);
                    }
                    fs::write(&path, (count + 1).to_string())?;
                    if !done.load(Ordering::SeqCst) {
                        anyhow::bail!("interrupted at {}", count + 1);
                    }
                    fs::write(ctx.output("model.txt"), format!("after {}", count + 1))?;
                    Ok(())
                }),
        ],
    }
}

#[test]
fn a_resumable_stage_continues_only_the_same_run() {
    let tmp = tempfile::tempdir().unwrap();
    make_capture(tmp.path(), 4, 0);
    let (done, resumed) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicUsize::new(0)),
    );
    let p = resumable_pipeline(done.clone(), resumed.clone());
    let partial = tmp.path().join("work/.t.partial/progress.txt");

    // Two interrupted attempts with the same settings: the second continues the first.
    assert!(run(&p, tmp.path(), Selection::default()).failed.is_some());
    assert!(run(&p, tmp.path(), Selection::default()).failed.is_some());
    assert_eq!(fs::read_to_string(&partial).unwrap(), "2");
    assert_eq!(resumed.load(Ordering::SeqCst), 1);

    // Changed settings: the old partial work is discarded.
    fs::write(tmp.path().join("capture.toml"), "[capture]\ncameras = 4\n").unwrap();
    let config = CaptureConfig::load(tmp.path()).unwrap();
    assert_eq!(config.capture.cameras, 4, "same value: same parameters");
    assert!(run(&p, tmp.path(), Selection::default()).failed.is_some());
    assert_eq!(fs::read_to_string(&partial).unwrap(), "3");
    make_capture_with_cameras(tmp.path(), 3);
    assert!(run(&p, tmp.path(), Selection::default()).failed.is_some());
    assert_eq!(
        fs::read_to_string(&partial).unwrap(),
        "1",
        "new parameters start over"
    );

    // --force starts over too; a finished run leaves no resume marker behind.
    done.store(true, Ordering::SeqCst);
    let force = Selection {
        force: true,
        ..Default::default()
    };
    let before = resumed.load(Ordering::SeqCst);
    assert!(run(&p, tmp.path(), force).failed.is_none());
    assert_eq!(resumed.load(Ordering::SeqCst), before);
    let out = tmp.path().join("work/t");
    assert_eq!(
        fs::read_to_string(out.join("model.txt")).unwrap(),
        "after 1"
    );
    assert!(!out.join(".resume-key").exists());
    assert!(!tmp.path().join("work/.t.partial").exists());
}

/// Keep the capture's folders but declare `cameras` of them in capture.toml.
fn make_capture_with_cameras(root: &Path, cameras: usize) {
    fs::remove_dir_all(root.join("raw/cam3")).unwrap();
    fs::write(
        root.join("capture.toml"),
        format!("[capture]\ncameras = {cameras}\n"),
    )
    .unwrap();
}
