//! Criterion benchmarks of the wgpu renderer on the CPU benchmark's scenes (`render.rs`):
//! forward at 512×384 for 10k, 100k and 1M Gaussians, one view per call and a batch of 8
//! views per call (the eval path), plus 1M at 1352×1014 (the paper's resolution). Times
//! include uploading the model and reading the images back, as a caller sees them.
//!
//! `gpu_train_step`: forward + backward (a training step's render work; loss and optimiser
//! excluded) and the backward alone, from image gradients to parameter gradients read
//! back on the host. 2k Gaussians at 128×96 is the size a software adapter can run;
//! 10k–1M at 512×384 and 1M at 1352×1014 (the 25 ms target) are for real GPUs.
//!
//! `gpu_resident_step`: one whole training iteration as training runs it on the GPU
//! (`GpuAdam::train_step`: render → L1 + D-SSIM loss → backward → Adam on the resident
//! model, one view, only the loss read back), and the same with the view's pseudo view
//! (`…_pseudo_view`: a second render beside it, the comparison and its backward, as
//! training runs it from a quarter of the run on). 2k Gaussians at 128×96 for software
//! adapters; 100k and 1M at 1352×1014 for real GPUs.
//!
//! `SPLAT4D_GPU_PROFILE=1` first prints where one such iteration's device time goes,
//! kernel by kernel (`Gpu::profile`), at 100k and 1M (2k on software adapters).
//!
//! `gpu_loss`: the L1 + D-SSIM loss with its image gradient (upload of both images and
//! read-back of loss and gradient included), next to the CPU loss; `gpu_adam`: one Adam
//! step on resident parameters (gradients already on the device; waits for the device),
//! next to the CPU `Adam::step`. 128×96 and 2k Gaussians for software adapters, the rest
//! for real GPUs.
//!
//! Run: `cargo bench -p splat4d --bench render_gpu` (`SPLAT4D_GPU_SOFTWARE=1` to measure
//! a software adapter such as lavapipe; add `-- gpu_train_step/.*128x96` for its size,
//! `-- 'gpu_loss/.*128x96|gpu_adam/.*/2000$'` for the loss and Adam at theirs).

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use splat4d::gpu::AdapterPolicy;
use splat4d::render::gpu::GpuBackend;
use splat4d::render::{RenderBackend, ViewRequest};
use splat4d::train::dataset::ImageU8;
use splat4d::train::gpu::{GpuAdam, GpuImage, GpuTraining, StepResult, TrainView};
use splat4d::train::loss::image_loss;
use splat4d::train::optim::{Adam, GroupRates, LearningRates};
use splat4d::train::pseudo_view::{VirtualView, shifted_camera};
use splat4d::{Camera, Gaussians, Gradients, ImageGradients, RenderOptions};
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
    if std::env::var("SPLAT4D_GPU_PROFILE").is_ok_and(|v| v == "1") {
        profile_resident_steps(&gpu);
    }
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
    train_step(c, &gpu);
    resident_step(c, &gpu);
    loss(c, &gpu);
    adam(c, &gpu);
}

/// Run the uploads waiting in the queue and wait for the device (set-up done before timing).
fn settle(gpu: &GpuBackend) {
    gpu.gpu().queue.submit([]);
    gpu.wait().unwrap();
}

/// A smooth `w×h` test image and a noisy copy (values in [0, 1]).
fn image_pair(w: u32, h: u32) -> (Vec<f32>, Vec<f32>) {
    let n = 3 * (w * h) as usize;
    let a: Vec<f32> = (0..n)
        .map(|k| {
            let (x, y) = ((k / 3) as u32 % w, (k / 3) as u32 / w);
            0.5 + 0.4 * ((x as f32 * 0.07).sin() * (y as f32 * 0.05 + k as f32 % 3.0).cos())
        })
        .collect();
    let b = a
        .iter()
        .enumerate()
        .map(|(k, v)| (v + 0.05 * ((k * 7919 % 101) as f32 / 101.0 - 0.5)).clamp(0.0, 1.0))
        .collect();
    (a, b)
}

fn loss(c: &mut Criterion, gpu: &GpuBackend) {
    let mut group = c.benchmark_group("gpu_loss");
    group.sample_size(10);
    for (w, h) in [(128u32, 96u32), (512, 384), (1352, 1014)] {
        let (r, t) = image_pair(w, h);
        let mut g = vec![0.0f32; r.len()];
        let size = format!("{w}x{h}");
        group.bench_function(BenchmarkId::new("gpu", &size), |b| {
            b.iter(|| black_box(gpu.image_loss(&r, &t, (w, h), 0.2, Some(&mut g)).unwrap()))
        });
        group.bench_function(BenchmarkId::new("cpu", &size), |b| {
            b.iter(|| {
                black_box(image_loss(
                    &r,
                    &t,
                    w as usize,
                    h as usize,
                    0.2,
                    Some(&mut g),
                ))
            })
        });
    }
    group.finish();
}

