//! Frame re-alignment on encoded captures: the common timeline, nearest frames with their
//! residuals, dropped frames, resizing and the PNGs written.

use crate::sync_support;

use rig::frames::{FramesConfig, extract, plan, working_size};
use rig::ingest::{IngestOptions, ingest};
use rig::sync::{SyncConfig, synchronise};
use shared_types::progress::NoProgress;
use sync_support::{FLASH_T, TestCamera, ffmpeg_available, write_capture};

#[test]
fn working_size_keeps_the_aspect_ratio() {
    assert_eq!(working_size((1920, 1080), 960, false), (960, 540));
    assert_eq!(working_size((1080, 1920), 960, false), (540, 960));
    assert_eq!(working_size((640, 480), 960, false), (640, 480));
    assert_eq!(working_size((640, 480), 960, true), (960, 720));
}

#[test]
fn aligned_frames_are_written_with_exact_timestamps() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let starts = [0.0123, 0.2137, 0.4511, 0.0789];
    let mut cams: Vec<_> = starts.iter().map(|&s| TestCamera::new(s)).collect();
    cams[1].dropped = vec![30, 31, 32];
    let streams = ingest(
        &write_capture(&dir.path().join("raw"), &cams),
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let sync = synchronise(
        &streams,
        &SyncConfig {
            max_offset_s: 1.0,
            ..Default::default()
        },
        &NoProgress,
    )
    .unwrap();
    let config = FramesConfig {
        long_side: 48,
        ..Default::default()
    };
    let out = dir.path().join("work/frames");
    let index = extract(&streams, &sync, &config, &out, &NoProgress).unwrap();

    // Common timeline (cam0's clock): latest start (cam2) to earliest end (cam0).
    let start = starts[2] - starts[0];
    let end = (starts[0] + 119.0 / 30.0) - starts[0];
    assert!((index.start_s - start).abs() < 1e-3, "{}", index.start_s);
    assert_eq!(
        index.frames.len(),
        ((end - start) * 30.0 + 1e-9).floor() as usize + 1
    );
    assert_eq!((index.cameras[0].width, index.cameras[0].height), (48, 36));
    let mut max_residual = [0.0f64; 4];
    for f in &index.frames {
        for (c, v) in f.views.iter().enumerate() {
            assert!((v.timestamp_s - v.residual_s - f.time_s).abs() < 1e-9);
            max_residual[c] = max_residual[c].max(v.residual_s.abs());
            assert!(out.join(&v.file).exists(), "{}", v.file);
        }
    }
    println!(
        "max |residual| per camera (ms): {:?}",
        max_residual.map(|r| (r * 1e4).round() / 10.0)
    );
    // Without drops, the nearest frame is within half a frame; across the 3-frame drop of
    // cam1 it can be up to two frames away.
    for c in [0, 2, 3] {
        assert!(
            max_residual[c] <= 0.5 / 30.0 + 1e-6,
            "cam{c}: {}",
            max_residual[c]
        );
    }
    assert!(max_residual[1] > 0.5 / 30.0 && max_residual[1] <= 2.0 / 30.0 + 1e-3);

    // The flash turns on at the same output frame in every camera (±1 for sub-frame phase).
    let flash_frame = |c: usize| {
        index
            .frames
            .iter()
            .position(|f| {
                let img = image::open(out.join(&f.views[c].file)).unwrap().to_luma8();
                img.pixels().map(|p| f64::from(p.0[0])).sum::<f64>() / img.len() as f64 > 150.0
            })
            .unwrap()
    };
    let on: Vec<usize> = (0..4).map(flash_frame).collect();
    let expected = ((FLASH_T - starts[0] - index.start_s) * 30.0).ceil() as usize;
    println!("flash first seen at output frames {on:?} (nominal {expected})");
    assert!(on.iter().all(|&k| k.abs_diff(expected) <= 1), "{on:?}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("frames.json")).unwrap()).unwrap();
    assert_eq!(json["frames"].as_array().unwrap().len(), index.frames.len());

    // Planning alone agrees with what was written, and max_frames trims.
    let planned = plan(
        &streams,
        &sync,
        &FramesConfig {
            max_frames: Some(5),
            ..config
        },
    )
    .unwrap();
    assert_eq!(planned.frames.len(), 5);
    assert_eq!(planned.frames[4], index.frames[4]);
}
