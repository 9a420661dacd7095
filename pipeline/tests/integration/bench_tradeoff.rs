//! `pipeline bench tradeoff` on a small simulated capture (`fixtures/tiny.toml`, 160×120,
//! one held-out camera): two settings are trained and measured, the table, CSV and plot
//! are written, a wider grid trains only the new setting (the measured rows stay as they
//! were), LPIPS is measured with the capture's `[eval] lpips` weights, and bad sources are
//! refused with errors that say what to give.

use crate::common;

use std::fs;

use common::fixture;
use pipeline::bench::inputs::BenchSource;
use pipeline::bench::tradeoff::{Grid, TrainOn, read_csv};
use pipeline::report::{OutputMode, Reporter};
use splat4d::decay::DecayVariant;

const SETTINGS: &str = "[sync]\nmethod = \"timestamps\"\n\
    [train]\niterations = 20\nbatch_size = 2\ncheckpoint_every = 0\n\
    [decay]\nwarmup = 5\n\
    [eval]\nlpips = \"lpips.onnx\"\n";

#[test]
fn a_grid_is_measured_plotted_and_resumed() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let reporter = Reporter::new(OutputMode::Quiet);
    common::tiny_capture(&root, SETTINGS);
    // `[eval] lpips` weights: a stand-in network (mean absolute difference) in ONNX.
    let net = fixture("onnx/lpips_tiny/mean_abs_diff.onnx");
    fs::copy(net, root.join("lpips.onnx")).unwrap();

    let source = BenchSource::from_args(&root, None).unwrap();
    let mut grid = Grid {
        iterations: vec![10, 30],
        resolution: vec![0.5],
        max_gaussians: vec![],
        decay: vec![DecayVariant::Neural],
        backend: vec![TrainOn::Cpu],
        stretch: None,
    };
    let md = pipeline::bench::tradeoff::run(&source, &grid, &reporter).unwrap();
    let out = md.parent().unwrap().to_path_buf();
    let csv_path = out.join("tradeoff.csv");
    let rows = read_csv(&csv_path).unwrap();
    assert_eq!(rows.len(), 2);
    for r in &rows {
        let psnr = r.psnr.unwrap();
        eprintln!(
            "{}: {:.2} s, {:?} CPU s, {:?} MiB, {} Gaussians, {psnr:.2} dB, moving {:?}",
            r.setting.key(),
            r.seconds,
            r.cpu_seconds,
            r.peak_ram_mib,
            r.gaussians,
            r.moving_psnr
        );
        assert!(psnr > 5.0 && psnr < 60.0, "{psnr}");
        assert!(r.seconds > 0.0 && r.gaussians > 0);
        assert!(r.cpu_seconds.unwrap() > 0.0);
        assert!(r.peak_ram_mib.unwrap() > 10.0);
        // The simulator masks its held-out camera: the moving region is measured too.
        assert!(r.moving_psnr.unwrap().is_finite());
        // The stand-in network's LPIPS is the mean absolute difference: in (0, 1).
        let lpips = r.lpips.expect("LPIPS with [eval] lpips set");
        assert!(lpips > 0.0 && lpips < 1.0, "{lpips}");
        assert_eq!(r.setting.resolution, 0.5);
    }
    // More steps fit the held-out view better (same points, seed and settings).
    assert!(rows[1].psnr.unwrap() > rows[0].psnr.unwrap(), "{rows:?}");
    let table = fs::read_to_string(&md).unwrap();
    assert!(
        table.contains("★") && table.contains("tradeoff.png"),
        "{table}"
    );
    assert!(
        table.contains("| 10 |") && table.contains("| 30 |"),
        "{table}"
    );
    assert!(table.contains("Machine:"), "{table}");
    let png = image::open(out.join("tradeoff.png")).unwrap().into_rgb8();
    assert_eq!(png.dimensions(), (1000, 640));
    let red = png
        .pixels()
        .filter(|p| p[0] > 200 && p[1] < 60 && p[2] < 60)
        .count();
    let ink = png.pixels().filter(|p| p[0] < 100 && p[1] < 100).count();
    assert!(red > 50, "the Pareto front is drawn in red: {red} pixels");
    assert!(ink > 2000, "axes, labels and points: {ink} dark pixels");

    // A wider grid trains only the new setting; the measured lines stay as written.
    let before = fs::read_to_string(&csv_path).unwrap();
    grid.iterations.push(20);
    pipeline::bench::tradeoff::run(&source, &grid, &reporter).unwrap();
    let after = fs::read_to_string(&csv_path).unwrap();
    assert!(after.starts_with(&before), "{before}\n---\n{after}");
    assert_eq!(read_csv(&csv_path).unwrap().len(), 3);
    // A grid of one setting still shows every row measured on this capture.
    grid.iterations = vec![10];
    pipeline::bench::tradeoff::run(&source, &grid, &reporter).unwrap();
    assert_eq!(fs::read_to_string(&csv_path).unwrap(), after);
    let table = fs::read_to_string(&md).unwrap();
    assert!(
        table.contains("| 20 |") && table.contains("| 30 |"),
        "{table}"
    );

    // Stretched training views (4 cameras × 12 frames at 80×60), the capture used as
    // prepared: a folder and table of their own, which say so; the plain table is left as
    // it was.
    let stretched = Grid {
        stretch: Some("12:80x60".parse().unwrap()),
        ..grid.clone()
    };
    let prepared = source.clone().as_prepared();
    let md_stretched = pipeline::bench::tradeoff::run(&prepared, &stretched, &reporter).unwrap();
    assert_eq!(
        md_stretched.parent().unwrap(),
        out.parent().unwrap().join("tradeoff-12x80x60")
    );
    let rows = read_csv(&md_stretched.with_file_name("tradeoff.csv")).unwrap();
    assert_eq!(rows.len(), 1);
    assert!(rows[0].psnr.unwrap().is_finite() && rows[0].gaussians > 0);
    let table = fs::read_to_string(&md_stretched).unwrap();
    assert!(
        table.contains("48 training views of 80×60")
            && table.contains("--stretch 12:80x60")
            && table.contains("(as prepared)")
            && table.contains("--as-prepared"),
        "{table}"
    );
    assert_eq!(fs::read_to_string(&csv_path).unwrap(), after);
    // A capture not prepared up to `init` is not used as prepared.
    let fresh = tmp.path().join("fresh");
    common::tiny_capture(&fresh, SETTINGS);
    let unprepared = BenchSource::from_args(&fresh, None).unwrap().as_prepared();
    let e = pipeline::bench::tradeoff::run(&unprepared, &stretched, &reporter)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--to init") && e.contains("fresh"), "{e}");

    // Bad sources.
    let scene_file = fixture("tiny.toml");
    let e = BenchSource::from_args(&scene_file, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("capture directory to simulate"), "{e}");
    let e = BenchSource::from_args(&root, Some(&root))
        .unwrap_err()
        .to_string();
    assert!(e.contains("remove the second path"), "{e}");
    let e = BenchSource::from_args(&tmp.path().join("nope"), None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("neither a scene file nor a capture directory"),
        "{e}"
    );
    let bad = Grid {
        resolution: vec![0.0],
        ..grid
    };
    let e = pipeline::bench::tradeoff::run(&source, &bad, &reporter)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--resolution"), "{e}");
}
