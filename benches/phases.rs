//! Wall and CPU time per render at 512×384 for one size (default 100k; `PHASES_N=…`):
//! a quick, load-robust companion to the criterion benchmark (on a shared machine the CPU
//! time per iteration is the steadier number). Run:
//! `cargo bench -p splat4d --bench phases`.
//!
//! `PHASES_COUNT=1` instead renders `PHASES_ITERS` forward+backward frames and nothing
//! else (no warm-up, no timing): the instruction-count mode, e.g.
//! `RAYON_NUM_THREADS=1 PHASES_COUNT=1 PHASES_ITERS=1 valgrind --tool=callgrind <bench>`;
//! subtract the scene set-up (`common::scene`, inclusive) to get instructions per frame.

mod common;

use splat4d::render::cpu::{self, render_with};
use splat4d::{Gradients, ImageGradients, RenderOptions};
use std::time::Instant;

fn cpu_seconds() -> f64 {
    // utime + stime of this process, in clock ticks (100 Hz on Linux).
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let n: usize = std::env::var("PHASES_N")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    let iters: usize = std::env::var("PHASES_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let model = common::scene(n);
    let cam = common::camera();
    let opts = RenderOptions::<f32>::default();
    let d_rgb: Vec<f32> = (0..3 * 512 * 384)
        .map(|i| ((i % 7) as f32 - 3.0) * 1e-3)
        .collect();
    if std::env::var("PHASES_COUNT").is_ok_and(|v| v == "1") {
        let mut grads = Gradients::zeros_like(&model, false);
        for _ in 0..iters {
            let r = render_with(&model, &cam, 0.5, &opts).unwrap();
            let up = ImageGradients {
                rgb: &d_rgb,
                alpha: None,
                depth: None,
            };
            cpu::backward_into(&r, &model, &up, &mut grads).unwrap();
            std::hint::black_box(&grads);
        }
        return;
    }
    let r = render_with(&model, &cam, 0.5, &opts).unwrap();
    let evals = r.stats.blend_evaluations;
    let _ = cpu::backward(
        &r,
        &model,
        &ImageGradients {
            rgb: &d_rgb,
            alpha: None,
            depth: None,
        },
    )
    .unwrap();
    let mut grads = Gradients::zeros_like(&model, false);
    let mut measure = |backward: bool| {
        let (w0, c0) = (Instant::now(), cpu_seconds());
        for _ in 0..iters {
            let r = render_with(&model, &cam, 0.5, &opts).unwrap();
            if backward {
                cpu::backward_into(
                    &r,
                    &model,
                    &ImageGradients {
                        rgb: &d_rgb,
                        alpha: None,
                        depth: None,
                    },
                    &mut grads,
                )
                .unwrap();
                std::hint::black_box(&grads);
            }
        }
        (
            w0.elapsed().as_secs_f64() / iters as f64,
            (cpu_seconds() - c0) / iters as f64,
        )
    };
    let (fw, fc) = measure(false);
    let (bw, bc) = measure(true);
    println!(
        "n={n} threads={} evaluations/frame={evals}",
        rayon::current_num_threads()
    );
    println!(
        "forward:          wall {:7.1} ms  cpu {:7.1} ms",
        fw * 1e3,
        fc * 1e3
    );
    println!(
        "forward+backward: wall {:7.1} ms  cpu {:7.1} ms",
        bw * 1e3,
        bc * 1e3
    );
    println!(
        "forward blend rate: {:.1} M evaluations/s (wall)",
        evals as f64 / fw / 1e6
    );
}
