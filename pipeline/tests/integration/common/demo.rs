//! The demo scene (`fixtures/demo.toml`) drawn by the simulator's mesh rasteriser (not by
//! the Gaussian renderer) as training and held-out datasets, for the long training
//! benchmarks (`train_demo.rs`, `decay_demo.rs`).

use rig::sim::{Scene, render_clean};
use shared_types::Camera;
use splat4d::CpuBackend;
use splat4d::TimeMapping;
use splat4d::train::{
    Dataset, ImageU8, PointCloud, TrainConfig, TrainHooks, TrainSummary, View, evaluate_psnr, train,
};
use splat4d::{Gaussians, load_model};
use std::path::Path;

/// The camera's image at scene time `t`, box-downsampled by `scale`, and its depth.
fn draw(scene: &Scene, cam: &Camera, t: f64, scale: usize) -> (View, Vec<f32>) {
    let r = render_clean(scene, &cam.name, t).expect("camera renders");
    let (w, h) = (r.width / scale, r.height / scale);
    let mut rgb = Vec::with_capacity(3 * w * h);
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f32; 3];
            for b in 0..scale {
                for a in 0..scale {
                    let c = r.color[(y * scale + b) * r.width + x * scale + a];
                    (0..3).for_each(|k| acc[k] += c[k] / (scale * scale) as f32);
                }
            }
            rgb.extend_from_slice(&acc);
        }
    }
    let image = ImageU8::from_f32(w as u32, h as u32, &rgb);
    let mut camera = cam.clone();
    camera.intrinsics = cam.intrinsics.scaled_to(w as u32, h as u32);
    (
        View {
            camera,
            time: 0.0,
            image,
        },
        r.depth,
    )
}

/// Training and held-out views of the demo scene plus a sparse point-map init.
pub fn demo_data(scale: usize) -> (Dataset, Dataset, PointCloud) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/demo.toml");
    let scene = Scene::from_file(&path).expect("demo scene");
    let (fps, duration) = (15.0, 2.4);
    let time_mapping = TimeMapping::frames_over_30(0.0, fps, duration);
    let frames = (duration * fps).round() as usize;
    let role = |c: &&rig::sim::SimCamera, r: &str| format!("{:?}", c.role) == r;
    let video: Vec<_> = scene.cameras.iter().filter(|c| role(c, "Video")).collect();
    let heldout: Vec<_> = scene
        .cameras
        .iter()
        .filter(|c| role(c, "Heldout"))
        .collect();
    assert_eq!((video.len(), heldout.len()), (4, 4));

    let mut views = Vec::new();
    let mut init = PointCloud {
        time: Some(Vec::new()),
        ..Default::default()
    };
    for k in (0..frames).step_by(3) {
        for c in &video {
            let t_s = (c.start_time + k as f64 / fps).clamp(0.0, duration);
            let (mut v, depth) = draw(&scene, &c.camera, t_s, scale);
            let model_t = time_mapping.model_time(t_s) as f32;
            v.time = model_t;
            if k % 12 == 0 {
                let i = &c.camera.intrinsics;
                let full_w = i.width as usize;
                for (p, &z) in depth.iter().enumerate().filter(|(p, _)| {
                    (p % full_w).is_multiple_of(12) && (p / full_w).is_multiple_of(12)
                }) {
                    if !z.is_finite() {
                        continue;
                    }
                    let (u, v_) = ((p % full_w) as f64 + 0.5, (p / full_w) as f64 + 0.5);
                    let z = z as f64;
                    let pc = [(u - i.cx) / i.fx * z, (v_ - i.cy) / i.fy * z, z];
                    let r = c.camera.world_to_camera.rotation().to_cols_array();
                    let t = c.camera.world_to_camera.translation().to_array();
                    let d = [pc[0] - t[0], pc[1] - t[1], pc[2] - t[2]];
                    let world: [f64; 3] =
                        std::array::from_fn(|a| (0..3).map(|b| r[3 * a + b] * d[b]).sum());
                    let (x, y) = ((p % full_w) / scale, (p / full_w) / scale);
                    let q = 3 * (y * v.image.width as usize + x);
                    init.xyz.push(world.map(|x| x as f32));
                    init.rgb
                        .push([v.image.data[q], v.image.data[q + 1], v.image.data[q + 2]]);
                    init.time.as_mut().unwrap().push(model_t);
                }
            }
            views.push(v);
        }
    }
    let mut held = Vec::new();
    for k in (1..frames).step_by(6) {
        for c in &heldout {
            let t_s = k as f64 / fps;
            let (mut v, _) = draw(&scene, &c.camera, t_s, scale);
            v.time = time_mapping.model_time(t_s) as f32;
            held.push(v);
        }
    }
    (
        Dataset {
            views,
            time_mapping,
        },
        Dataset {
            views: held,
            time_mapping,
        },
        init,
    )
}

/// The reference 4DGS schedule compressed to `iterations` (densify from 500/30k to
/// 15k/30k every 100, colour degree every 1000/30k, no opacity reset), checkpoints only at
/// the end.
pub fn train_config(iterations: u64) -> TrainConfig {
    let mut config = TrainConfig {
        background: splat4d::train::Background::Colour([0.0; 3]),
        iterations,
        checkpoint_every: 0,
        ..Default::default()
    };
    let s = iterations as f64 / 30_000.0;
    config.degree_every = ((1000.0 * s) as u64).max(1);
    config.densify.from_iteration = (500.0 * s) as u64;
    config.densify.until_iteration = (15_000.0 * s) as u64;
    config.densify.every = 100;
    config.densify.opacity_reset_every = 0;
    config
}

/// A model trained on the demo data, with its mean PSNR on the training and held-out views.
pub struct Trained {
    pub model: Gaussians<f32>,
    pub summary: TrainSummary,
    pub train_psnr: f64,
    pub held_psnr: f64,
}

/// Train `config` from `init` on `train_data` with `hooks` (outputs in `dir`), then measure
/// the model on the training views and on `held_data`.
pub fn train_and_measure(
    config: &TrainConfig,
    (train_data, held_data, init): (&Dataset, &Dataset, &PointCloud),
    dir: &Path,
    hooks: &mut dyn TrainHooks,
) -> Trained {
    let summary = train(
        &CpuBackend,
        config,
        train_data,
        init,
        dir,
        false,
        hooks,
        &shared_types::NoProgress,
    )
    .unwrap();
    let model = load_model(&summary.model_path).unwrap();
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let train_psnr = mean(
        evaluate_psnr(
            &CpuBackend,
            &model,
            train_data,
            config.background.resolve(train_data),
        )
        .unwrap(),
    );
    let held_psnr = mean(
        evaluate_psnr(
            &CpuBackend,
            &model,
            held_data,
            config.background.resolve(train_data),
        )
        .unwrap(),
    );
    Trained {
        model,
        summary,
        train_psnr,
        held_psnr,
    }
}
