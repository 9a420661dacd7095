//! Timing of render/eval on a demo-sized model (numbers for BENCHMARKS.md, no assertions
//! on time). Run: `cargo test --release -p splat4d --test integration -- --ignored --nocapture eval_timing::`.

use crate::eval_support;

use std::time::Instant;

use eval_support::*;
use glam::DVec3;
use splat4d::CpuBackend;
use splat4d::eval::{EvalView, FrameOutputs, evaluate, render_path};
use splat4d::metrics::lpips::Lpips;
use splat4d::trajectories::{PathKind, PathSpec, TimeMode, camera_path};
use splat4d::{ColourDegrees, Gaussians, NoProgress, TimeMapping};

/// ~63k Gaussians (the demo's trained size) in a 3×3×2 box, spread over 1.2 model units
/// (2.4 s at 15 fps), full colour degree.
fn demo_sized() -> Gaussians<f32> {
    let mut g = Gaussians::new(
        ColourDegrees::FULL,
        TimeMapping::frames_over_30(0.0, 15.0, 2.4),
    );
    g.active = ColourDegrees::FULL;
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut u = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f32 / (1u64 << 53) as f32
    };
    for _ in 0..63_000 {
        let m = [3.0 * u() - 1.5, 3.0 * u() - 1.5, 2.0 * u() - 1.0, 1.2 * u()];
        g.push(
            m,
            [-3.2 - u(), -3.2 - u(), -3.2 - u(), -1.5],
            1.0,
            [u(), u(), u()],
        );
    }
    g
}

