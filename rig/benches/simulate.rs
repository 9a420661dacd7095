//! How long the simulator takes: the whole `tiny.toml` capture (4 videos, 1 held-out
//! camera, 8 stills), and one frame of the demo scene.
//! `CARGO_TARGET_DIR=… cargo bench -p rig --bench simulate`

use std::path::Path;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use rig::sim::{Scene, render_clean, simulate};
use shared_types::NoProgress;

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(name)
}

fn bench(c: &mut Criterion) {
    let tiny = Scene::from_file(&fixture("tiny.toml")).unwrap();
    let mut g = c.benchmark_group("simulate");
    g.sample_size(10);
    g.bench_function("tiny.toml", |b| {
        b.iter_batched(
            || tempfile::tempdir().unwrap(),
            |dir| simulate(&tiny, dir.path(), &NoProgress).unwrap(),
            BatchSize::PerIteration,
        )
    });
    g.bench_function("parse+validate tiny.toml", |b| {
        b.iter(|| Scene::from_file(&fixture("tiny.toml")).unwrap())
    });
    let demo = Scene::from_file(&fixture("demo.toml")).unwrap();
    g.bench_function(
        "demo.toml one cam0 frame (480x360, 2x2 supersampling, incl. texture bake)",
        |b| b.iter(|| render_clean(&demo, "cam0", 1.0).unwrap()),
    );
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
