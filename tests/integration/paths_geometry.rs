//! Camera paths: the orbit keeps its radius and height, every orbit/spiral view looks at
//! the scene centre, the interpolation passes exactly through the training cameras, and
//! the time modes map frames to the right model times.

use glam::DVec3;
use splat4d::trajectories::{PathError, PathKind, PathSpec, SceneFrame, TimeMode, camera_path};
use splat4d::{Camera, Distortion, Intrinsics, TimeMapping, WorldToCamera};

const CENTRE: DVec3 = DVec3::new(1.0, 2.0, 0.5);

/// Four cameras on a ring of radius 3 around `CENTRE`, at different heights and azimuths
/// (not evenly spread, like a real rig), all looking at the centre with z up.
fn rig() -> Vec<Camera> {
    [(0.3, 0.8), (1.5, 1.2), (2.9, 0.6), (4.4, 1.0)]
        .iter()
        .enumerate()
        .map(|(i, &(az, h)): (usize, &(f64, f64))| {
            let eye = CENTRE + DVec3::new(3.0 * az.cos(), 3.0 * az.sin(), h);
            Camera {
                name: format!("cam{i}"),
                intrinsics: Intrinsics::from_hfov(160, 120, 60.0),
                distortion: Distortion::None,
                world_to_camera: WorldToCamera::look_at(eye, CENTRE, DVec3::Z).unwrap(),
            }
        })
        .collect()
}

fn mapping() -> TimeMapping {
    TimeMapping::frames_over_30(0.0, 30.0, 2.0) // 2 s → model time 0..2
}

#[test]
fn scene_frame_finds_the_centre_and_up() {
    let f = SceneFrame::from_cameras(&rig()).unwrap();
    assert!((f.centre - CENTRE).length() < 1e-9, "{}", f.centre);
    // Cameras look slightly down, so their image-up leans; the average stays close to z.
    assert!(f.up.dot(DVec3::Z) > 0.95, "{}", f.up);
}

#[test]
fn orbit_keeps_radius_and_height_and_looks_at_the_centre() {
    let cams = rig();
    let mut spec = PathSpec::new(PathKind::Orbit, TimeMode::Fixed(0.5), 24);
    spec.size = Some((64, 48));
    let path = camera_path(&spec, &cams, &[], &mapping()).unwrap();
    assert_eq!(path.len(), 24);
    let f = SceneFrame::from_cameras(&cams).unwrap();
    let mut expected_r = 0.0;
    let mut expected_h = 0.0;
    for c in &cams {
        let d = c.world_to_camera.centre() - f.centre;
        expected_h += d.dot(f.up) / 4.0;
        expected_r += (d - d.dot(f.up) * f.up).length() / 4.0;
    }
    for (cam, t) in &path {
        assert_eq!((cam.intrinsics.width, cam.intrinsics.height), (64, 48));
        let d = cam.world_to_camera.centre() - f.centre;
        let h = d.dot(f.up);
        let r = (d - h * f.up).length();
        assert!((r - expected_r).abs() < 1e-9 && (h - expected_h).abs() < 1e-9);
        // The centre projects onto the principal point: the camera looks at it.
        let (px, depth) = cam.project(f.centre).unwrap();
        assert!((px.x - 32.0).abs() < 1e-9 && (px.y - 24.0).abs() < 1e-9 && depth > 0.0);
        assert!((t - 0.5).abs() < 1e-12);
    }
    // The first frame sits at the first camera's azimuth; the frames spread all around.
    let d0 = cams[0].world_to_camera.centre() - f.centre;
    let p0 = path[0].0.world_to_camera.centre() - f.centre;
    let flat = |v: DVec3| (v - v.dot(f.up) * f.up).normalize();
    assert!(flat(d0).dot(flat(p0)) > 1.0 - 1e-9);
    let half = path[12].0.world_to_camera.centre() - f.centre;
    assert!(flat(d0).dot(flat(half)) < -1.0 + 1e-9);
}

#[test]
fn spiral_looks_at_the_centre_from_varying_distances() {
    let cams = rig();
    let spec = PathSpec::new(PathKind::Spiral, TimeMode::Sweep, 40);
    let path = camera_path(&spec, &cams, &[], &mapping()).unwrap();
    let f = SceneFrame::from_cameras(&cams).unwrap();
    let dists: Vec<f64> = path
        .iter()
        .map(|(c, _)| (c.world_to_camera.centre() - f.centre).length())
        .collect();
    for (cam, _) in &path {
        let pc = cam.world_to_camera.apply(f.centre);
        assert!(pc.x.abs() < 1e-9 && pc.y.abs() < 1e-9 && pc.z > 0.0);
    }
    let (lo, hi) = dists
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &d| (a.min(d), b.max(d)));
    assert!(hi - lo > 0.3, "the spiral moves in and out: {lo}..{hi}");
}

