//! A measuring tool, not a check: how close a simulated capture's `work/init/points.ply`
//! lies to the scene's true surfaces. Run on a demo capture (`pipeline demo`, then init):
//!
//! ```text
//! INIT_ACCURACY_CAPTURE=/tmp/tri-demo cargo test -p pipeline --test integration -- --ignored --nocapture init_accuracy::
//! ```
//!
//! The solved cameras are aligned to `groundtruth/cameras.json` by a similarity (camera
//! centres), each point is compared with the surfaces at its own time (scene time = common
//! timeline, as the simulator's reference camera starts at 0), and distances are in metres.

use std::path::PathBuf;

use glam::DVec3;
use rayon::prelude::*;

fn quantiles(mut v: Vec<f64>) -> String {
    if v.is_empty() {
        return "-".into();
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let q = |f: f64| v[((v.len() - 1) as f64 * f) as usize];
    let within = |d: f64| v.iter().filter(|x| **x < d).count() as f64 / v.len() as f64;
    format!(
        "n {}, median {:.4}, p90 {:.4} m; within 2 cm {:.0} %, 10 cm {:.0} %",
        v.len(),
        q(0.5),
        q(0.9),
        100.0 * within(0.02),
        100.0 * within(0.1)
    )
}

#[test]
#[ignore = "a measuring tool: set INIT_ACCURACY_CAPTURE"]
fn init_points_against_the_true_surfaces() {
    let Some(root) = std::env::var_os("INIT_ACCURACY_CAPTURE").map(PathBuf::from) else {
        eprintln!("set INIT_ACCURACY_CAPTURE to a simulated capture with a finished init");
        return;
    };
    let scene_file = std::env::var_os("INIT_ACCURACY_SCENE")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fixtures/demo.toml"));
    let scene = rig::sim::Scene::from_file(&scene_file).unwrap();
    let solved = calib::poses::PosesFile::read(&root.join("work/poses/cameras.json")).unwrap();
    let truth: shared_types::CameraSet = serde_json::from_str(
        &std::fs::read_to_string(root.join("groundtruth/cameras.json")).unwrap(),
    )
    .unwrap();
    let (src, dst): (Vec<DVec3>, Vec<DVec3>) = solved
        .set
        .cameras
        .iter()
        .filter_map(|c| {
            let t = truth.get(&c.name)?;
            Some((c.world_to_camera.centre(), t.world_to_camera.centre()))
        })
        .unzip();
    let sim = calib::similarity::umeyama(&src, &dst).unwrap();
    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    let units_per_second = index.fps / 30.0;
    let cloud = shared_types::points::read_points_ply(&root.join("work/init/points.ply")).unwrap();
    let n = cloud.xyz.len();
    let times = cloud.time.clone().unwrap_or_else(|| vec![0.0; n]);
    let spans = cloud.time_span.clone().unwrap_or_else(|| vec![0.0; n]);
    // Surfaces at each distinct point time (moments), built once.
    let mut distinct: Vec<f32> = times.clone();
    distinct.sort_by(|a, b| a.total_cmp(b));
    distinct.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
    let surfaces: Vec<(f32, Vec<[DVec3; 3]>)> = if distinct.len() > 64 {
        vec![(0.0, rig::sim::surface_triangles(&scene, index.start_s))]
    } else {
        distinct
            .iter()
            .map(|&t| {
                let s = t as f64 / units_per_second + index.start_s;
                (t, rig::sim::surface_triangles(&scene, s))
            })
            .collect()
    };
    let dist: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let p = sim.apply(DVec3::from_array(cloud.xyz[i].map(f64::from)));
            let tris = &surfaces
                .iter()
                .min_by(|a, b| (a.0 - times[i]).abs().total_cmp(&(b.0 - times[i]).abs()))
                .unwrap()
                .1;
            tris.iter()
                .map(|t| (rig::sim::closest_on_triangle(p, *t) - p).length())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let pick = |f: &dyn Fn(usize) -> bool| {
        (0..n)
            .filter(|&i| f(i))
            .map(|i| dist[i])
            .collect::<Vec<_>>()
    };
    eprintln!("{}: {n} points", root.display());
    eprintln!("  all:     {}", quantiles(dist.clone()));
    eprintln!("  static:  {}", quantiles(pick(&|i| spans[i] > 0.0)));
    eprintln!("  moving:  {}", quantiles(pick(&|i| spans[i] == 0.0)));
    for &t in &distinct {
        if distinct.len() > 12 {
            break;
        }
        let c = (0..n)
            .filter(|&i| spans[i] == 0.0 && (times[i] - t).abs() < 1e-6)
            .count();
        eprintln!("  moving points at t = {t:.3}: {c}");
    }
}
