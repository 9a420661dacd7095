//! Point init by plane-sweep stereo at several moments with the TRUE cameras (an imported
//! calibration: no COLMAP, no point maps), on `fixtures/tiny.toml` at 480×360 (a moving
//! crate, a waving flag, a static ball in a room). Checked against the simulator's true
//! surfaces and its moving-object masks. Needs no external binary.

use crate::common;

use common::sim_moments::{FPS, median, moments, on_moving_mask, simulate, surface_distance};
use glam::DVec3;
use pointinit::{InitConfig, InitInputs, Source, StillImage, UsedSource, run_init};
use shared_types::NoProgress;

/// Aligned frames used as moments (tiny: 15 frames at 15 fps, cameras start together).
const FRAMES: [usize; 2] = [0, 14];

#[test]
fn swept_points_lie_on_the_true_surfaces_and_moving_ones_on_the_moving_objects() {
    let c = simulate();
    let inputs = InitInputs {
        cameras: c.cameras.clone(),
        images: vec![],
        sparse: None,
        moments: moments(&c, &FRAMES),
        plate_frames: Vec::new(),
        stills: Vec::new(),
    };
    let config = InitConfig {
        source: Source::Sweep,
        moments: FRAMES.len(),
        ..InitConfig::default()
    };
    let out = c.dir.join("init");
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Swept, "{report:#?}");
    assert!(report.fallbacks.is_empty(), "{:?}", report.fallbacks);
    assert_eq!(report.sweeps.len(), FRAMES.len());
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    let (times, spans) = (cloud.time.unwrap(), cloud.time_span.unwrap());
    let s = &report.statics;
    eprintln!(
        "sweeps {:?}; static {} (from {} tagged), moving {} (from {})",
        report.sweeps, s.static_points, s.static_tagged, s.dynamic_points, s.dynamic_tagged
    );
    let xyz = |i: usize| DVec3::from_array(cloud.xyz[i].map(f64::from));

    // Static points: dense and on the true surfaces.
    let triangles = rig::sim::surface_triangles(&c.scene, 0.0);
    let statics: Vec<f64> = (0..cloud.xyz.len())
        .filter(|&i| spans[i] > 0.0)
        .map(|i| surface_distance(&triangles, xyz(i)))
        .collect();
    let med = median(statics.clone());
    let mut sorted = statics.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    eprintln!(
        "percentiles 10/25/50/75/90: {:?}",
        [10, 25, 50, 75, 90].map(|q| sorted[q * sorted.len() / 100])
    );
    let near = statics.iter().filter(|d| **d < 0.03).count() as f64 / statics.len() as f64;
    eprintln!(
        "{} static points: median distance to the true surfaces {med:.4} m, {:.1} % within 3 cm",
        statics.len(),
        100.0 * near
    );
    assert!(statics.len() >= 20_000, "{}", statics.len());
    assert!(med < 0.02 && near > 0.8, "{med} {near}");

    // Moving points at the last moment: on the moving objects' masks and on their surfaces.
    let n = FRAMES[1];
    let t = n as f64 / FPS;
    let tris = rig::sim::surface_triangles(&c.scene, t);
    let later: Vec<usize> = (0..spans.len())
        .filter(|&i| spans[i] == 0.0 && (times[i] as f64 - t).abs() < 1e-4)
        .collect();
    let on_mask: Vec<f64> = later
        .iter()
        .filter(|&&i| on_moving_mask(&c, xyz(i), n))
        .map(|&i| surface_distance(&tris, xyz(i)))
        .collect();
    eprintln!(
        "last moment: {} moving points, {} on the moving masks, median distance {:.4} m",
        later.len(),
        on_mask.len(),
        median(on_mask.clone())
    );
    assert!(on_mask.len() >= 200, "{} of {}", on_mask.len(), later.len());
    assert!(median(on_mask) < 0.015);

    // `auto` sweeps first: it needs no COLMAP (none here), and triangulation is not tried.
    let auto = InitConfig {
        moments: 1,
        colmap: Some(c.dir.join("no-such-colmap")),
        ..InitConfig::default()
    };
    let report = run_init(&inputs, &auto, &c.dir.join("auto"), &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Swept, "{report:#?}");
    assert_eq!(report.sweeps.len(), 1);
    assert!(
        report
            .fallbacks
            .iter()
            .any(|f| f.contains("sweeping moments")),
        "{:?}",
        report.fallbacks
    );
    assert!(report.moments.is_empty(), "{:?}", report.moments);
    assert!(report.points_written > 20_000, "{}", report.points_written);
}

