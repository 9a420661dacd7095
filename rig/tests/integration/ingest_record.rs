//! The live recorder's device-independent parts: format negotiation, the frame clock, and
//! the writer, fed by a test camera behind the same `CameraSource` trait, read back by
//! ingest. The concurrent recorder records four simulated cameras at once, stops on
//! request, and stops everything when one camera fails. Without a device, recording fails
//! cleanly.

use crate::common;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use rig::ingest::{IngestOptions, ingest};
use rig::record::v4l2::yuyv_to_rgb;
use rig::record::{
    FormatOption, FrameClock, RecordConfig, RecordError, negotiate, record, record_source,
    record_sources,
};
use rig::sim::{Scene, SimSource};
use rig::source::{CameraSource, Frame, PixelLayout, SourceError};
use shared_types::atomic::temp_sibling;
use shared_types::progress::NoProgress;

/// A camera that films a moving bar at ~30 fps with timestamp jitter and one dropped frame.
struct TestCamera {
    index: usize,
    times: Vec<f64>,
}

impl TestCamera {
    fn new() -> Self {
        let mut times: Vec<f64> = (0..45)
            .map(|k| 12.5 + k as f64 / 30.0 + 0.0007 * ((k * 7919) % 11) as f64 / 11.0)
            .collect();
        times.remove(20);
        TestCamera { index: 0, times }
    }
}

impl CameraSource for TestCamera {
    fn name(&self) -> &str {
        "cam0"
    }
    fn frame_size(&self) -> (u32, u32) {
        (64, 48)
    }
    fn nominal_fps(&self) -> Option<f64> {
        Some(30.0)
    }
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        let Some(&t) = self.times.get(self.index) else {
            return Ok(None);
        };
        let mut data = vec![30u8; 64 * 48 * 3];
        let bar = self.index % 64;
        for y in 0..48 {
            data[(y * 64 + bar) * 3..(y * 64 + bar) * 3 + 3].copy_from_slice(&[250, 250, 250]);
        }
        self.index += 1;
        Ok(Some(Frame {
            index: self.index - 1,
            timestamp: t,
            width: 64,
            height: 48,
            layout: PixelLayout::Rgb8,
            data,
        }))
    }
}

#[test]
fn negotiation_prefers_mjpeg_at_the_wanted_size_and_rate() {
    let opt = |f: &[u8; 4], w, h, fps: &[f64]| FormatOption {
        fourcc: *f,
        width: w,
        height: h,
        fps: fps.to_vec(),
    };
    let offered = vec![
        opt(b"YUYV", 1280, 720, &[10.0]),
        opt(b"MJPG", 1280, 720, &[30.0, 60.0]),
        opt(b"MJPG", 640, 480, &[30.0]),
        opt(b"H264", 1920, 1080, &[30.0]),
    ];
    let want = RecordConfig {
        width: 1280,
        height: 720,
        fps: 60.0,
        ..Default::default()
    };
    let (choice, fps) = negotiate(&offered, &want).unwrap();
    assert_eq!((&choice.fourcc, choice.width, fps), (b"MJPG", 1280, 60.0));
    let want = RecordConfig {
        width: 1920,
        height: 1080,
        ..Default::default()
    };
    let (choice, _) = negotiate(&offered, &want).unwrap();
    assert_eq!(
        choice.width, 1280,
        "H264 is not supported; the closest supported size wins"
    );
    assert!(negotiate(&[opt(b"H264", 640, 480, &[30.0])], &want).is_none());
}

#[test]
fn the_frame_clock_counts_drops_and_ignores_repeats() {
    let mut c = FrameClock::new(100.0);
    assert_eq!(c.stamp(100, 500_000, Some(7)), Some(0.5));
    assert!((c.stamp(100, 533_333, Some(8)).unwrap() - 0.533333).abs() < 1e-9);
    assert_eq!(
        c.stamp(100, 533_333, Some(8)),
        None,
        "a repeated buffer is not a new frame"
    );
    assert!(c.stamp(100, 633_333, Some(11)).is_some());
    assert_eq!(c.dropped, 2);
}

