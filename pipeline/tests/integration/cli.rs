//! Command-line parsing and the binary's behaviour on a valid capture.

use crate::common;

use std::process::Command;

use clap::Parser;
use common::make_capture;
use pipeline::cli::{Cli, Command as Cmd};

fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
    Cli::try_parse_from(std::iter::once("pipeline").chain(args.iter().copied()))
}

#[test]
fn run_takes_a_stage_range() {
    let cli = parse(&[
        "run", "cap", "--from", "sync", "--to", "train", "--force", "-v",
    ])
    .unwrap();
    assert_eq!(cli.verbose, 1);
    let Cmd::Run(args) = cli.command else {
        panic!("expected run")
    };
    assert_eq!(args.capture_dir.to_str(), Some("cap"));
    assert_eq!(args.stages.from.as_deref(), Some("sync"));
    assert_eq!(args.stages.to.as_deref(), Some("train"));
    assert!(args.stages.force);
}

#[test]
fn unknown_stages_and_conflicting_flags_are_rejected() {
    let err = parse(&["run", "cap", "--only", "trian"])
        .unwrap_err()
        .to_string();
    assert!(err.contains("trian") && err.contains("train"), "{err}");
    assert!(parse(&["run", "cap", "--only", "train", "--from", "sync"]).is_err());
    assert!(parse(&["--quiet", "--json", "status", "cap"]).is_err());
    assert!(
        parse(&["run"]).is_err(),
        "the capture directory is required"
    );
}

#[test]
fn submit_takes_several_captures_and_a_stage_range() {
    let cli = parse(&["submit", "a", "b", "--to", "train", "--backend", "cpu"]).unwrap();
    let Cmd::Submit(args) = cli.command else {
        panic!("expected submit")
    };
    assert_eq!(args.capture_dirs.len(), 2);
    assert_eq!(args.stages.to.as_deref(), Some("train"));
    assert!(
        parse(&["submit"]).is_err(),
        "a capture directory is required"
    );
    assert!(parse(&["submit", "a", "--only", "trian"]).is_err());
    assert!(matches!(
        parse(&["cancel", "a"]).unwrap().command,
        Cmd::Cancel { .. }
    ));
}

/// Without Slurm's commands on PATH, `submit` names the first missing one (`sinfo`, read
/// before anything is queued) and submits nothing; `status` still prints its table.
#[test]
fn submit_without_slurm_says_what_is_missing() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(&tmp.path().join("cap"), 4, 8);
    let empty = tmp.path().join("no-tools");
    std::fs::create_dir_all(&empty).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["submit", "--to", "sync"])
        .arg(&root)
        .env("PATH", &empty)
        .env("PIPELINE_CLUSTER_CONFIG", tmp.path().join("none.toml"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("`sinfo` was not found") && err.contains("login node"),
        "{err}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("status")
        .arg(&root)
        .env("PATH", &empty)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("STAGE"));
}

#[test]
fn demo_has_a_default_output_directory() {
    let Cmd::Demo {
        out_dir,
        backend,
        preset,
        to,
    } = parse(&["demo"]).unwrap().command
    else {
        panic!()
    };
    assert_eq!(out_dir.to_str(), Some("4c4d-demo"));
    assert_eq!(backend, None, "no --backend: capture.toml decides");
    assert_eq!(preset, None, "no --preset: capture.toml decides");
    assert_eq!(to, None, "no --to: every stage");
    let Cmd::Demo {
        out_dir,
        backend,
        preset,
        to,
    } = parse(&[
        "--json",
        "demo",
        "/tmp/x",
        "--backend",
        "cpu",
        "--preset",
        "preview",
        "--to",
        "init",
    ])
    .unwrap()
    .command
    else {
        panic!()
    };
    assert_eq!(out_dir.to_str(), Some("/tmp/x"));
    assert_eq!(backend, Some(pipeline::engine_inputs::BackendChoice::Cpu));
    assert_eq!(preset, Some(pipeline::presets::Preset::Preview));
    assert_eq!(to.as_deref(), Some("init"));
    assert!(
        parse(&["demo", "--to", "training"]).is_err(),
        "an unknown stage is refused"
    );
    assert!(parse(&["run", "x", "--preset", "fastest"]).is_err());
    assert!(
        parse(&["demo", "--backend", "cuda"]).is_err(),
        "an unknown backend is refused"
    );
}