fn adam(c: &mut Criterion, gpu: &GpuBackend) {
    let mut group = c.benchmark_group("gpu_adam");
    group.sample_size(10);
    let rates = LearningRates::default().at(10, 100, 2.0);
    for n in [2_000usize, 100_000, 1_000_000] {
        let model = std::cell::OnceCell::new();
        let get = || model.get_or_init(|| scene(n));
        // Set up once (as `resident_step`): the upload stays out of the timed iterations.
        let mut resident = None;
        group.bench_function(BenchmarkId::new("gpu_step", n), |b| {
            let on_gpu = resident.get_or_insert_with(|| {
                let m = get();
                let mut grads = Gradients::zeros_like(m, false);
                grads.colours.fill(1e-3);
                let on_gpu = GpuAdam::new(gpu, m).unwrap();
                on_gpu.set_gradients(gpu, &grads).unwrap();
                settle(gpu);
                on_gpu
            });
            b.iter(|| {
                on_gpu.step(gpu, &rates).unwrap();
                gpu.wait().unwrap();
            })
        });
        group.bench_function(BenchmarkId::new("cpu_step", n), |b| {
            let mut m = get().clone();
            let mut grads = Gradients::zeros_like(&m, false);
            grads.colours.fill(1e-3);
            let mut cpu = Adam::new(&m);
            b.iter(|| cpu.step(&mut m, &grads, &rates))
        });
    }
    group.finish();
}

/// The sizes `gpu_resident_step` times: 2k at 128×96 for software adapters, 100k and 1M
/// at 1352×1014 for real GPUs.
const RESIDENT_SIZES: [(usize, u32, u32); 3] = [
    (2_000, 128, 96),
    (100_000, 1352, 1014),
    (1_000_000, 1352, 1014),
];

/// One whole training iteration on the device, set up for `n` Gaussians and a `w×h` view
/// against a mid-grey target (which the model does not match anywhere), with or without
/// a pseudo view (a virtual camera beside the view: a second render, the comparison and
/// its backward).
struct ResidentStep {
    model: Gaussians<f32>,
    camera: Camera,
    target: GpuImage,
    adam: GpuAdam,
    rates: GroupRates,
    pseudo: Option<VirtualView>,
}

impl ResidentStep {
    fn new(gpu: &GpuBackend, n: usize, (w, h): (u32, u32), pseudo: bool) -> Self {
        let mut camera: Camera = camera();
        camera.intrinsics = camera.intrinsics.scaled_to(w, h);
        let model = scene(n);
        let target = gpu
            .upload_image(&ImageU8 {
                width: w,
                height: h,
                data: vec![128; 3 * (w * h) as usize],
            })
            .unwrap();
        let adam = GpuAdam::new(gpu, &model).unwrap();
        let rates = LearningRates::default().at(10, 100, 2.0);
        let pseudo = pseudo.then(|| {
            let shift = [0.15, 0.05];
            VirtualView {
                camera: shifted_camera(&camera, shift),
                shift,
                weight: 0.3,
            }
        });
        Self {
            model,
            camera,
            target,
            adam,
            rates,
            pseudo,
        }
    }

    /// One iteration; returns once its loss is read back.
    fn run(&mut self, gpu: &GpuBackend) -> StepResult {
        let views = [TrainView {
            camera: &self.camera,
            t: 0.5,
            target: &self.target,
            pseudo: self.pseudo.clone(),
        }];
        self.adam
            .train_step(gpu, &self.model, &views, [0.0; 3], 0.2, &self.rates)
            .unwrap()
    }
}

fn resident_step(c: &mut Criterion, gpu: &GpuBackend) {
    let mut group = c.benchmark_group("gpu_resident_step");
    group.sample_size(10);
    for (n, w, h) in RESIDENT_SIZES {
        // Set up once, on first use: criterion calls the routine once per sample, and a
        // fresh model's upload would land in the first timed iteration of each.
        for (pseudo, name) in [
            (false, format!("{w}x{h}")),
            (true, format!("{w}x{h}_pseudo_view")),
        ] {
            let mut step = None;
            group.bench_function(BenchmarkId::new(name, n), |b| {
                let step = step.get_or_insert_with(|| {
                    let step = ResidentStep::new(gpu, n, (w, h), pseudo);
                    settle(gpu);
                    step
                });
                b.iter(|| black_box(step.run(gpu)))
            });
        }
    }
    group.finish();
}

