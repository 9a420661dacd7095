//! `[engine] backend` picks the renderer of the render stage: the CPU and the GPU (here
//! Mesa's lavapipe, forced with `SPLAT4D_GPU_SOFTWARE=1`) draw the same frames, the
//! backend used is recorded in `stage.json`, switching it reruns nothing, and bad values
//! are errors that name the key. Without a GPU adapter the GPU half skips, except under
//! `CI=true`, where that is a failure. One test in its own binary (it sets an environment
//! variable).

use crate::common;

use common::fixture;
use pipeline::config::CaptureConfig;
use pipeline::engine_inputs::{BackendChoice, render_backend};
use pipeline::manifest::Manifest;
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::Selection;
use pipeline::simulate;
use std::fs;
use std::path::Path;

const TRAIN: &str = "[train]\niterations = 12\nbatch_size = 2\ncheckpoint_every = 0\n\
    [render]\npath = \"train\"\ntime = \"sweep\"\nframes = 3\nvideo = false\npng = true\n";

fn frames(dir: &Path) -> Vec<image::RgbImage> {
    let mut files: Vec<_> = fs::read_dir(dir.join("rgb"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
        .iter()
        .map(|f| image::open(f).unwrap().to_rgb8())
        .collect()
}

#[test]
fn cpu_and_gpu_render_stages_draw_the_same_frames() {
    let bad = CaptureConfig::parse("[engine]\nbackend = \"cuda\"\n", Path::new("capture.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        bad.contains("backend") && bad.contains("capture.toml"),
        "{bad}"
    );
    let good = CaptureConfig::parse("[engine]\nbackend = \"gpu\"\n", Path::new("c.toml")).unwrap();
    assert_eq!(good.engine.backend, BackendChoice::Gpu);
    assert_eq!(CaptureConfig::default().engine.backend, BackendChoice::Auto);
    assert!(
        render_backend(BackendChoice::Cpu)
            .unwrap()
            .describe()
            .starts_with("cpu")
    );

    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let scene = rig::sim::Scene::from_file(&fixture("sync-audio.toml")).unwrap();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    simulate::write_truth_calibration(&root).unwrap();
    let settings = |backend: &str| format!("{TRAIN}[engine]\nbackend = \"{backend}\"\n");
    fs::write(root.join("capture.toml"), settings("cpu")).unwrap();
    let summary = common::run_stages(
        &root,
        Selection {
            to: Some("render".into()),
            ..Default::default()
        },
    );
    assert!(summary.failed.is_none(), "{summary:?}");
    let render_dir = root.join("work/render");
    let cpu = frames(&render_dir);
    assert_eq!(cpu.len(), 3);
    let tools = Manifest::read(&render_dir).unwrap().tool_versions;
    assert!(tools["render backend"].starts_with("cpu"), "{tools:?}");

    // SAFETY: this binary has this one test; nothing else reads the environment meanwhile.
    unsafe { std::env::set_var("SPLAT4D_GPU_SOFTWARE", "1") };
    if let Err(e) = render_backend(BackendChoice::Gpu) {
        if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
            panic!("no GPU adapter under CI=true: {e:#}; run scripts/setup.sh");
        }
        eprintln!("SKIPPED the GPU half: {e:#}");
        return;
    }
    // Switching the backend is not a change of settings: nothing is stale.
    fs::write(root.join("capture.toml"), settings("gpu")).unwrap();
    let again = common::run_stages(
        &root,
        Selection {
            to: Some("render".into()),
            ..Default::default()
        },
    );
    assert!(again.ran.is_empty(), "{again:?}");
    let forced = common::run_stages(
        &root,
        Selection {
            only: Some("render".into()),
            force: true,
            ..Default::default()
        },
    );
    assert!(forced.failed.is_none(), "{forced:?}");
    let tools = Manifest::read(&render_dir).unwrap().tool_versions;
    assert!(tools["render backend"].starts_with("gpu: "), "{tools:?}");
    let gpu = frames(&render_dir);
    for (a, b) in cpu.iter().zip(&gpu) {
        assert_eq!(a.dimensions(), b.dimensions());
        let diffs: Vec<i32> = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(x, y)| (*x as i32 - *y as i32).abs())
            .collect();
        let max = diffs.iter().copied().max().unwrap();
        let mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
        eprintln!("cpu vs gpu frame: max {max}/255, mean {mean:.4}");
        assert!(max <= 1 && mean < 0.01, "max {max}, mean {mean}");
    }
}