#[test]
fn demo_stops_after_the_stage_given_by_to_and_reuses_its_capture() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("demo");
    let demo = |to: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
            .arg("demo")
            .arg(&dir)
            .args(["--to", to])
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "demo --to {to} failed:\n{said}");
        said
    };
    let first = demo("ingest");
    assert!(first.contains("simulating the demo capture"), "{first}");
    assert!(dir.join("work/ingest/stage.json").is_file());
    for later in ["sync", "frames", "init", "train"] {
        assert!(
            !dir.join("work").join(later).exists(),
            "{later} ran: {first}"
        );
    }
    assert!(
        !dir.join("pointmaps").exists(),
        "the init's point maps are written only when the demo goes as far as init"
    );
    let second = demo("sync");
    assert!(second.contains("reusing the simulated capture"), "{second}");
    assert!(second.contains("1 ran, 1 up to date"), "{second}");
    assert!(dir.join("work/sync/stage.json").is_file());
    assert!(!dir.join("work/frames").exists(), "{second}");
}

#[test]
fn help_explains_the_commands() {
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("--help")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    for word in ["run", "status", "demo", "ingest → sync → frames"] {
        assert!(text.contains(word), "--help lacks {word}: {text}");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["run", "--help"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("raw/cam0/") && text.contains("--from") && text.contains("Example"),
        "{text}"
    );
}

#[test]
fn json_mode_prints_one_event_per_line() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["--json", "run"])
        .arg(&root)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let events: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("each line is JSON"))
        .collect();
    assert!(!events.is_empty());
    let last = events.last().unwrap();
    assert_eq!(last["event"], "run_finished");
    // Every stage is accounted for, one way or another.
    let summary = &last["summary"];
    let accounted = ["ran", "skipped", "not_implemented", "blocked"]
        .iter()
        .map(|k| summary[k].as_array().map_or(0, |a| a.len()))
        .sum::<usize>()
        + usize::from(!summary["failed"].is_null());
    assert_eq!(
        accounted,
        pipeline::stages::pipeline().stage_names().len(),
        "{summary}"
    );
}

#[test]
fn status_prints_a_table_of_every_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("status")
        .arg(&root)
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("STAGE") && text.contains("STATE") && text.contains("DETAILS"),
        "{text}"
    );
    for stage in pipeline::stages::pipeline().stage_names() {
        assert!(
            text.lines().any(|l| l.starts_with(stage)),
            "no row for {stage}: {text}"
        );
    }
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["--json", "status"])
        .arg(&root)
        .output()
        .unwrap();
    let rows: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        rows.as_array().unwrap().len(),
        pipeline::stages::pipeline().stage_names().len()
    );
    let first = text.lines().next().unwrap_or_default().to_string();
    assert!(first.ends_with("(4 cameras, 8 stills)"), "{first}");

    // A fifth camera listed as held-out is counted apart from the training cameras.
    let root = make_capture(tmp.path(), 5, 8);
    std::fs::write(
        root.join("capture.toml"),
        "[capture]\nheldout = [\"cam4\"]\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("status")
        .arg(&root)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(
        text.lines()
            .next()
            .unwrap_or_default()
            .ends_with("(4 cameras, 1 held-out: cam4, 8 stills)"),
        "{text}"
    );
    assert_eq!(rows[0]["state"], "missing");
}

#[test]
fn record_without_devices_fails_cleanly() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("rec");
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["record", "--seconds", "1"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("V4L2") || err.contains("/dev/video"), "{err}");
    assert!(
        !dir.join("raw").exists(),
        "nothing recorded, nothing written"
    );
}

#[test]
fn record_through_nokhwa_fails_cleanly_without_the_feature_or_a_camera() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("rec");
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args([
            "record",
            "--backend",
            "nokhwa",
            "--device",
            "0",
            "--seconds",
            "1",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    if cfg!(feature = "nokhwa") {
        if out.status.success() {
            return; // a machine with a webcam recorded from it
        }
        assert!(
            err.contains("no camera #0") && err.contains("--list"),
            "{err}"
        );
    } else {
        assert!(!out.status.success());
        assert!(
            err.contains("cargo build --release -p pipeline --features nokhwa"),
            "{err}"
        );
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        !dir.join("raw").exists(),
        "nothing recorded, nothing written"
    );
}

#[test]
fn record_lists_the_cameras_of_a_backend() {
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["record", "--backend", "v4l2", "--list"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["record", "--backend", "nokhwa", "--list"])
        .output()
        .unwrap();
    assert_eq!(out.status.success(), cfg!(feature = "nokhwa"));
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["record", "--seconds", "1"])
        .output()
        .unwrap();
    assert!(!out.status.success(), "a capture directory is required");
}