/// With `SPLAT4D_GPU_PROFILE=1`: where one resident training iteration's device time goes,
/// kernel by kernel ([`splat4d::gpu::Gpu::profile`]), at the sizes `gpu_resident_step`
/// times (the small one on software adapters only), next to the iteration's wall time;
/// where the kernels use subgroups, again with the fixed-order kernels.
fn profile_resident_steps(gpu: &GpuBackend) {
    if !gpu.gpu().can_profile() {
        eprintln!("profile: {}", gpu.gpu().profile(|| ()).unwrap_err());
        return;
    }
    let ordered = gpu
        .uses_subgroups()
        .then(|| GpuBackend::without_subgroups(AdapterPolicy::from_env()).unwrap());
    let backends = [("", Some(gpu)), (", fixed-order kernels", ordered.as_ref())];
    let sizes = RESIDENT_SIZES
        .into_iter()
        .filter(|&(n, ..)| (n == 2_000) == gpu.is_software());
    for (n, w, h) in sizes {
        for (what, backend) in backends {
            let Some(backend) = backend else { continue };
            let mut step = ResidentStep::new(backend, n, (w, h), false);
            // Warm up (the pool of scratch buffers fills), then the mean of a few.
            for _ in 0..3 {
                step.run(backend);
            }
            let repeats = 10;
            let started = std::time::Instant::now();
            let (_, profile) = backend
                .gpu()
                .profile(|| (0..repeats).for_each(|_| drop(step.run(backend))))
                .unwrap();
            let wall = started.elapsed().as_secs_f64() * 1e3 / repeats as f64;
            let profile = profile.per_repetition(repeats);
            println!(
                "profile: one resident training iteration, {n} Gaussians at {w}x{h}{what}: {wall:.2} ms wall, {:.2} ms in kernels (mean of {repeats})",
                profile.total_ms()
            );
            println!("{}", profile.table());
        }
    }
}

/// Fixed upstream gradients for a `w×h` image (any values do: the work does not depend
/// on them).
fn upstream(w: u32, h: u32) -> (Vec<f32>, Vec<f32>) {
    let npix = (w * h) as usize;
    let rgb = (0..3 * npix)
        .map(|i| ((i % 7) as f32 - 3.0) * 0.1)
        .collect();
    let alpha = (0..npix).map(|i| ((i % 5) as f32 - 2.0) * 0.05).collect();
    (rgb, alpha)
}

fn train_step(c: &mut Criterion, gpu: &GpuBackend) {
    let opts = RenderOptions::<f32>::default();
    let mut group = c.benchmark_group("gpu_train_step");
    group.sample_size(10);
    let sized = |w: u32, h: u32| {
        let mut cam: Camera = camera();
        cam.intrinsics = cam.intrinsics.scaled_to(w, h);
        cam
    };
    let cases = [
        (2_000usize, 128u32, 96u32),
        (10_000, 512, 384),
        (100_000, 512, 384),
        (1_000_000, 512, 384),
        (1_000_000, 1352, 1014),
    ];
    let models: Vec<(usize, std::cell::OnceCell<Gaussians<f32>>)> =
        [2_000, 10_000, 100_000, 1_000_000]
            .into_iter()
            .map(|n| (n, std::cell::OnceCell::new()))
            .collect();
    for (n, w, h) in cases {
        let cam = sized(w, h);
        let get = || {
            let (_, cell) = models
                .iter()
                .find(|(m, _)| *m == n)
                .expect("a model per size");
            cell.get_or_init(|| scene(n))
        };
        let (rgb, alpha) = upstream(w, h);
        let up = ImageGradients {
            rgb: &rgb,
            alpha: Some(&alpha),
            depth: None,
        };
        let size = format!("{w}x{h}");
        group.bench_function(
            BenchmarkId::new(format!("forward_backward_{size}"), n),
            |b| {
                let m = get();
                let mut grads = Gradients::zeros_like(m, false);
                b.iter(|| {
                    let frame = gpu.render(m, &cam, 0.5, &opts).unwrap();
                    gpu.backward(m, &frame, &up, &mut grads).unwrap();
                    black_box(&grads);
                })
            },
        );
        group.bench_function(BenchmarkId::new(format!("backward_{size}"), n), |b| {
            let m = get();
            let frame = gpu.render(m, &cam, 0.5, &opts).unwrap();
            let mut grads = Gradients::zeros_like(m, false);
            b.iter(|| {
                gpu.backward(m, &frame, &up, &mut grads).unwrap();
                black_box(&grads);
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
