//! Criterion benchmarks of the CPU renderer: forward and forward+backward at 512×384 for
//! 10k, 100k and 1M Gaussians with a realistic spread of sizes (log-normal scales around a
//! median of ~2 px at 100k, opacities spread over the sigmoid, full colour degrees).
//! Run: `cargo bench -p splat4d --bench render`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::{DMat3, DVec3};
use splat4d::model::ColourDegrees;
use splat4d::{Camera, Distortion, Gaussians, ImageGradients, Intrinsics, RenderOptions, TimeMapping, WorldToCamera, render_with};
use std::hint::black_box;

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
    fn normal(&mut self) -> f32 {
        let u1 = self.uniform().max(1e-7);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }
}

/// `n` Gaussians in a 3×3×3 box seen from 4 units away; the median scale shrinks with
/// √n so the image coverage (overdraw) stays similar across sizes.
pub fn scene(n: usize) -> Gaussians<f32> {
    let mut rng = Rng(42);
    let mut g = Gaussians::<f32>::new(ColourDegrees::FULL, TimeMapping::default());
    g.active = ColourDegrees::FULL;
    let median = 0.0146 * (100_000.0 / n as f32).sqrt();
    for _ in 0..n {
        let mean = [3.0 * rng.uniform() - 1.5, 3.0 * rng.uniform() - 1.5, 3.0 * rng.uniform() - 1.5, rng.uniform()];
        let ls = [
            median.ln() + 0.8 * rng.normal(),
            median.ln() + 0.8 * rng.normal(),
            median.ln() + 0.8 * rng.normal(),
            (0.3f32).ln() + 0.3 * rng.normal(),
        ];
        let i = g.push(mean, ls, 1.5 * rng.normal(), [rng.uniform(), rng.uniform(), rng.uniform()]);
        let q = [rng.normal(), rng.normal(), rng.normal(), rng.normal()];
        g.rot_left[i] = q;
        g.rot_right[i] = [q[0] + 0.1 * rng.normal(), q[1], q[2], q[3]];
        let k = g.coeffs_per_channel();
        for j in 3..3 * k {
            g.colours[i * 3 * k + j] = 0.05 * rng.normal();
        }
    }
    g
}

pub fn camera() -> Camera {
    let eye = DVec3::new(0.5, -4.5, 1.0);
    let z = (DVec3::ZERO - eye).normalize();
    let x = z.cross(DVec3::Z).normalize();
    let y = z.cross(x);
    let r = DMat3::from_cols(x, y, z).transpose();
    Camera {
        name: "bench".into(),
        intrinsics: Intrinsics::from_hfov(512, 384, 50.0),
        distortion: Distortion::None,
        world_to_camera: WorldToCamera::from_parts(r, -(r * eye)),
    }
}

fn bench(c: &mut Criterion) {
    let cam = camera();
    let opts = RenderOptions::<f32> { background: [0.0; 3], ..RenderOptions::default() };
    let d_rgb: Vec<f32> = (0..3 * 512 * 384).map(|i| ((i % 7) as f32 - 3.0) * 1e-3).collect();
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
                    r.visible_count(),
                    r.tile_pairs(),
                    r.blend_evaluations(),
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
            b.iter(|| {
                let r = render_with(m, &cam, 0.5, &opts).unwrap();
                black_box(r.backward(m, &ImageGradients { rgb: &d_rgb, alpha: None, depth: None }).unwrap())
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
