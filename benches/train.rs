//! Criterion benchmarks of training: the loss with its SSIM backward at 512×384, one Adam
//! step over 100k full-colour Gaussians, and 20 whole iterations (batch 4, render +
//! loss + backward + Adam + log) on the analytic scene of the trainer tests at 128×96.
//! Run: `cargo bench -p splat4d --bench train`.

#[path = "../tests/integration/train_scene/mod.rs"]
mod train_scene;

use criterion::{Criterion, criterion_group, criterion_main};
use splat4d::CpuBackend;
use splat4d::model::ColourDegrees;
use splat4d::train::loss::image_loss;
use splat4d::train::optim::{Adam, LearningRates};
use splat4d::train::{NoHooks, TrainConfig, train};
use splat4d::{Gaussians, Gradients, NoProgress, TimeMapping};
use std::hint::black_box;

fn loss(c: &mut Criterion) {
    let (w, h) = (512, 384);
    let n = 3 * w * h;
    let a: Vec<f32> = (0..n).map(|i| ((i * 37 % 101) as f32) / 101.0).collect();
    let b: Vec<f32> = (0..n).map(|i| ((i * 53 % 97) as f32) / 97.0).collect();
    let mut g = vec![0.0f32; n];
    c.bench_function("loss_l1_ssim_backward_512x384", |bench| {
        bench.iter(|| black_box(image_loss(&a, &b, w, h, 0.2, Some(&mut g))))
    });
}

fn adam(c: &mut Criterion) {
    let mut model = Gaussians::<f32>::new(ColourDegrees::FULL, TimeMapping::default());
    for i in 0..100_000 {
        let x = i as f32 * 1e-5;
        model.push([x, x, x, 0.5], [-3.0; 4], 0.0, [0.5; 3]);
    }
    let mut grads = Gradients::zeros_like(&model, false);
    grads
        .colours
        .iter_mut()
        .enumerate()
        .for_each(|(i, g)| *g = (i % 7) as f32 * 1e-3);
    grads.means.iter_mut().for_each(|g| *g = [1e-3; 4]);
    let mut opt = Adam::new(&model);
    let rates = LearningRates::default().at(0, 30_000, 1.0);
    c.bench_function("adam_step_100k_full_colour", |bench| {
        bench.iter(|| opt.step(&mut model, &grads, &rates))
    });
}

fn iterations(c: &mut Criterion) {
    let data = train_scene::dataset(128, 96);
    let init = train_scene::points(24, 18, &[0.0, 0.5, 1.0]);
    let dir = tempfile::tempdir().unwrap();
    let mut config = TrainConfig {
        background: splat4d::train::Background::Colour([0.0; 3]),
        iterations: 20,
        checkpoint_every: 0,
        ..Default::default()
    };
    config.densify.enabled = false;
    let mut group = c.benchmark_group("train");
    group.sample_size(10);
    group.bench_function("20_iterations_batch4_128x96_1296_gaussians", |bench| {
        bench.iter(|| {
            train(
                &CpuBackend,
                &config,
                &data,
                &init,
                dir.path(),
                false,
                &mut NoHooks,
                &NoProgress,
            )
            .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, loss, adam, iterations);
criterion_main!(benches);
