//! Criterion benchmarks of the wgpu renderer on the CPU benchmark's scenes (`render.rs`):
//! forward at 512×384 for 10k, 100k and 1M Gaussians, one view per call and a batch of 8
//! views per call (the eval path), plus 1M at 1352×1014 (the paper's resolution). Times
//! include uploading the model and reading the images back, as a caller sees them.
//! Run: `cargo bench -p splat4d --bench render_gpu` (`SPLAT4D_GPU_SOFTWARE=1` to measure
//! a software adapter such as lavapipe).

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use splat4d::render::gpu::{AdapterPolicy, GpuBackend};
use splat4d::render::{RenderBackend, ViewRequest};
use splat4d::{Camera, RenderOptions};
use std::hint::black_box;

mod common;

use common::{camera, scene};

fn bench(c: &mut Criterion) {
    let gpu = match GpuBackend::new(AdapterPolicy::from_env()) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("no GPU to benchmark: {e}");
            return;
        }
    };
    eprintln!("adapter: {}", gpu.describe());
    let opts = RenderOptions::<f32>::default();
    let small = camera();
    let mut large: Camera = camera();
    large.intrinsics = large.intrinsics.scaled_to(1352, 1014);
    let mut group = c.benchmark_group("gpu_render");
    group.sample_size(10);
    for n in [10_000usize, 100_000, 1_000_000] {
        let model = std::cell::OnceCell::new();
        let get = || model.get_or_init(|| scene(n));
        group.bench_function(BenchmarkId::new("forward_512x384", n), |b| {
            let m = get();
            b.iter(|| black_box(gpu.render(m, &small, 0.5, &opts).unwrap()))
        });
        group.bench_function(BenchmarkId::new("batch8_512x384_per_call", n), |b| {
            let m = get();
            let views: Vec<ViewRequest> = (0..8)
                .map(|k| ViewRequest {
                    camera: &small,
                    t: 0.1 * k as f32,
                    options: opts,
                })
                .collect();
            b.iter(|| black_box(gpu.render_batch(m, &views).unwrap()))
        });
        if n == 1_000_000 {
            group.bench_function(BenchmarkId::new("forward_1352x1014", n), |b| {
                let m = get();
                b.iter(|| black_box(gpu.render(m, &large, 0.5, &opts).unwrap()))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
