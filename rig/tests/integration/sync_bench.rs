//! Speed and accuracy on one minute of 4-camera 1080p30 footage (H.264 + AAC), made here
//! with ffmpeg. Ignored by default (it encodes 4 minutes of 1080p first); run with
//! `cargo test --release -p rig --test integration -- --ignored --nocapture sync_bench::`.
//! Prints timings; asserts only accuracy.

use crate::sync_support;

use std::time::Instant;

use rig::frames::{FramesConfig, extract};
use rig::ingest::{IngestOptions, ingest};
use rig::sync::{SyncConfig, SyncMethod, synchronise};
use shared_types::progress::NoProgress;
use sync_support::{cut, ffmpeg, ffmpeg_available};

#[test]
#[ignore = "benchmark: encodes 4 minutes of 1080p footage"]
fn one_minute_of_four_1080p_cameras() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let seconds = std::env::var("SYNC_BENCH_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    let starts = [0.0, 0.3137, 1.0511, 0.6789];
    // Master scene: moving test pattern, a white flash from 20 s to 21 s, shared room noise
    // with a clap (one ~21 ms frame of noise 40× louder) at about 15 s.
    let master = dir.path().join("master.mov");
    let total = format!("{}", seconds + 2.0);
    let video = "testsrc2=size=1920x1080:rate=30,drawbox=enable='between(t,20,21)':c=white:t=fill";
    let audio = "anoisesrc=color=pink:amplitude=0.02:seed=7:sample_rate=48000,\
                 volume=enable='between(t,15,15.03)':volume=40";
    let m = master.to_string_lossy().to_string();
    let t0 = Instant::now();
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        video,
        "-f",
        "lavfi",
        "-i",
        audio,
        "-t",
        &total,
        "-c:v",
        "libx264",
        "-preset",
        "ultrafast",
        "-qp",
        "18",
        "-c:a",
        "pcm_s16le",
        &m,
    ]);
    let mut cams = Vec::new();
    for (i, s) in starts.iter().enumerate() {
        let cam = dir.path().join(format!("cam{i}"));
        std::fs::create_dir_all(&cam).unwrap();
        let (ss, t) = (format!("{s}"), format!("{seconds}"));
        cut(&master, &ss, &t, &cam.join("GX010001.MP4"));
        cams.push((format!("cam{i}"), cam));
    }
    println!(
        "footage: {seconds} s × 4 cameras, 1920x1080 30 fps, encoded in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    let per_minute = 60.0 / seconds;
    // Offset error of every camera against the true start, milliseconds.
    let errors_ms = |r: &rig::sync::SyncResult| -> Vec<f64> {
        r.cameras
            .iter()
            .zip(&starts)
            .map(|(c, s)| (c.offset_s - s) * 1e3)
            .collect()
    };

    let t = Instant::now();
    let streams = ingest(&cams, &IngestOptions::default(), &NoProgress).unwrap();
    let ingest_s = t.elapsed().as_secs_f64();
    println!(
        "ingest: {ingest_s:.2} s ({:.2} s per minute of footage)",
        ingest_s * per_minute
    );

    let t = Instant::now();
    for c in &streams.cameras {
        rig::ingest::decode_audio(c).unwrap();
    }
    println!(
        "audio decoding alone: {:.2} s per minute of footage",
        t.elapsed().as_secs_f64() * per_minute
    );
    let config = SyncConfig {
        max_offset_s: 2.0,
        ..Default::default()
    };
    let no_clap = SyncConfig {
        audio: rig::sync::audio::AudioSyncConfig {
            use_clap: false,
            max_excerpt_s: 30.0,
            ..Default::default()
        },
        ..config.clone()
    };
    let t = Instant::now();
    let r = synchronise(
        &streams,
        &SyncConfig {
            method: SyncMethod::Audio,
            ..no_clap
        },
        &NoProgress,
    )
    .unwrap();
    let errs = errors_ms(&r);
    println!(
        "sync Audio without clap window (30 s excerpt): {:.2} s per minute of footage; errors (ms) {errs:?}",
        t.elapsed().as_secs_f64() * per_minute
    );
    for method in [SyncMethod::Audio, SyncMethod::Flash] {
        let t = Instant::now();
        let r = synchronise(
            &streams,
            &SyncConfig {
                method,
                ..config.clone()
            },
            &NoProgress,
        )
        .unwrap();
        println!("{method:?} notes: {:?}", r.notes);
        let secs = t.elapsed().as_secs_f64();
        let errs = errors_ms(&r);
        println!(
            "sync {method:?}: {secs:.2} s ({:.2} s per minute of footage); offset errors (ms) {:?}",
            secs * per_minute,
            errs.iter()
                .map(|e| (e * 1000.0).round() / 1000.0)
                .collect::<Vec<_>>()
        );
        // The truth here is only as exact as ffmpeg's cutting of the master (a fraction of a
        // millisecond); sub-sample accuracy is checked with exact truth in sync_audio.rs and
        // sync_files.rs.
        let bound = if method == SyncMethod::Audio {
            1.0
        } else {
            1000.0 / 30.0
        };
        assert!(errs.iter().all(|e| e.abs() < bound), "{errs:?}");
        if method == SyncMethod::Audio {
            let t = Instant::now();
            let out = dir.path().join("frames");
            let index = extract(&streams, &r, &FramesConfig::default(), &out, &NoProgress).unwrap();
            let secs = t.elapsed().as_secs_f64();
            println!(
                "frames: {} × 4 PNGs at 960x540 in {secs:.1} s ({:.1} s per minute of footage)",
                index.frames.len(),
                secs * per_minute
            );
        }
    }
}