#[test]
#[ignore = "timing for BENCHMARKS.md; run with --release --ignored --nocapture"]
fn render_and_eval_timing() {
    let model = demo_sized();
    let train = rig(240, 180);
    let dir = tempfile::tempdir().unwrap();
    for (w, h) in [(240, 180), (480, 360)] {
        let mut spec = PathSpec::new(PathKind::Orbit, TimeMode::Sweep, 36);
        spec.size = Some((w, h));
        let path = camera_path(&spec, &train, &[], &model.time).unwrap();
        for (label, outputs) in [
            (
                "rgb only",
                FrameOutputs {
                    rgb: true,
                    depth: false,
                    alpha: false,
                },
            ),
            ("rgb+depth+alpha", FrameOutputs::ALL),
        ] {
            let start = Instant::now();
            render_path(
                &CpuBackend,
                &model,
                &path,
                &dir.path().join(format!("r{w}{label}")),
                outputs,
                [0.0; 3],
                None,
                &NoProgress,
                None,
            )
            .unwrap();
            let s = start.elapsed().as_secs_f64();
            println!(
                "render_path orbit 36 frames {w}x{h} {label}: {s:.2} s ({:.0} ms/frame)",
                s * 1000.0 / 36.0
            );
        }
        let start = Instant::now();
        for (cam, t) in &path {
            splat4d::render::cpu::render(&model, cam, *t as f32).unwrap();
        }
        let s = start.elapsed().as_secs_f64();
        println!(
            "render only (no PNG) 36 frames {w}x{h}: {s:.2} s ({:.0} ms/frame)",
            s * 1000.0 / 36.0
        );
    }
    // 24 held-out views at 240×180 (4 cameras × 6 times), ground truth = renders at
    // shifted times, as PNG.
    let held: Vec<_> = (0..4)
        .map(|i| {
            let a = 1.0 + i as f64 * 1.3;
            camera(
                &format!("h{i}"),
                DVec3::new(4.6 * a.cos(), 4.6 * a.sin(), 1.2),
                240,
                180,
            )
        })
        .collect();
    let mut views = Vec::new();
    for (i, cam) in held.iter().enumerate() {
        for k in 0..6 {
            let t = 0.1 + 0.18 * k as f64;
            let path = dir.path().join(format!("gt{i}_{k}.png"));
            save_render(&model, cam, t + 0.02, &path);
            views.push(EvalView {
                camera: cam.clone(),
                time: t,
                image_path: path,
                mask: None,
                gain: [1.0; 3],
            });
        }
    }
    let start = Instant::now();
    let report = evaluate(
        &CpuBackend,
        &model,
        &views,
        &[],
        &dir.path().join("eval"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    let s = start.elapsed().as_secs_f64();
    println!(
        "evaluate 24 views 240x180, no LPIPS: {s:.2} s ({:.0} ms/view), mean PSNR {:.2}",
        s * 1000.0 / 24.0,
        report.heldout.psnr.unwrap()
    );
    let net = Lpips::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures/onnx/lpips_tiny/mean_abs_diff.onnx"),
    )
    .unwrap();
    let start = Instant::now();
    evaluate(
        &CpuBackend,
        &model,
        &views,
        &[],
        &dir.path().join("eval2"),
        Some(&net),
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    let s = start.elapsed().as_secs_f64();
    println!(
        "evaluate 24 views 240x180, tiny LPIPS fixture: {s:.2} s ({:.0} ms/view)",
        s * 1000.0 / 24.0
    );
    match Lpips::installed() {
        Ok(Some(alex)) => {
            let start = Instant::now();
            let report = evaluate(
                &CpuBackend,
                &model,
                &views,
                &[],
                &dir.path().join("eval3"),
                Some(&alex),
                [0.0; 3],
                None,
                &NoProgress,
            )
            .unwrap();
            let s = start.elapsed().as_secs_f64();
            println!(
                "evaluate 24 views 240x180, LPIPS-alex native: {s:.2} s ({:.0} ms/view), mean LPIPS {:.4}",
                s * 1000.0 / 24.0,
                report.heldout.lpips.unwrap()
            );
        }
        _ => println!("no LPIPS-alex weights installed: native LPIPS not timed"),
    }
    let (a, b) = (vec![0.3f32; 240 * 180 * 3], vec![0.5f32; 240 * 180 * 3]);
    let start = Instant::now();
    for _ in 0..24 {
        splat4d::metrics::image_metrics(&a, &b, 240, 180).unwrap();
    }
    println!(
        "image_metrics (PSNR+SSIM1+SSIM2) 240x180: {:.1} ms",
        start.elapsed().as_secs_f64() * 1000.0 / 24.0
    );
}

/// CPU seconds (user + system, all threads) this process has used so far (Linux).
fn process_cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name's closing parenthesis; utime and stime are 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    (ticks(11) + ticks(12)) / 100.0
}

#[test]
#[ignore = "timing for BENCHMARKS.md; run with --release --ignored --nocapture"]
fn lpips_alex_timing() {
    let Ok(Some(net)) = Lpips::installed() else {
        println!("no LPIPS-alex weights installed: nothing to time");
        return;
    };
    let image = |w: usize, h: usize, seed: usize| -> Vec<f32> {
        (0..w * h * 3)
            .map(|i| (((i * 7919 + seed * 104_729) % 1000) as f32 / 999.0) * 0.5 + 0.25)
            .collect()
    };
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("load average at start: {}", load.trim());
    for (w, h, n) in [(640, 360, 10), (1352, 1014, 4)] {
        let (a, b) = (image(w, h, 1), image(w, h, 2));
        net.distance(&a, &b, w, h).unwrap();
        let (start, cpu) = (Instant::now(), process_cpu_seconds());
        for _ in 0..n {
            std::hint::black_box(net.distance(&a, &b, w, h).unwrap());
        }
        let wall = start.elapsed().as_secs_f64() / n as f64;
        let cpu = (process_cpu_seconds() - cpu) / n as f64;
        println!(
            "LPIPS-alex one pair {w}x{h}: {:.0} ms wall, {:.0} ms CPU ({} threads)",
            wall * 1000.0,
            cpu * 1000.0,
            rayon::current_num_threads()
        );
    }
}
