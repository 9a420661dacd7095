//! Point init by triangulation at several moments with the TRUE cameras (the situation of
//! an imported calibration: no COLMAP solve, no sparse points), on `fixtures/tiny.toml`
//! (a moving crate, a waving flag, a static ball in a room). Checked against the
//! simulator's true surfaces and its moving-object masks. Needs COLMAP (skipped without
//! it, except under CI=true).

use crate::common;

use common::sim_moments::{FPS, median, moments, on_moving_mask, simulate, surface_distance};
use glam::DVec3;
use pointinit::{InitConfig, InitInputs, Source, UsedSource, run_init};
use shared_types::NoProgress;

/// Aligned frames used as moments (tiny: 15 frames at 15 fps, cameras start together).
const FRAMES: [usize; 3] = [0, 7, 14];

fn colmap_or_skip() -> bool {
    if common::colmap_available() {
        return true;
    }
    let ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
    assert!(!ci, "COLMAP is required under CI");
    false
}

#[test]
fn moments_triangulated_with_true_cameras_lie_on_the_true_surfaces() {
    if !colmap_or_skip() {
        return;
    }
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
        source: Source::Triangulate,
        moments: FRAMES.len(),
        ..InitConfig::default()
    };
    let out = c.dir.join("init");
    let start = std::time::Instant::now();
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    let seconds = start.elapsed().as_secs_f64();
    assert_eq!(report.source, UsedSource::Triangulated, "{report:#?}");
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    let (times, spans) = (cloud.time.unwrap(), cloud.time_span.unwrap());
    let s = &report.statics;
    eprintln!(
        "{:.1} s; points per moment {:?}; static {} (from {} tagged), moving {} (from {})",
        seconds,
        report.moments.iter().map(|m| m.points).collect::<Vec<_>>(),
        s.static_points,
        s.static_tagged,
        s.dynamic_points,
        s.dynamic_tagged
    );
    assert_eq!(report.moments.len(), FRAMES.len());
    for m in &report.moments {
        assert!(m.error.is_none() && m.points >= 30, "{m:?}");
    }

    // Static points: on the true surfaces (measured: median 6 mm; one pixel ≈ 7 mm at 3 m).
    let triangles = rig::sim::surface_triangles(&c.scene, 0.0);
    let xyz = |i: usize| DVec3::from_array(cloud.xyz[i].map(f64::from));
    let statics: Vec<f64> = (0..cloud.xyz.len())
        .filter(|&i| spans[i] > 0.0)
        .map(|i| surface_distance(&triangles, xyz(i)))
        .collect();
    let med = median(statics.clone());
    eprintln!("static points: median distance to the true surfaces {med:.4} m");
    assert!(s.static_points >= 30 && med < 0.015, "{med}");
    let clip = (FRAMES[2] - FRAMES[0]) as f32 / FPS as f32;
    for i in (0..spans.len()).filter(|&i| spans[i] > 0.0) {
        // Centre of a span within the clip.
        assert!(spans[i] <= clip + 1e-4 && times[i] - spans[i] / 2.0 >= -1e-4);
        assert!(times[i] + spans[i] / 2.0 <= clip + 1e-4);
    }

    // Moving points at later moments: on the moving objects' masks at their time, and on
    // the surfaces of that time.
    let mut later = 0;
    let mut on_mask = 0;
    let mut dists = Vec::new();
    for &n in FRAMES.iter().skip(1) {
        let t = n as f64 / c.fps;
        let tris = rig::sim::surface_triangles(&c.scene, t);
        for i in (0..spans.len()).filter(|&i| spans[i] == 0.0 && (times[i] as f64 - t).abs() < 1e-4)
        {
            later += 1;
            if on_moving_mask(&c, xyz(i), n) {
                on_mask += 1;
                dists.push(surface_distance(&tris, xyz(i)));
            }
        }
    }
    eprintln!(
        "later moments: {later} moving points, {on_mask} on the moving masks, median distance {:.4} m",
        if dists.is_empty() {
            f64::NAN
        } else {
            median(dists.clone())
        }
    );
    assert!(on_mask >= 40, "{on_mask} of {later}");
    assert!(median(dists) < 0.015);
    // Static tagging: the room is mostly static.
    assert!(s.static_tagged > 2 * (s.dynamic_tagged - on_mask.min(s.dynamic_tagged)));
}