#[test]
fn interpolate_hits_the_training_cameras_at_the_knots() {
    let cams = rig();
    let spec = PathSpec::new(PathKind::Interpolate, TimeMode::Sweep, 10);
    let path = camera_path(&spec, &cams, &[], &mapping()).unwrap();
    for (k, cam) in cams.iter().enumerate() {
        let (p, _) = &path[3 * k];
        let (a, b) = (&p.world_to_camera, &cam.world_to_camera);
        assert!((a.centre() - b.centre()).length() < 1e-9, "knot {k}");
        assert!(
            (a.rotation() - b.rotation())
                .abs()
                .to_cols_array()
                .iter()
                .all(|v| *v < 1e-9),
            "knot {k}"
        );
    }
    // Between knots the path is smooth: no jump larger than twice the mean step.
    let steps: Vec<f64> = path
        .windows(2)
        .map(|w| (w[1].0.world_to_camera.centre() - w[0].0.world_to_camera.centre()).length())
        .collect();
    let mean = steps.iter().sum::<f64>() / steps.len() as f64;
    assert!(steps.iter().all(|s| *s < 2.0 * mean), "{steps:?}");
    // Sweep covers the whole sequence.
    assert_eq!(path[0].1, 0.0);
    assert!((path[9].1 - 2.0).abs() < 1e-12);
}

#[test]
fn train_and_heldout_paths_reuse_the_cameras() {
    let cams = rig();
    let mut spec = PathSpec::new(PathKind::Train, TimeMode::Real, 8);
    spec.fps = 10.0;
    let path = camera_path(&spec, &cams, &[], &mapping()).unwrap();
    let names: Vec<&str> = path.iter().map(|(c, _)| c.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "cam0", "cam0", "cam1", "cam1", "cam2", "cam2", "cam3", "cam3"
        ]
    );
    assert_eq!(path[2].0.world_to_camera, cams[1].world_to_camera);
    // Real time at 10 fps: 0.1 s per frame = 0.1 model units (30 fps capture, t = frame/30).
    assert!((path[5].1 - 0.5).abs() < 1e-12);
    spec.kind = PathKind::Heldout;
    assert_eq!(
        camera_path(&spec, &cams, &[], &mapping()),
        Err(PathError::TooFewCameras {
            what: "heldout",
            needed: 1,
            got: 0
        })
    );
    let held = camera_path(&spec, &cams, &cams[2..3], &mapping()).unwrap();
    assert!(held.iter().all(|(c, _)| c.name == "cam2"));
}

#[test]
fn path_and_time_values_parse_like_the_cli_writes_them() {
    assert_eq!("orbit".parse(), Ok(PathKind::Orbit));
    assert_eq!("interpolate".parse(), Ok(PathKind::Interpolate));
    assert!("circle".parse::<PathKind>().is_err());
    assert_eq!("fixed:1.25".parse(), Ok(TimeMode::Fixed(1.25)));
    assert_eq!("sweep".parse(), Ok(TimeMode::Sweep));
    assert_eq!("real".parse(), Ok(TimeMode::Real));
    assert!("fixed:soon".parse::<TimeMode>().is_err());
    assert!("fixed:NaN".parse::<TimeMode>().is_err());
}

#[test]
fn bad_requests_are_typed_errors() {
    let cams = rig();
    assert_eq!(
        camera_path(
            &PathSpec::new(PathKind::Orbit, TimeMode::Sweep, 0),
            &cams,
            &[],
            &mapping()
        ),
        Err(PathError::NoFrames)
    );
    assert_eq!(
        camera_path(
            &PathSpec::new(PathKind::Interpolate, TimeMode::Sweep, 5),
            &cams[..1],
            &[],
            &mapping()
        ),
        Err(PathError::TooFewCameras {
            what: "interpolate",
            needed: 2,
            got: 1
        })
    );
    let mut spec = PathSpec::new(PathKind::Orbit, TimeMode::Sweep, 5);
    spec.size = Some((0, 10));
    assert!(matches!(
        camera_path(&spec, &cams, &[], &mapping()),
        Err(PathError::EmptySize { .. })
    ));
}
