//! Criterion benchmarks of the CPU renderer: forward and forward+backward at 512×384 for
//! 10k, 100k and 1M Gaussians with a realistic spread of sizes (log-normal scales around a
//! median of ~2 px at 100k, opacities spread over the sigmoid, full colour degrees).
//! Run: `cargo bench -p splat4d --bench render`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use splat4d::render::cpu::{self, render_with};
use splat4d::{Gradients, ImageGradients, RenderOptions};
use std::hint::black_box;

mod common;

use common::{camera, scene};

fn bench(c: &mut Criterion) {
    let cam = camera();
    let opts = RenderOptions::<f32> {
        background: [0.0; 3],
        ..RenderOptions::default()
    };
    let d_rgb: Vec<f32> = (0..3 * 512 * 384)
        .map(|i| ((i % 7) as f32 - 3.0) * 1e-3)
        .collect();
    let mut group = c.benchmark_group("render_512x384");
    group.sample_size(10);
    for n in [10_000usize, 100_000, 1_000_000] {
        // Built lazily, so a filtered run (`-- forward/100000`) builds only what it needs.
        let model = std::cell::OnceCell::new();
        let get = || {
            model.get_or_init(|| {
                let m = scene(n);
                let r = render_with(&m, &cam, 0.5, &opts).unwrap();
                eprintln!(
                    "n={n}: visible {}, tile pairs {}, blend evaluations {}, mean alpha {:.3}",
                    r.stats.visible,
                    r.stats.tile_pairs,
                    r.stats.blend_evaluations,
                    r.alpha.iter().sum::<f32>() / r.alpha.len() as f32
                );
                m
            })
        };
        group.bench_function(BenchmarkId::new("forward", n), |b| {
            let m = get();
            b.iter(|| black_box(render_with(m, &cam, 0.5, &opts).unwrap()))
        });
        group.bench_function(BenchmarkId::new("forward_backward", n), |b| {
            let m = get();
            // A training loop keeps its gradient buffer between steps.
            let mut grads = Gradients::zeros_like(m, false);
            b.iter(|| {
                let r = render_with(m, &cam, 0.5, &opts).unwrap();
                cpu::backward_into(
                    &r,
                    m,
                    &ImageGradients {
                        rgb: &d_rgb,
                        alpha: None,
                        depth: None,
                    },
                    &mut grads,
                )
                .unwrap();
                black_box(&grads);
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
