//! Sync on real MP4 files (H.264 + AAC, made with ffmpeg) of a scene with a clap and a
//! flash, filmed by cameras with known start times.

use crate::sync_support;

use rig::ingest::{IngestOptions, ingest};
use rig::sync::{SyncConfig, SyncError, SyncMethod, synchronise};
use shared_types::progress::NoProgress;
use sync_support::{Mic, TestCamera, ffmpeg_available, write_capture};

const STARTS: [f64; 4] = [0.0123, 0.2137, 0.4511, 0.0789];

fn config() -> SyncConfig {
    SyncConfig {
        max_offset_s: 1.0,
        ..Default::default()
    }
}

/// Offset errors (s) against the truth `offset_i = start_i − start_0`.
fn errors(result: &rig::sync::SyncResult, starts: &[f64]) -> Vec<f64> {
    result
        .cameras
        .iter()
        .zip(starts)
        .map(|(c, s)| c.offset_s - (s - starts[0]))
        .collect()
}

#[test]
fn auto_uses_audio_when_every_camera_hears_the_clap() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cams: Vec<_> = STARTS.iter().map(|&s| TestCamera::new(s)).collect();
    let streams = ingest(
        &write_capture(dir.path(), &cams),
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let result = synchronise(&streams, &config(), &NoProgress).unwrap();
    assert_eq!(result.method, SyncMethod::Audio);
    assert!(
        result
            .notes
            .iter()
            .any(|n| n.contains("around the clap at 1.48")),
        "{:?}",
        result.notes
    );
    for (i, e) in errors(&result, &STARTS).iter().enumerate() {
        println!(
            "audio (AAC in MP4): cam{i} error {:.2} µs, confidence {:?}",
            e * 1e6,
            result.cameras[i].confidence
        );
        assert!(e.abs() < 1e-4, "cam{i}: {e}");
    }
    // Timestamps on the common timeline: local + offset.
    let c1 = &result.cameras[1];
    assert!((c1.timestamps[0] - (streams.cameras[1].timestamps[0] + c1.offset_s)).abs() < 1e-12);
}

#[test]
fn a_silent_camera_makes_auto_fall_back_to_flash() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // A 180° shutter: every frame integrates light for half a frame interval.
    let exposure = 0.5 / 30.0;
    let mut cams: Vec<_> = STARTS
        .iter()
        .map(|&s| TestCamera {
            exposure,
            ..TestCamera::new(s)
        })
        .collect();
    cams[2].mic = Mic::Silent;
    cams[3].mic = Mic::None;
    cams[1].dropped = vec![50, 51, 52, 80];
    let streams = ingest(
        &write_capture(dir.path(), &cams),
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    assert_eq!(streams.cameras[1].video.gaps, 2);
    let result = synchronise(
        &streams,
        &SyncConfig {
            exposure_s: exposure,
            ..config()
        },
        &NoProgress,
    )
    .unwrap();
    assert_eq!(result.method, SyncMethod::Flash);
    assert!(
        result
            .notes
            .iter()
            .any(|n| n.contains("cam2") && n.contains("silent")),
        "{:?}",
        result.notes
    );
    for (i, e) in errors(&result, &STARTS).iter().enumerate() {
        println!("flash, global shutter: cam{i} error {:.2} ms", e * 1e3);
        assert!(e.abs() < 0.5 / 30.0, "cam{i}: {e}");
    }
}

#[test]
fn rolling_shutter_flash_is_timed_to_milliseconds() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let readout = 0.030;
    let cams: Vec<_> = STARTS
        .iter()
        .map(|&s| TestCamera {
            readout,
            size: (64, 240),
            ..TestCamera::new(s)
        })
        .collect();
    let streams = ingest(
        &write_capture(dir.path(), &cams),
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let config = SyncConfig {
        method: SyncMethod::Flash,
        readout_s: readout,
        ..config()
    };
    let result = synchronise(&streams, &config, &NoProgress).unwrap();
    for (i, e) in errors(&result, &STARTS).iter().enumerate() {
        println!("flash, rolling shutter: cam{i} error {:.3} ms", e * 1e3);
        assert!(e.abs() < 2e-3, "cam{i}: {e}");
    }
}

#[test]
fn no_clap_and_no_flash_fails_with_an_explanation() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cams: Vec<_> = STARTS[..2]
        .iter()
        .map(|&s| TestCamera {
            flash: false,
            mic: Mic::None,
            ..TestCamera::new(s)
        })
        .collect();
    let streams = ingest(
        &write_capture(dir.path(), &cams),
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let err = synchronise(&streams, &config(), &NoProgress).unwrap_err();
    let msg = err.to_string();
    println!("{msg}");
    assert!(matches!(err, SyncError::NoMethod(_)));
    assert!(
        msg.contains("no audio track") && msg.contains("flash") && msg.contains("manual"),
        "{msg}"
    );
    // Timestamps and manual methods still work.
    let manual = SyncConfig {
        method: SyncMethod::Manual,
        manual_offsets: [("cam1".to_string(), 0.25)].into_iter().collect(),
        ..config()
    };
    let r = synchronise(&streams, &manual, &NoProgress).unwrap();
    assert_eq!(r.cameras[1].offset_s, 0.25);
    let bad = SyncConfig {
        manual_offsets: [("cam9".to_string(), 0.1)].into_iter().collect(),
        ..manual
    };
    assert!(
        synchronise(&streams, &bad, &NoProgress)
            .unwrap_err()
            .to_string()
            .contains("cam9")
    );
}