#[test]
fn yuyv_converts_grey_and_colour() {
    let rgb = yuyv_to_rgb(&[235, 128, 16, 128], 2, 1);
    assert_eq!(rgb, vec![255, 255, 255, 0, 0, 0]);
}

#[test]
fn recorded_frames_keep_their_exact_timestamps_through_ingest() {
    let dir = tempfile::tempdir().unwrap();
    let cam_dir = dir.path().join("raw/cam0");
    let mut camera = TestCamera::new();
    let expected = camera.times.clone();
    let stop = AtomicBool::new(false);
    let rec = record_source(&mut camera, &cam_dir, &stop, None, &NoProgress).unwrap();
    assert_eq!(rec.frames, 44);
    assert!(
        cam_dir.join("capture.mov").exists()
            && !temp_sibling(&cam_dir.join("capture.mov")).exists()
    );
    let csv = std::fs::read_to_string(cam_dir.join("timestamps.csv")).unwrap();
    assert_eq!(csv.lines().count(), 45);
    let streams = ingest(
        &[("cam0".into(), cam_dir.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let c = &streams.cameras[0];
    assert_eq!(c.video.frame_count, 44);
    assert_eq!(c.video.gaps, 1, "the dropped frame shows as a gap");
    let max_err = c
        .timestamps
        .iter()
        .zip(&expected)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    println!(
        "recorder timestamp round trip: max error {:.3} µs",
        max_err * 1e6
    );
    assert!(max_err < 2e-6, "{max_err}");
}

#[test]
fn recording_without_a_device_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let missing = PathBuf::from("/dev/video-does-not-exist");
    let err = record(
        &[missing],
        dir.path(),
        &RecordConfig::default(),
        &stop,
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(err, RecordError::NoDevice(_)), "{err}");
    assert!(err.to_string().starts_with("no V4L2 device found"), "{err}");
    let err = record(
        &[],
        dir.path(),
        &RecordConfig::default(),
        &stop,
        &NoProgress,
    )
    .unwrap_err();
    assert!(err.to_string().contains("no V4L2 device found"), "{err}");
}

/// Counts the frames the recorder reports.
#[derive(Default)]
struct Counted(AtomicU64);

impl shared_types::Progress for Counted {
    fn start(&self, _: u64, _: &str) {}
    fn advance(&self, n: u64) {
        self.0.fetch_add(n, Ordering::SeqCst);
    }
    fn message(&self, _: &str) {}
    fn finish(&self) {}
}

#[test]
fn four_simulated_cameras_record_concurrently_on_one_clock() {
    // sync-audio.toml: four cameras started at different times with sub-frame phases;
    // cam2 also drops two frames.
    let mut table = common::fixture_table("sync-audio.toml");
    common::video_cam(&mut table, 2).insert("dropped".into(), toml::Value::from(vec![5, 6]));
    let scene = Scene::from_toml_str(&toml::to_string(&table).unwrap(), "sync-audio.toml").unwrap();
    let sources: Vec<Box<dyn CameraSource>> = SimSource::video_cameras(&scene)
        .unwrap()
        .into_iter()
        .map(|s| Box::new(s) as Box<dyn CameraSource>)
        .collect();
    assert_eq!(sources.len(), 4);
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let counted = Counted::default();
    let mut prompts = Vec::new();
    let recorded = record_sources(sources, dir.path(), None, &stop, &counted, &mut || {
        prompts.push(counted.0.load(Ordering::SeqCst))
    })
    .unwrap();
    assert_eq!(prompts.len(), 1, "the flash prompt fires exactly once");
    assert!(
        prompts[0] >= 4,
        "the prompt waits for every camera's first frame"
    );
    let per_camera = scene.frames_per_camera() as usize;
    let frames: Vec<usize> = recorded.iter().map(|r| r.frames).collect();
    assert_eq!(
        frames,
        vec![per_camera, per_camera, per_camera - 2, per_camera]
    );
    assert_eq!(
        counted.0.load(Ordering::SeqCst),
        frames.iter().sum::<usize>() as u64
    );

    let dirs: Vec<(String, PathBuf)> = recorded
        .iter()
        .map(|r| (r.name.clone(), r.dir.clone()))
        .collect();
    let streams = ingest(&dirs, &IngestOptions::default(), &NoProgress).unwrap();
    let origin = SimSource::origin(&scene);
    assert!(origin < 0.0, "cam3 starts before scene time 0");
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
        "simulated live cameras: worst timestamp error {:.3} µs",
        worst * 1e6
    );
    assert!(
        worst < 2e-6,
        "every frame keeps the shared clock's time: {worst}"
    );
    assert_eq!(
        streams.cameras[2].video.gaps, 1,
        "the two dropped frames are one gap"
    );
}

/// A camera that never ends, or fails at frame `fail_at`.
struct Endless {
    name: &'static str,
    next: usize,
    fail_at: Option<usize>,
}

impl CameraSource for Endless {
    fn name(&self) -> &str {
        self.name
    }
    fn frame_size(&self) -> (u32, u32) {
        (32, 24)
    }
    fn nominal_fps(&self) -> Option<f64> {
        Some(30.0)
    }
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        if self.fail_at == Some(self.next) {
            return Err(SourceError::Device {
                device: "/dev/video9".into(),
                message: "unplugged".into(),
            });
        }
        self.next += 1;
        std::thread::sleep(std::time::Duration::from_millis(2));
        Ok(Some(Frame {
            index: self.next - 1,
            timestamp: self.next as f64 / 30.0,
            width: 32,
            height: 24,
            layout: PixelLayout::Rgb8,
            data: vec![(self.next % 256) as u8; 32 * 24 * 3],
        }))
    }
}

