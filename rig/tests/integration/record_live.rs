//! The live recorder path that nokhwa cameras take, fed by the simulator: each simulated
//! camera delivers its frames as a webcam would (MJPEG, YUYV, NV12 or BGR buffers with the
//! backend's Unix capture times) through a capture thread into a [`LiveSource`], and the
//! concurrent recorder writes them; ingest reads back every frame at its exact time. Also:
//! a camera that stalls, changes size or fails stops the recording with a clear error, and
//! asking for nokhwa in a build without it (or with no camera) fails cleanly. The test
//! that needs a real webcam is ignored.

use crate::common;

use std::sync::atomic::AtomicBool;
use std::sync::mpsc;
use std::time::Duration;

use rig::ingest::{IngestOptions, ingest};
use rig::record::live::{LiveSource, RawFrame};
use rig::record::{RecordConfig, RecordError, record_nokhwa, record_sources};
use rig::sim::{Scene, SimSource};
use rig::source::{CameraSource, SourceError};
use shared_types::progress::NoProgress;

/// BT.601 limited-range YCbCr of one RGB pixel.
fn ycbcr(p: &[u8]) -> [f32; 3] {
    let [r, g, b] = [p[0], p[1], p[2]].map(f32::from);
    [
        16.0 + 0.257 * r + 0.504 * g + 0.098 * b,
        128.0 - 0.148 * r - 0.291 * g + 0.439 * b,
        128.0 + 0.439 * r - 0.368 * g - 0.071 * b,
    ]
}

fn byte(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// RGB8 as a webcam buffer of `fourcc` (the inverse of the recorder's conversion).
fn camera_buffer(fourcc: &[u8; 4], rgb: &[u8], w: usize, h: usize) -> Vec<u8> {
    match fourcc {
        b"MJPG" => {
            let img = image::RgbImage::from_raw(w as u32, h as u32, rgb.to_vec()).unwrap();
            let mut jpeg = Vec::new();
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
                .encode_image(&img)
                .unwrap();
            jpeg
        }
        b"YUYV" => rgb
            .chunks_exact(6)
            .flat_map(|two| {
                let (a, b) = (ycbcr(&two[..3]), ycbcr(&two[3..]));
                [a[0], (a[1] + b[1]) / 2.0, b[0], (a[2] + b[2]) / 2.0].map(byte)
            })
            .collect(),
        b"NV12" => {
            let yuv: Vec<[f32; 3]> = rgb.chunks_exact(3).map(ycbcr).collect();
            let mut out: Vec<u8> = yuv.iter().map(|p| byte(p[0])).collect();
            for y in (0..h).step_by(2) {
                for x in (0..w).step_by(2) {
                    let quad = [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)];
                    let mean =
                        |c: usize| quad.iter().map(|&(i, j)| yuv[j * w + i][c]).sum::<f32>() / 4.0;
                    out.extend([byte(mean(1)), byte(mean(2))]);
                }
            }
            out
        }
        b"BGR3" => rgb
            .chunks_exact(3)
            .flat_map(|p| [p[2], p[1], p[0]])
            .collect(),
        other => panic!("no test encoder for {other:?}"),
    }
}

/// A Unix time for the session's origin (any will do; this one is in 2023).
const ORIGIN: Duration = Duration::from_secs(1_700_000_000);

/// A simulated camera behind a capture thread, as the nokhwa source runs a webcam: the
/// thread renders each frame, packs it as `fourcc` and stamps it with the capture time the
/// backend would report (Unix time), arriving 4 ms later. Frame 3 comes twice (a repeated
/// buffer the source must skip).
fn simulated_webcam(mut sim: SimSource, fourcc: [u8; 4]) -> LiveSource {
    let (w, h) = sim.frame_size();
    let fps = sim.nominal_fps().unwrap();
    let name = sim.name().to_string();
    let (tx, rx) = mpsc::sync_channel(4);
    std::thread::spawn(move || {
        while let Ok(Some(frame)) = sim.next_frame() {
            let captured = ORIGIN + Duration::from_secs_f64(frame.timestamp);
            let raw = RawFrame {
                fourcc,
                width: w,
                height: h,
                data: camera_buffer(&fourcc, &frame.data, w as usize, h as usize),
                captured: Some(captured),
                arrived: captured + Duration::from_millis(4),
            };
            let copies = if frame.index == 3 { 2 } else { 1 };
            for _ in 0..copies {
                if tx.send(Ok::<_, SourceError>(raw.clone())).is_err() {
                    return;
                }
            }
        }
    });
    LiveSource::new(&name, &format!("simulated {name}"), (w, h), fps, ORIGIN, rx)
}