#[test]
fn presets_are_announced_and_keys_they_set_are_refused_beside_them() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("run")
        .arg(&root)
        .args(["--preset", "preview", "--only", "ingest"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let v = pipeline::presets::Preset::Preview.values();
    assert!(
        stderr.contains(&format!("preset preview: {} iterations", v.iterations)),
        "{stderr}"
    );
    std::fs::write(
        root.join("capture.toml"),
        "[train]\npreset = \"best\"\niterations = 5\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("status")
        .arg(&root)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("remove `iterations` or the preset") && stderr.contains("capture.toml"),
        "{stderr}"
    );
}

/// The LPIPS repository's example images (fixtures/lpips).
fn lpips_example(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures/lpips")
        .join(name)
}

/// Whether LPIPS weights are installed; a panic under `CI=true` when they are not
/// (scripts/setup.sh installs them).
fn lpips_weights_installed() -> bool {
    match splat4d::metrics::lpips::find_weights() {
        Ok(Some(_)) => true,
        _ if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") => panic!(
            "no LPIPS weights under CI=true: {}",
            splat4d::metrics::lpips::INSTALL_HINT
        ),
        _ => {
            eprintln!("LPIPS weights are not installed: only the other metrics are checked");
            false
        }
    }
}

#[test]
fn metrics_compares_two_images_or_two_folders() {
    let weights = lpips_weights_installed();
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["--json", "metrics"])
        .arg(lpips_example("ex_ref.png"))
        .arg(lpips_example("ex_p0.png"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let events: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("each line is JSON"))
        .collect();
    let pair = events.iter().find(|e| e["event"] == "metrics").unwrap();
    assert_eq!(
        (pair["width"].as_u64(), pair["height"].as_u64()),
        (Some(64), Some(64))
    );
    let psnr = pair["psnr"].as_f64().unwrap();
    assert!(psnr > 5.0 && psnr < 40.0, "{psnr}");
    if weights {
        let lpips = pair["lpips"].as_f64().unwrap();
        assert!((lpips - 0.722).abs() <= 0.001, "{lpips}");
    } else {
        assert!(pair["lpips"].is_null());
    }

    // Two folders: pairs by name without extension, the rest left out and said so.
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("renders"), tmp.path().join("truth"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    for (src, dst) in [
        ("ex_p0.png", a.join("0001.png")),
        ("ex_p1.png", a.join("0002.png")),
        ("ex_p1.png", a.join("0003.png")),
        ("ex_ref.png", b.join("0001.png")),
        ("ex_ref.png", b.join("0002.png")),
    ] {
        std::fs::copy(lpips_example(src), dst).unwrap();
    }
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("metrics")
        .arg(&a)
        .arg(&b)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(
        stdout.contains("0001.png") && stdout.contains("0002.png"),
        "{stdout}"
    );
    assert!(stdout.contains("mean of 2"), "{stdout}");
    assert!(
        stderr.contains("1 image(s) only in") && stderr.contains("0003.png"),
        "{stderr}"
    );
    if weights {
        assert!(
            stdout.contains("0.72") && stdout.contains("0.13"),
            "{stdout}"
        );
    } else {
        assert!(
            stdout.contains("skipped") && stderr.contains("scripts/setup.sh"),
            "{stderr}"
        );
    }
}

#[test]
fn metrics_mistakes_name_the_path_and_the_fix() {
    let tmp = tempfile::tempdir().unwrap();
    let small = tmp.path().join("small.png");
    image::RgbImage::new(32, 20).save(&small).unwrap();
    let metrics = |a: &std::path::Path, b: &std::path::Path| {
        let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
            .arg("metrics")
            .arg(a)
            .arg(b)
            .output()
            .unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let reference = lpips_example("ex_ref.png");
    let err = metrics(&reference, &small);
    assert!(
        err.contains("64×64") && err.contains("32×20") && err.contains("small.png"),
        "{err}"
    );
    let absent = tmp.path().join("absent.png");
    let err = metrics(&absent, &reference);
    assert!(
        err.contains("absent.png") && err.contains("does not exist"),
        "{err}"
    );
    let err = metrics(tmp.path(), &reference);
    assert!(err.contains("is a folder but"), "{err}");

    // LPIPS_WEIGHTS naming a file that is not there is an error, not a silent skip.
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("metrics")
        .arg(&reference)
        .arg(&reference)
        .env("LPIPS_WEIGHTS", &absent)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("LPIPS_WEIGHTS") && err.contains("absent.png"),
        "{err}"
    );
}
