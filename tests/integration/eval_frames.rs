//! Rendering a camera path to frames: colour, colour-mapped depth and alpha PNGs per
//! frame, the same colour frames handed to a sink (the MP4 writer's place), and a sink
//! error stopping the render.

use crate::eval_support;

use eval_support::*;
use splat4d::CpuBackend;
use splat4d::NoProgress;
use splat4d::eval::{EvalError, FrameOutputs, render_path};
use splat4d::trajectories::{PathKind, PathSpec, TimeMode, camera_path};

#[test]
fn an_orbit_renders_to_colour_depth_and_alpha_frames() {
    let model = scene();
    let mut spec = PathSpec::new(PathKind::Orbit, TimeMode::Sweep, 6);
    spec.size = Some((48, 32));
    let path = camera_path(&spec, &rig(64, 48), &[], &model.time).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut seen = Vec::new();
    let mut sink = |i: usize, img: &image::RgbImage| -> Result<(), String> {
        seen.push((i, img.clone()));
        Ok(())
    };
    let out = render_path(
        &CpuBackend,
        &model,
        &path,
        dir.path(),
        FrameOutputs::ALL,
        [0.0; 3],
        None,
        &NoProgress,
        Some(&mut sink),
    )
    .unwrap();
    assert_eq!(out.frames, 6);
    let (near, far) = out.depth_range.unwrap();
    assert!(
        near > 2.0 && far < 5.0 && near < far,
        "the scene sits ~3.5 away: {near}..{far}"
    );
    assert_eq!(seen.len(), 6);
    for (i, img) in &seen {
        let name = format!("{i:06}.png");
        let rgb = image::open(dir.path().join("rgb").join(&name))
            .unwrap()
            .to_rgb8();
        assert_eq!(&rgb, img, "the sink gets the frame written to disk");
        let depth = image::open(dir.path().join("depth").join(&name))
            .unwrap()
            .to_rgb8();
        let alpha = image::open(dir.path().join("alpha").join(&name))
            .unwrap()
            .to_luma8();
        assert_eq!((depth.width(), depth.height(), alpha.width()), (48, 32, 48));
        // Depth is coloured exactly where the scene covers the pixel, black elsewhere.
        let mut covered = 0;
        for ((d, a), c) in depth.pixels().zip(alpha.pixels()).zip(rgb.pixels()) {
            let coloured = d.0 != [0, 0, 0];
            assert_eq!(coloured, a.0[0] >= 128, "alpha {} depth {:?}", a.0[0], d.0);
            covered += coloured as usize;
            if a.0[0] == 0 {
                assert_eq!(c.0, [0, 0, 0], "black background where nothing is drawn");
            }
        }
        assert!(
            covered > 50 && covered < 48 * 32,
            "frame {i}: {covered} covered pixels"
        );
    }
    // Time sweeps: first and last frame differ.
    assert_ne!(seen[0].1, seen[5].1);
}

#[test]
fn a_failing_sink_stops_the_render() {
    let model = scene();
    let path = camera_path(
        &PathSpec::new(PathKind::Train, TimeMode::Fixed(0.2), 3),
        &rig(32, 24),
        &[],
        &model.time,
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut sink = |i: usize, _: &image::RgbImage| -> Result<(), String> {
        if i == 1 {
            Err("disk full".to_string())
        } else {
            Ok(())
        }
    };
    let e = render_path(
        &CpuBackend,
        &model,
        &path,
        dir.path(),
        FrameOutputs::NONE,
        [0.0; 3],
        None,
        &NoProgress,
        Some(&mut sink),
    )
    .unwrap_err();
    assert!(
        matches!(&e, EvalError::Sink { frame: 1, message } if message == "disk full"),
        "{e}"
    );
    assert!(
        std::fs::read_dir(dir.path()).unwrap().next().is_none(),
        "no folders without outputs"
    );
}
