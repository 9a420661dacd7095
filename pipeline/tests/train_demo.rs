//! Training on the demo scene (`fixtures/demo.toml`), drawn by the simulator's mesh
//! rasteriser (not by the Gaussian renderer): the 4 video cameras at every 3rd frame, each
//! at its own exact timestamp, at half resolution; initial points unprojected from their
//! depth maps (as a point-map initialisation would give). Reports held-out PSNR on the 4
//! held-out cameras at in-between frames, iterations/s, Gaussian count and peak memory.
//! Long: ignored by default. Run (numbers in BENCHMARKS.md, "Training"):
//! `TRAIN_DEMO_ITERS=1000 cargo test --release -p pipeline --test train_demo -- --ignored --nocapture`

use rig::sim::{Scene, render_clean};
use splat4d::train::{
    Dataset, ImageU8, NoHooks, PointCloud, TrainConfig, View, evaluate_psnr, train,
};
use splat4d::{Camera, NoProgress, TimeMapping, load_model};
use std::path::Path;

const SCALE: usize = 2;

/// The camera's image at scene time `t`, box-downsampled by `SCALE`, and its depth.
fn draw(scene: &Scene, cam: &Camera, t: f64) -> (View, Vec<f32>) {
    let r = render_clean(scene, &cam.name, t).expect("camera renders");
    let (w, h) = (r.width / SCALE, r.height / SCALE);
    let mut rgb = Vec::with_capacity(3 * w * h);
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f32; 3];
            for b in 0..SCALE {
                for a in 0..SCALE {
                    let c = r.color[(y * SCALE + b) * r.width + x * SCALE + a];
                    (0..3).for_each(|k| acc[k] += c[k] / (SCALE * SCALE) as f32);
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

fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .map(str::to_string)
        })
        .and_then(|l| {
            l.split_whitespace()
                .nth(1)
                .and_then(|v| v.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

#[test]
#[ignore = "trains for minutes; run explicitly for BENCHMARKS.md"]
fn demo_scene_trains_and_reports_held_out_psnr() {
    let iterations: u64 = std::env::var("TRAIN_DEMO_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/demo.toml");
    let scene = Scene::from_file(&path).expect("demo scene");
    let (fps, duration) = (15.0, 2.4);
    let time_mapping = TimeMapping::frames_over_30(0.0, fps, duration);
    let frames = (duration * fps).round() as usize;
    let video: Vec<_> = scene
        .cameras
        .iter()
        .filter(|c| format!("{:?}", c.role) == "Video")
        .collect();
    let heldout: Vec<_> = scene
        .cameras
        .iter()
        .filter(|c| format!("{:?}", c.role) == "Heldout")
        .collect();
    assert_eq!((video.len(), heldout.len()), (4, 4));

    let mut views = Vec::new();
    let mut init = PointCloud {
        time: Some(Vec::new()),
        ..Default::default()
    };
    for k in (0..frames).step_by(3) {
        for c in &video {
            // Each camera's frame k shows its own instant (offset and sub-frame phase).
            let t_s = (c.start_time + k as f64 / fps).clamp(0.0, duration);
            let (mut v, depth) = draw(&scene, &c.camera, t_s);
            let model_t = time_mapping.model_time(t_s) as f32;
            v.time = model_t;
            if k % 12 == 0 {
                // A sparse point map: every 12th full-resolution pixel with finite depth.
                let i = &c.camera.intrinsics;
                let full_w = i.width as usize;
                for (p, &z) in depth
                    .iter()
                    .enumerate()
                    .filter(|(p, _)| (p % full_w) % 12 == 0 && (p / full_w) % 12 == 0)
                {
                    if !z.is_finite() {
                        continue;
                    }
                    let (u, v_) = ((p % full_w) as f64 + 0.5, (p / full_w) as f64 + 0.5);
                    let z = z as f64;
                    let pc = [(u - i.cx) / i.fx * z, (v_ - i.cy) / i.fy * z, z];
                    // world = Rᵀ (p_cam − t); R column-major from glam.
                    let r = c.camera.world_to_camera.rotation().to_cols_array();
                    let t = c.camera.world_to_camera.translation().to_array();
                    let d = [pc[0] - t[0], pc[1] - t[1], pc[2] - t[2]];
                    // Rᵀ row a = column a of R = r[3a..3a+3].
                    let world: [f64; 3] =
                        std::array::from_fn(|a| (0..3).map(|b| r[3 * a + b] * d[b]).sum());
                    let (x, y) = ((p % full_w) / SCALE, (p / full_w) / SCALE);
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
            let (mut v, _) = draw(&scene, &c.camera, t_s);
            v.time = time_mapping.model_time(t_s) as f32;
            held.push(v);
        }
    }
    let train_data = Dataset {
        views,
        time_mapping,
    };
    let held_data = Dataset {
        views: held,
        time_mapping,
    };

    let mut config = TrainConfig {
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
    let dir = tempfile::tempdir().unwrap();
    let summary = train(
        &config,
        &train_data,
        &init,
        dir.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();
    let model = load_model(&summary.model_path).unwrap();
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let train_psnr = mean(evaluate_psnr(&model, &train_data, config.background).unwrap());
    let held_psnr = mean(evaluate_psnr(&model, &held_data, config.background).unwrap());
    let v0 = &train_data.views[0].image;
    println!(
        "demo {}x{}: {} train views, {} held-out views, {} initial points, {iterations} iterations (batch {}): \
         {:.0} s, {:.3} it/s, {} Gaussians, train PSNR {train_psnr:.2} dB, held-out PSNR {held_psnr:.2} dB, peak RSS {:.0} MiB",
        v0.width,
        v0.height,
        train_data.views.len(),
        held_data.views.len(),
        init.xyz.len(),
        config.batch_size,
        summary.seconds,
        iterations as f64 / summary.seconds,
        model.len(),
        peak_rss_mib()
    );
    assert!(
        train_psnr.is_finite() && held_psnr > 12.0,
        "held-out PSNR {held_psnr:.2} dB"
    );
}
