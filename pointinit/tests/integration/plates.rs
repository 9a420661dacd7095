//! Static plates tell moving points from static ones by where they land on each moment's
//! moving pixels, in every camera that frames them.

use glam::DVec3;
use image::{Rgb, RgbImage};
use pointinit::plates::{MOTION_THRESHOLD, Plates};
use pointinit::statics::TimedPoint;
use pointinit::{Moment, ViewImage};
use shared_types::{Camera, CameraSet, Intrinsics, WorldToCamera};

const W: u32 = 80;
const H: u32 = 60;

fn rig() -> CameraSet {
    let eyes = [DVec3::new(4.0, 0.0, 1.0), DVec3::new(0.0, 4.0, 1.0)];
    CameraSet::new(
        eyes.iter()
            .enumerate()
            .map(|(i, eye)| Camera {
                name: format!("cam{i}"),
                intrinsics: Intrinsics::from_hfov(W, H, 60.0),
                distortion: Default::default(),
                world_to_camera: WorldToCamera::look_at(*eye, DVec3::ZERO, DVec3::Z).unwrap(),
            })
            .collect(),
    )
}

/// A grey frame of `camera` with a red disc of radius 4 px wherever `object` projects.
fn frame(camera: &Camera, object: Option<DVec3>) -> RgbImage {
    let mut img = RgbImage::from_pixel(W, H, Rgb([120, 120, 110]));
    if let Some((p, _)) = object.and_then(|o| camera.project(o)) {
        for (x, y, px) in img.enumerate_pixels_mut() {
            if (x as f64 + 0.5 - p.x).hypot(y as f64 + 0.5 - p.y) < 4.0 {
                *px = Rgb([220, 30, 30]);
            }
        }
    }
    img
}

#[test]
fn points_on_what_moves_are_moving_and_the_rest_static() {
    let dir = tempfile::tempdir().unwrap();
    let cameras = rig();
    // A ball flies across both cameras' views over nine frames (about 2.6 px a frame, so
    // no pixel shows it in more than a third of them).
    let across = DVec3::new(1.0, -1.0, 0.0).normalize();
    let ball = |k: usize| across * (-1.2 + 0.3 * k as f64) + DVec3::new(0.0, 0.0, 0.3);
    let mut plate_frames = Vec::new();
    let mut views_at = vec![Vec::new(); 9];
    for cam in &cameras.cameras {
        for (k, views) in views_at.iter_mut().enumerate() {
            let path = dir.path().join(format!("{}_{k}.png", cam.name));
            frame(cam, Some(ball(k))).save(&path).unwrap();
            let view = ViewImage {
                camera: cam.name.clone(),
                path,
                time: k as f64,
            };
            plate_frames.push(view.clone());
            views.push(view);
        }
    }
    let plates = Plates::new(&cameras, &plate_frames, MOTION_THRESHOLD).unwrap();
    assert_eq!(plates.len(), 2);
    let moments = vec![
        Moment {
            frame: 2,
            time: 2.0,
            views: views_at[2].clone(),
        },
        Moment {
            frame: 6,
            time: 6.0,
            views: views_at[6].clone(),
        },
    ];
    let point = |xyz: DVec3, moment: usize| TimedPoint {
        xyz,
        rgb: [0.0; 3],
        moment,
        time: moments[moment].time,
    };
    // Behind the ball in camera 0 only (on the line from camera 0 through the ball).
    let eye0 = DVec3::new(4.0, 0.0, 1.0);
    let behind_in_cam0 = eye0 + (ball(2) - eye0) * 1.3;
    let points = [
        point(ball(2), 0),                    // the ball where it is: moving
        point(ball(6), 1),                    // again at the second moment: moving
        point(ball(6), 0),                    // where the ball is only later: static now
        point(DVec3::new(0.0, 0.0, -0.5), 0), // the floor: static
        point(behind_in_cam0, 0),             // on the ball's pixels in one of two cameras
        point(DVec3::new(0.0, 0.0, 40.0), 1), // framed by neither camera: static
    ];
    let (is_static, fractions) = plates.static_tags(&points, &moments).unwrap();
    assert_eq!(is_static, [false, false, true, true, true, true]);
    assert_eq!(fractions.len(), 2);
    // A disc of radius 4 grown by 2 px: about π·6² of 80×60 pixels.
    for f in fractions {
        assert!(f > 0.015 && f < 0.035, "moving fraction {f}");
    }
}

#[test]
fn an_unreadable_frame_is_an_error_naming_it() {
    let cameras = rig();
    let missing = std::path::PathBuf::from("/nonexistent/cam0_0.png");
    let frames = [ViewImage {
        camera: "cam0".into(),
        path: missing.clone(),
        time: 0.0,
    }];
    let err = Plates::new(&cameras, &frames, MOTION_THRESHOLD)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("/nonexistent/cam0_0.png"), "{err}");
}
