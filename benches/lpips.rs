//! Criterion benchmark of LPIPS-alex computed natively (`splat4d::metrics::lpips`): one
//! image pair at 640×360 and at 1352×1014, and a batch of four 640×360 pairs (how eval
//! measures its views), on the CPU and, where a GPU opens, the same three on the GPU
//! (`gpu_*`; software adapters such as lavapipe only with `SPLAT4D_GPU_SOFTWARE=1`).
//! Needs the weights `scripts/setup.sh` installs; without them it says so and measures
//! nothing.
//! Run: `cargo bench -p splat4d --bench lpips`.

use criterion::{Criterion, criterion_group, criterion_main};
use splat4d::gpu::{AdapterPolicy, Gpu};
use splat4d::metrics::lpips::{INSTALL_HINT, ImagePair, Lpips, LpipsDevice};
use std::hint::black_box;

/// A smooth image with some texture (values in [0, 1]).
fn image(width: usize, height: usize, seed: usize) -> Vec<f32> {
    (0..width * height * 3)
        .map(|i| {
            let (p, c) = (i / 3, i % 3);
            let (x, y) = ((p % width) as f32, (p / width) as f32);
            let v = (x * 0.05 + seed as f32).sin() * (y * 0.03 + c as f32).cos();
            0.5 + 0.4 * v + 0.1 * (((i * 7919 + seed) % 101) as f32 / 100.0 - 0.5)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let net = match Lpips::installed() {
        Ok(Some(net)) => net,
        Ok(None) => {
            eprintln!("no LPIPS weights: nothing to measure; {INSTALL_HINT}");
            return;
        }
        Err(e) => panic!("{e}"),
    };
    let gpu = match Gpu::open(AdapterPolicy::from_env()) {
        Ok(gpu) => Some(gpu),
        Err(e) => {
            eprintln!("no GPU cases: {e}");
            None
        }
    };
    let mut group = c.benchmark_group("lpips_alex");
    group.sample_size(10);
    let mut devices = vec![("", LpipsDevice::Cpu)];
    if let Some(gpu) = &gpu {
        eprintln!("GPU cases on {}", gpu.describe());
        devices.push(("gpu_", LpipsDevice::Gpu(gpu)));
    }
    let (w, h) = (640, 360);
    let images: Vec<(Vec<f32>, Vec<f32>)> = (0..4)
        .map(|k| (image(w, h, 2 * k), image(w, h, 2 * k + 1)))
        .collect();
    let batch: Vec<ImagePair> = images
        .iter()
        .map(|(a, b)| ImagePair {
            a,
            b,
            width: w,
            height: h,
        })
        .collect();
    for (prefix, device) in devices {
        for (w, h) in [(640, 360), (1352, 1014)] {
            let (a, b) = (image(w, h, 1), image(w, h, 2));
            let pair = [ImagePair {
                a: &a,
                b: &b,
                width: w,
                height: h,
            }];
            group.bench_function(format!("{prefix}pair_{w}x{h}"), |bench| {
                bench.iter(|| black_box(net.distances_on(device, &pair).pop().unwrap().unwrap()))
            });
        }
        group.bench_function(format!("{prefix}batch_4x_640x360"), |bench| {
            bench.iter(|| black_box(net.distances_on(device, &batch)))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