#[test]
fn four_simulated_webcams_record_through_the_live_source_at_their_capture_times() {
    // sync-audio.toml: four cameras started at different times with sub-frame phases;
    // cam2 also drops two frames.
    let mut table = common::fixture_table("sync-audio.toml");
    common::video_cam(&mut table, 2).insert("dropped".into(), toml::Value::from(vec![5, 6]));
    let scene = Scene::from_toml_str(&toml::to_string(&table).unwrap(), "sync-audio.toml").unwrap();
    let formats = [*b"MJPG", *b"YUYV", *b"NV12", *b"BGR3"];
    let sources: Vec<Box<dyn CameraSource>> = SimSource::video_cameras(&scene)
        .unwrap()
        .into_iter()
        .zip(formats)
        .map(|(sim, fourcc)| Box::new(simulated_webcam(sim, fourcc)) as Box<dyn CameraSource>)
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let mut prompts = 0;
    let recorded = record_sources(sources, dir.path(), None, &stop, &NoProgress, &mut || {
        prompts += 1
    })
    .unwrap();
    assert_eq!(prompts, 1, "the flash prompt fires once every camera runs");
    let per_camera = scene.frames_per_camera() as usize;
    let frames: Vec<usize> = recorded.iter().map(|r| r.frames).collect();
    assert_eq!(
        frames,
        vec![per_camera, per_camera, per_camera - 2, per_camera],
        "repeated buffers are skipped, dropped frames are missing"
    );

    let dirs: Vec<(String, std::path::PathBuf)> = recorded
        .iter()
        .map(|r| (r.name.clone(), r.dir.clone()))
        .collect();
    let streams = ingest(&dirs, &IngestOptions::default(), &NoProgress).unwrap();
    let origin = SimSource::origin(&scene);
    let mut worst = 0.0f64;
    for (cam, truth) in streams.cameras.iter().zip(scene.video_cameras()) {
        let expected: Vec<f64> = (0..scene.frames_per_camera())
            .filter(|k| !truth.dropped.contains(k))
            .map(|k| truth.start_time - origin + k as f64 / scene.fps())
            .collect();
        assert_eq!(cam.timestamps.len(), expected.len(), "{}", cam.name);
        for (a, b) in cam.timestamps.iter().zip(&expected) {
            worst = worst.max((a - b).abs());
        }
    }
    println!(
        "simulated webcams through the live source: worst timestamp error {:.3} µs",
        worst * 1e6
    );
    assert!(worst < 2e-6, "every frame keeps its capture time: {worst}");
    assert_eq!(streams.cameras[2].video.gaps, 1, "the dropped frames show");

    // The pixels survive each camera format (chroma subsampling and two JPEG passes cost
    // a little): compare the first recorded frame with the simulator's.
    let mut sims = SimSource::video_cameras(&scene).unwrap();
    for (rec, sim) in recorded.iter().zip(sims.iter_mut()) {
        let truth = sim.next_frame().unwrap().unwrap().data;
        let (_, got) = common::video_frames(&rec.dir.join("capture.mov")).remove(0);
        let mean = got
            .iter()
            .zip(&truth)
            .map(|(a, b)| f64::from(a.abs_diff(*b)))
            .sum::<f64>()
            / truth.len() as f64;
        println!("{}: mean abs pixel difference {mean:.2}", rec.name);
        assert!(mean < 8.0, "{}: {mean}", rec.name);
    }
}

/// A source whose capture thread sends `frames` and then waits (or hangs up).
fn scripted(frames: Vec<Result<RawFrame, SourceError>>, hang_up: bool) -> LiveSource {
    let (tx, rx) = mpsc::sync_channel(8);
    for f in frames {
        tx.send(f).unwrap();
    }
    if hang_up {
        drop(tx);
    } else {
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_secs(5));
            drop(tx);
        });
    }
    LiveSource::new("cam0", "#0 Test Cam", (4, 2), 30.0, ORIGIN, rx)
        .with_timeout(Duration::from_millis(200))
}

