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

/// Manual sync with the cameras' known start times (scene clock) as offsets.
fn manual_sync(streams: &rig::ingest::Streams, starts: &[f64]) -> rig::sync::SyncResult {
    let config = SyncConfig {
        method: rig::sync::SyncMethod::Manual,
        manual_offsets: starts
            .iter()
            .enumerate()
            .map(|(i, s)| (format!("cam{i}"), s - starts[0]))
            .collect(),
        ..Default::default()
    };
    synchronise(streams, &config, &NoProgress).unwrap()
}

/// Cameras started far apart keep only the span where all of them film, and the index
/// says which cameras lost how much; cameras that never film together fail naming the
/// one that starts last and the one that stops first.
#[test]
fn cameras_that_film_together_only_partly() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let starts = [0.0, 2.0];
    let cams: Vec<_> = starts.iter().map(|&s| TestCamera::new(s)).collect();
    let streams = ingest(
        &write_capture(&dir.path().join("raw"), &cams),
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let config = FramesConfig {
        long_side: 48,
        ..Default::default()
    };
    let out = dir.path().join("work/frames");
    let index = extract(
        &streams,
        &manual_sync(&streams, &starts),
        &config,
        &out,
        &NoProgress,
    )
    .unwrap();
    // Each camera films 119/30 s; together from 2.0 s to 119/30 s on cam0's clock.
    assert!((index.start_s - 2.0).abs() < 1e-6, "{}", index.start_s);
    assert_eq!(
        index.frames.len(),
        ((119.0 / 30.0 - 2.0) * 30.0 + 1e-6) as usize + 1
    );
    assert!(
        index
            .frames
            .iter()
            .all(|f| f.views[1].residual_s.abs() < 1e-6)
    );
    assert_eq!(index.warnings.len(), 2, "{:?}", index.warnings);
    for (w, cam) in index.warnings.iter().zip(["cam0", "cam1"]) {
        assert!(w.starts_with(cam) && w.contains("cam1 starts last"), "{w}");
    }
    let written: rig::frames::FramesIndex =
        serde_json::from_str(&std::fs::read_to_string(out.join("frames.json")).unwrap()).unwrap();
    assert_eq!(written.warnings, index.warnings);

    let apart = [0.0, 5.0];
    let err = plan(&streams, &manual_sync(&streams, &apart), &config).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("cam1 starts at 5.000 s") && msg.contains("after cam0 has stopped"),
        "{msg}"
    );
}

/// A phone's variable frame rate (30 fps, then 10 fps in the dark) is matched frame by
/// frame on its own timestamps: each output frame takes the camera's nearest frame, at
/// most half that camera's local interval away, and the index warns about the camera
/// whose frames fall far from the output times, not about the steady one.
#[test]
fn variable_frame_rate_frames_keep_their_own_times() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("raw");
    let mut cameras = Vec::new();
    for (name, extra) in [
        ("cam0", vec![]),
        (
            "cam1",
            vec![
                "-vf",
                "settb=1/1000,setpts='if(lt(N,30),N/30,1+(N-30)/10)/TB'",
                "-fps_mode",
                "passthrough",
                "-enc_time_base",
                "1/1000",
            ],
        ),
    ] {
        let folder = raw.join(name);
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("clip.mkv").to_string_lossy().to_string();
        let mut args = vec![
            "-f",
            "lavfi",
            "-i",
            "testsrc2=size=96x72:rate=30",
            "-t",
            "3",
        ];
        args.extend_from_slice(&extra);
        args.extend_from_slice(&[
            "-pix_fmt",
            "yuv420p",
            "-c:v",
            "libx264",
            "-preset",
            "ultrafast",
        ]);
        args.push(&path);
        sync_support::ffmpeg(&args);
        cameras.push((name.to_string(), folder));
    }
    let streams = ingest(&cameras, &IngestOptions::default(), &NoProgress).unwrap();
    assert!(streams.cameras[1].video.variable_frame_rate);
    let out = dir.path().join("work/frames");
    let config = FramesConfig {
        long_side: 48,
        fps: Some(30.0),
        ..Default::default()
    };
    let index = extract(
        &streams,
        &manual_sync(&streams, &[0.0, 0.0]),
        &config,
        &out,
        &NoProgress,
    )
    .unwrap();
    let times = &streams.cameras[1].timestamps;
    let t0 = times[0];
    for f in &index.frames {
        let v = &f.views[1];
        assert_eq!(v.timestamp_s, times[v.source_frame], "frame {}", f.index);
        let local = if v.timestamp_s - t0 < 1.0 {
            1.0 / 30.0
        } else {
            1.0 / 10.0
        };
        assert!(
            v.residual_s.abs() <= 0.5 * local + 2e-3,
            "frame {}: residual {}",
            f.index,
            v.residual_s
        );
        assert!(out.join(&v.file).exists());
    }
    assert_eq!(index.warnings.len(), 1, "{:?}", index.warnings);
    assert!(
        index.warnings[0].starts_with("cam1:"),
        "{}",
        index.warnings[0]
    );
}
