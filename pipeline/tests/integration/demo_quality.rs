//! `pipeline demo` end to end (simulate, every stage, the demo's training) held to the
//! quality measured for it (BENCHMARKS.md, "Motion at init"): held-out PSNR and SSIM on the four
//! filmed held-out cameras, and PSNR inside the masks of what moves (the walking figure and
//! the waving flag), each within 0.5 dB / 0.02 of the measurement, and that region within
//! 3 dB of the whole image.
//!
//! Long (6–12 minutes in a release build on 2 cores): ignored by default. Run with the
//! release binary:
//! `cargo build --release -p pipeline && PIPELINE_BIN=$PWD/target/release/pipeline cargo test -p pipeline --test integration -- --ignored --nocapture demo_quality::`

use std::path::PathBuf;
use std::process::Command;

/// Held-out PSNR (dB) and SSIM measured for the demo, minus the run-to-run margin.
/// (BENCHMARKS.md "Motion at init": 2000 steps on `RADIAL` poses with motion at init, 24.72 dB,
/// SSIM 0.845; without it two captures gave 24.58 and 24.61 dB.)
const PSNR_FLOOR: f64 = 24.72 - 0.5;
const SSIM_FLOOR: f64 = 0.845 - 0.02;
/// PSNR inside the masks of what moves (the figure and the flag), dB (22.67).
const MOVING_FLOOR: f64 = 22.67 - 0.5;
/// The moving region within 3 dB of the whole image.
const MOVING_GAP: f64 = 3.0;

fn binary() -> PathBuf {
    std::env::var_os("PIPELINE_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_pipeline")))
}

#[test]
#[ignore = "runs the whole demo (6–12 minutes in release); run for BENCHMARKS.md"]
fn the_demo_reaches_its_measured_held_out_quality() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("demo");
    let out = Command::new(binary())
        .args(["--quiet", "demo"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "pipeline demo failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("work/eval/metrics.json")).unwrap())
            .unwrap();
    let held = &metrics["heldout"];
    let psnr = held["mean"]["psnr"].as_f64().unwrap();
    let ssim = held["mean"]["ssim"].as_f64().unwrap();
    let moving = held["moving"]["mean"]["psnr"].as_f64().unwrap();
    eprintln!("held-out PSNR {psnr:.2} dB, SSIM {ssim:.3}; moving region {moving:.2} dB");
    assert!(
        psnr >= PSNR_FLOOR,
        "held-out PSNR {psnr:.2} dB < {PSNR_FLOOR:.2}"
    );
    assert!(
        ssim >= SSIM_FLOOR,
        "held-out SSIM {ssim:.3} < {SSIM_FLOOR:.3}"
    );
    assert!(
        moving >= MOVING_FLOOR,
        "moving region {moving:.2} dB < {MOVING_FLOOR:.2}"
    );
    assert!(
        psnr - moving <= MOVING_GAP,
        "moving region {moving:.2} dB is more than {MOVING_GAP} dB below the whole image"
    );
}