#[test]
fn stills_add_static_points_on_the_true_surfaces() {
    let c = simulate();
    let gt: shared_types::CameraSet = serde_json::from_str(
        &std::fs::read_to_string(c.dir.join("capture/groundtruth/cameras.json")).unwrap(),
    )
    .unwrap();
    let stills: Vec<StillImage> = gt
        .cameras
        .iter()
        .filter(|cam| cam.name.starts_with("still"))
        .map(|cam| StillImage {
            camera: cam.clone(),
            path: c.dir.join(format!("capture/stills/{}.jpg", cam.name)),
        })
        .collect();
    assert!(stills.len() >= 4, "{}", stills.len());
    let moments = moments(&c, &FRAMES);
    // The two moments' frames make each camera's static plate.
    let plate_frames = moments.iter().flat_map(|m| m.views.clone()).collect();
    let inputs = InitInputs {
        cameras: c.cameras.clone(),
        images: vec![],
        sparse: None,
        moments,
        plate_frames,
        stills,
    };
    let config = InitConfig {
        source: Source::Sweep,
        moments: FRAMES.len(),
        sweep_size: 160,
        ..InitConfig::default()
    };
    let out = c.dir.join("init-stills");
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    let still_sweep = report.still_sweep.clone().expect("the stills were swept");
    eprintln!("{still_sweep:?}; {:?}", report.statics);
    // The stills' points are static extras, dropped only beside a moving point.
    let s = &report.statics;
    assert!(still_sweep.points > 10_000, "{still_sweep:?}");
    assert_eq!(s.sparse_merged + s.sparse_dropped, still_sweep.points);
    assert!(s.sparse_dropped < still_sweep.points / 10, "{s:?}");
    // Static points' (count, median distance to the true surfaces, share within 3 cm).
    let triangles = rig::sim::surface_triangles(&c.scene, 0.0);
    let accuracy = |dir: &std::path::Path| {
        let cloud = shared_types::points::read_points_ply(&dir.join("points.ply")).unwrap();
        let spans = cloud.time_span.unwrap();
        let statics: Vec<f64> = (0..cloud.xyz.len())
            .filter(|&i| spans[i] > 0.0)
            .map(|i| surface_distance(&triangles, DVec3::from_array(cloud.xyz[i].map(f64::from))))
            .collect();
        let near = statics.iter().filter(|d| **d < 0.03).count() as f64 / statics.len() as f64;
        (statics.len(), median(statics), near)
    };
    // Without the stills the same moments give fewer static points, as accurate.
    let without_dir = c.dir.join("init-no-stills");
    let without = run_init(
        &InitInputs {
            stills: Vec::new(),
            ..inputs
        },
        &config,
        &without_dir,
        &NoProgress,
    )
    .unwrap();
    assert!(without.still_sweep.is_none());
    let (n, med, near) = accuracy(&out);
    let (n0, med0, near0) = accuracy(&without_dir);
    eprintln!(
        "static points: {n} with the stills, median {med:.4} m from the true surfaces, {:.1} % within 3 cm; \
         {n0} without, {med0:.4} m, {:.1} %",
        100.0 * near,
        100.0 * near0
    );
    assert!(
        n as f64 > 1.3 * n0 as f64,
        "{n} with the stills, {n0} without"
    );
    // The stills' points are a little less accurate than the moments' (at this size the
    // stills' partners are closer together than the rig's cameras), still on the surfaces.
    assert!(med < 0.02 && near > 0.7, "{med} {near}");
}