#[test]
fn a_stop_request_ends_every_camera_with_complete_files() {
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let sources: Vec<Box<dyn CameraSource>> = ["cam0", "cam1"]
        .into_iter()
        .map(|name| {
            Box::new(Endless {
                name,
                next: 0,
                fail_at: None,
            }) as Box<dyn CameraSource>
        })
        .collect();
    let recorded = std::thread::scope(|scope| {
        scope.spawn(|| {
            std::thread::sleep(std::time::Duration::from_millis(300));
            stop.store(true, Ordering::Relaxed);
        });
        record_sources(sources, dir.path(), None, &stop, &NoProgress, &mut || {}).unwrap()
    });
    for rec in &recorded {
        assert!(rec.frames > 0, "{}", rec.name);
        assert!(rec.dir.join("capture.mov").exists() && rec.dir.join("timestamps.csv").exists());
        assert!(!temp_sibling(&rec.dir.join("capture.mov")).exists());
    }
}

#[test]
fn one_failing_camera_stops_the_others_and_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let stop = AtomicBool::new(false);
    let sources: Vec<Box<dyn CameraSource>> = vec![
        Box::new(Endless {
            name: "cam0",
            next: 0,
            fail_at: None,
        }),
        Box::new(Endless {
            name: "cam1",
            next: 0,
            fail_at: Some(10),
        }),
    ];
    let err =
        record_sources(sources, dir.path(), None, &stop, &NoProgress, &mut || {}).unwrap_err();
    assert!(
        matches!(&err, RecordError::Camera { camera, .. } if camera == "cam1"),
        "{err}"
    );
    let text = err.to_string();
    assert!(
        text.contains("unplugged") && text.contains("other cameras were stopped"),
        "{text}"
    );
    assert!(
        dir.path().join("raw/cam0/capture.mov").exists(),
        "the healthy camera's file is complete"
    );
}
