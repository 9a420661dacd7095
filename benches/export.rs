//! Criterion benchmarks of the exports on the render benchmark's 100k-Gaussian scene
//! (full colour degrees): baking one time step into 3D Gaussians, encoding a 3DGS PLY
//! frame, the native 4D PLY, the `.splatv`, the viewer's `model.4dgs`, and a whole
//! `export_all` of 10 frames (files into a temporary folder, no viewer).
//! Run: `cargo bench -p splat4d --bench export`.

use criterion::{Criterion, criterion_group, criterion_main};
use splat4d::export::{ExportOptions, bake_frame, export_all, ply3d, ply4d, splatv, web4d};
use splat4d::{CameraSet, NoProgress};
use std::hint::black_box;

mod common;

fn bench(c: &mut Criterion) {
    let model = common::scene(100_000);
    let cams = CameraSet::new(vec![common::camera()]);
    let mut group = c.benchmark_group("export_100k");
    group.sample_size(10);
    group.bench_function("bake_frame", |b| {
        b.iter(|| black_box(bake_frame(&model, 0.5, 1.0 / 255.0)))
    });
    let frame = bake_frame(&model, 0.5, 1.0 / 255.0);
    eprintln!(
        "bake at t=0.5: {} kept, {} dropped",
        frame.splats.len(),
        frame.dropped
    );
    group.bench_function("encode_frame_ply", |b| {
        b.iter(|| black_box(ply3d::frame_table(&frame).encode()))
    });
    group.bench_function("encode_model4d_ply", |b| {
        b.iter(|| black_box(ply4d::model_table(&model).encode()))
    });
    group.bench_function("splatv", |b| {
        b.iter(|| {
            black_box(splatv::encode(
                &splatv::splats_from_model(&model, None),
                &[],
            ))
        })
    });
    group.bench_function("viewer_model", |b| {
        b.iter(|| black_box(web4d::encode(&model, [0.0, 1.0], 1.0 / 255.0).bytes))
    });
    let web = web4d::encode(&model, [0.0, 1.0], 1.0 / 255.0);
    eprintln!(
        "model.4dgs: {} Gaussians, {} bytes",
        web.header.count,
        web.bytes.len()
    );
    let dir = tempfile::tempdir().unwrap();
    let times: Vec<f64> = (0..10).map(|k| k as f64 / 9.0).collect();
    let opts = ExportOptions {
        viewer: false,
        ..Default::default()
    };
    group.bench_function("export_all_10_frames", |b| {
        b.iter(|| {
            black_box(export_all(&model, &cams, &times, dir.path(), &opts, &NoProgress).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
