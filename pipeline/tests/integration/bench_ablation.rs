//! `pipeline bench ablation` on a small simulated capture (`fixtures/tiny.toml`, one
//! held-out camera with moving-region masks): two decay variants train from the same points
//! with a preset's settings over the capture's, each is measured over the whole held-out
//! image and inside its masks (LPIPS with the capture's `[eval] lpips` network), the table
//! compares each with `none`, and a second run trains nothing.

use crate::common;

use std::fs;

use common::fixture;
use pipeline::bench::ablation::{Ablation, run};
use pipeline::bench::inputs::BenchSource;
use pipeline::bench::tradeoff::{TrainOn, read_csv};
use pipeline::presets::Preset;
use pipeline::report::{OutputMode, Reporter};
use splat4d::decay::DecayVariant;

#[test]
fn each_variant_is_measured_whole_and_moving_and_resumed() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let reporter = Reporter::new(OutputMode::Quiet);
    // The capture's own schedule is 30 000 steps; the preset's 300 run instead. A decay
    // warm-up of 3000 of 30 000 steps is 30 of the preset's 300.
    common::tiny_capture(
        &root,
        "[sync]\nmethod = \"timestamps\"\n[train]\nbatch_size = 1\ncheckpoint_every = 0\n\
         [train.densify]\nenabled = false\n[decay]\nwarmup = 3000\nconstant = 0.99\n\
         [eval]\nlpips = \"lpips.onnx\"\n",
    );
    let net = fixture("onnx/lpips_tiny/mean_abs_diff.onnx");
    fs::copy(net, root.join("lpips.onnx")).unwrap();

    let source = BenchSource::from_args(&root, None).unwrap();
    let ablation = Ablation {
        preset: Some(Preset::Preview),
        iterations: None,
        decay: vec![DecayVariant::None, DecayVariant::Constant],
        backend: TrainOn::Cpu,
    };
    let md = run(&source, &ablation, &reporter).unwrap();
    assert_eq!(md, root.join("work/bench/ablation/ablation.md"));
    let csv = md.with_extension("csv");
    let rows = read_csv(&csv).unwrap();
    assert_eq!(rows.len(), 2);
    for r in &rows {
        assert_eq!(
            (
                r.setting.iterations,
                r.setting.resolution,
                r.setting.max_gaussians
            ),
            (300, 1.0, 80_000),
            "the preset's settings"
        );
        let (psnr, moving) = (r.psnr.unwrap(), r.moving_psnr.unwrap());
        assert!(psnr > 10.0 && psnr < 60.0 && moving.is_finite(), "{r:?}");
        assert!(r.moving_ssim.is_some_and(|s| s > -1.0 && s < 1.0), "{r:?}");
        // The stand-in network is mean |a − b|: in (0, 1) over the masks' boxes too.
        assert!(r.moving_lpips.is_some_and(|l| l > 0.0 && l < 1.0), "{r:?}");
    }
    assert_eq!(rows[0].setting.decay, DecayVariant::None);
    // The constant decay thins every opacity for 270 steps: the two runs differ.
    assert_ne!(rows[0].psnr, rows[1].psnr);
    let table = fs::read_to_string(&md).unwrap();
    assert!(
        table.contains("| none |") && table.contains("| +0.00 |"),
        "{table}"
    );
    let delta = rows[1].psnr.unwrap() - rows[0].psnr.unwrap();
    assert!(
        table.contains(&format!(
            "| constant | {:.2} | {delta:+.2} |",
            rows[1].psnr.unwrap()
        )),
        "{table}"
    );
    assert!(
        table.contains("300 iterations")
            && table.contains("warm-up 30 steps")
            && table.contains("constant 0.99"),
        "{table}"
    );

    // Run again: nothing is trained, the CSV is as it was.
    let before = fs::read_to_string(&csv).unwrap();
    run(&source, &ablation, &reporter).unwrap();
    assert_eq!(fs::read_to_string(&csv).unwrap(), before);

    let bad = Ablation {
        iterations: Some(0),
        preset: None,
        ..ablation
    };
    let e = run(&source, &bad, &reporter).unwrap_err().to_string();
    assert!(e.contains("--iterations"), "{e}");
}
