//! The engine-only build (`cargo build -p pipeline --no-default-features --features
//! bundled-sqlite`: no FFmpeg, no
//! OpenCV, no system SQLite; what a GPU node runs, docs/cluster.md) on a capture the full
//! build prepared up to `init`: it links none of them, runs `train`, `render`, `eval` and `export`, and
//! trains the same model as the full build; the stages that read videos say they need
//! the full build, and an ONNX LPIPS model that it needs the `onnx` feature. `scripts/test.sh` builds the binary and names it in
//! `PIPELINE_ENGINE_ONLY`; without it the test says so and passes, except under
//! `CI=true`, where that is a failure.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common;

fn engine_only_binary() -> Option<PathBuf> {
    match std::env::var_os("PIPELINE_ENGINE_ONLY") {
        Some(p) => Some(PathBuf::from(p)),
        None if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") => panic!(
            "PIPELINE_ENGINE_ONLY is not set under CI=true: scripts/test.sh builds the \
             engine-only binary and sets it"
        ),
        None => {
            eprintln!(
                "skipped: set PIPELINE_ENGINE_ONLY to a `cargo build -p pipeline \
                 --no-default-features --features bundled-sqlite` binary (scripts/test.sh \
                 does)"
            );
            None
        }
    }
}

fn run(binary: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new(binary)
        .arg("--quiet")
        .args(args)
        .args(["--backend", "cpu"])
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn the_engine_only_build_trains_renders_evaluates_and_exports_what_the_full_build_prepared() {
    let Some(engine) = engine_only_binary() else {
        return;
    };
    let ldd = Command::new("ldd").arg(&engine).output().unwrap();
    let libraries = String::from_utf8_lossy(&ldd.stdout);
    for lib in [
        "libavcodec",
        "libavformat",
        "libswscale",
        "libopencv",
        "libsqlite3",
    ] {
        assert!(
            !libraries.contains(lib),
            "{} links {lib}:\n{libraries}",
            engine.display()
        );
    }

    let tmp = tempfile::tempdir().unwrap();
    let full_dir = tmp.path().join("full");
    common::tiny_capture(&full_dir, common::CHEAP);
    let full = Path::new(env!("CARGO_BIN_EXE_pipeline"));
    let dir = full_dir.to_str().unwrap();
    let (ok, text) = run(full, &["run", dir, "--to", "init"]);
    assert!(ok, "the full build up to init: {text}");
    let engine_dir = tmp.path().join("engine");
    common::copy_dir(&full_dir, &engine_dir);

    let (ok, text) = run(full, &["run", dir]);
    assert!(ok, "the full build from train on: {text}");
    let engine_capture = engine_dir.to_str().unwrap();
    let (ok, text) = run(&engine, &["run", engine_capture]);
    assert!(ok, "the engine-only build from train on: {text}");
    for out in [
        "train/model.bin",
        "render/rgb",
        "eval/metrics.json",
        "export/export.json",
    ] {
        assert!(engine_dir.join("work").join(out).exists(), "{out} missing");
    }
    // The same code trains the same model.
    let model = |d: &Path| std::fs::read(d.join("work/train/model.bin")).unwrap();
    assert!(
        model(&engine_dir) == model(&full_dir),
        "the two builds trained different models"
    );

    let (ok, text) = run(
        &engine,
        &["run", engine_capture, "--only", "ingest", "--force"],
    );
    assert!(!ok, "ingest ran without FFmpeg: {text}");
    assert!(
        text.contains("built without FFmpeg") && text.contains("the ingest stage"),
        "{text}"
    );
    // The refused stage left the earlier outputs as they were.
    assert!(engine_dir.join("work/ingest/streams.json").is_file());

    // An ONNX model needs the `onnx` feature, which this build (like a default one) leaves out.
    let metrics = std::fs::read(engine_dir.join("work/eval/metrics.json")).unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../fixtures/onnx/lpips_tiny/mean_abs_diff.onnx"),
        engine_dir.join("lpips.onnx"),
    )
    .unwrap();
    let toml = engine_dir.join("capture.toml");
    let text = std::fs::read_to_string(&toml).unwrap();
    let with_onnx = text.replace("[eval]\n", "[eval]\nlpips = \"lpips.onnx\"\n");
    assert_ne!(text, with_onnx, "capture.toml has an [eval] section");
    std::fs::write(&toml, with_onnx).unwrap();
    let (ok, text) = run(
        &engine,
        &["run", engine_capture, "--only", "eval", "--force"],
    );
    assert!(!ok, "eval ran an ONNX model without the feature: {text}");
    assert!(
        text.contains("lpips.onnx")
            && text.contains("runs no ONNX models")
            && text.contains("--features onnx"),
        "{text}"
    );
    assert_eq!(
        std::fs::read(engine_dir.join("work/eval/metrics.json")).unwrap(),
        metrics,
        "the refused eval changed the earlier metrics"
    );
}