fn grey(width: u32, height: u32, at_s: f64) -> RawFrame {
    let t = ORIGIN + Duration::from_secs_f64(at_s);
    RawFrame {
        fourcc: *b"GREY",
        width,
        height,
        data: vec![128; (width * height) as usize],
        captured: Some(t),
        arrived: t,
    }
}

#[test]
fn a_stalled_camera_times_out_naming_the_device() {
    let mut source = scripted(vec![Ok(grey(4, 2, 0.1))], false);
    assert!(source.next_frame().unwrap().is_some());
    let err = source.next_frame().unwrap_err().to_string();
    assert!(
        err.starts_with("camera device #0 Test Cam: no frame for 0.2 s")
            && err.contains("still connected"),
        "{err}"
    );
}

#[test]
fn a_camera_that_changes_size_or_fails_stops_with_its_reason() {
    let mut source = scripted(vec![Ok(grey(4, 2, 0.1)), Ok(grey(8, 2, 0.2))], true);
    assert!(source.next_frame().unwrap().is_some());
    let err = source.next_frame().unwrap_err().to_string();
    assert!(err.contains("switched from 4x2 to 8x2"), "{err}");

    let failing = scripted(
        vec![
            Ok(grey(4, 2, 0.1)),
            Err(SourceError::Device {
                device: "#0 Test Cam".into(),
                message: "Could not capture frame: unplugged; check the cable".into(),
            }),
        ],
        true,
    );
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let err = record_sources(
        vec![Box::new(failing)],
        dir.path(),
        None,
        &stop,
        &NoProgress,
        &mut || {},
    )
    .unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(&err, RecordError::Camera { camera, .. } if camera == "cam0")
            && text.contains("#0 Test Cam: Could not capture frame: unplugged"),
        "{text}"
    );
}

fn record_camera_zero(dir: &std::path::Path) -> Result<(), RecordError> {
    let stop = AtomicBool::new(false);
    record_nokhwa(
        &["0".into()],
        dir,
        &RecordConfig::default(),
        &stop,
        &NoProgress,
    )
    .map(|_| ())
}

#[cfg(not(feature = "nokhwa"))]
#[test]
fn recording_through_nokhwa_in_a_build_without_it_says_how_to_build_it() {
    let dir = tempfile::tempdir().unwrap();
    let err = record_camera_zero(dir.path()).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, RecordError::NokhwaNotBuilt { .. }), "{text}");
    assert!(text.contains("--features nokhwa"), "{text}");
    assert!(!dir.path().join("raw").exists(), "nothing written");
}

#[cfg(feature = "nokhwa")]
#[test]
fn recording_through_nokhwa_without_a_camera_fails_cleanly() {
    if !rig::record::nokhwa::list_cameras()
        .unwrap_or_default()
        .is_empty()
    {
        return; // a machine with a webcam: the ignored test below records from it
    }
    let dir = tempfile::tempdir().unwrap();
    let err = record_camera_zero(dir.path()).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, RecordError::NoCamera { .. }), "{text}");
    assert!(text.contains("no camera #0"), "{text}");
    assert!(!dir.path().join("raw").exists(), "nothing written");
}

/// Records two seconds from the first webcam nokhwa lists and reads it back.
#[cfg(feature = "nokhwa")]
#[test]
#[ignore = "needs a webcam: run `cargo test -p rig --features nokhwa --test integration -- --ignored record_live::` on a machine with one"]
fn a_real_webcam_records_through_nokhwa() {
    let cameras = rig::record::nokhwa::list_cameras().unwrap();
    let first = cameras.first().expect("no webcam is connected");
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let config = RecordConfig {
        width: 640,
        height: 480,
        duration_s: Some(2.0),
        flash_prompt: false,
        ..Default::default()
    };
    let recorded = record_nokhwa(
        &[first.index.to_string()],
        dir.path(),
        &config,
        &stop,
        &NoProgress,
    )
    .unwrap();
    assert!(recorded[0].frames > 10, "{recorded:?}");
    let streams = ingest(
        &[("cam0".into(), recorded[0].dir.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let t = &streams.cameras[0].timestamps;
    assert!(t.windows(2).all(|w| w[1] > w[0]), "timestamps increase");
    assert!(t[t.len() - 1] - t[0] < 2.2, "{t:?}");
}
