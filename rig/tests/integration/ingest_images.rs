//! Image-sequence cameras: folders of numbered stills go through ingest, sync and frames
//! like videos, image `k` at `k / image_fps` seconds.

use std::path::{Path, PathBuf};

use rig::frames::{FramesConfig, extract};
use rig::ingest::{IngestError, IngestOptions, SourceKind, camera_files, ingest};
use rig::sync::{SyncConfig, SyncMethod, synchronise};
use shared_types::progress::NoProgress;

/// A 40×30 image of one colour; `value` encodes (camera, image).
fn write_image(path: &Path, size: (u32, u32), value: u8) {
    let data = vec![value; (size.0 * size.1 * 3) as usize];
    image::save_buffer(path, &data, size.0, size.1, image::ExtendedColorType::Rgb8).unwrap();
}

/// Camera folders `cam0..` holding `names`, camera `c`'s image `k` filled with 20c + 60k
/// (PNG is lossless, so the value comes back exactly).
fn write_sequences(root: &Path, cameras: usize, names: &[&str]) -> Vec<(String, PathBuf)> {
    (0..cameras)
        .map(|c| {
            let dir = root.join(format!("cam{c}"));
            std::fs::create_dir_all(&dir).unwrap();
            for (k, name) in names.iter().enumerate() {
                write_image(&dir.join(name), (40, 30), (20 * c + 60 * k) as u8);
            }
            (format!("cam{c}"), dir)
        })
        .collect()
}

#[test]
fn numbered_images_are_timed_by_image_fps_in_natural_order() {
    let dir = tempfile::tempdir().unwrap();
    // Names out of lexical order: img10 must come after img2.
    let cams = write_sequences(dir.path(), 3, &["img1.png", "img2.png", "img10.png"]);
    // A hidden leftover of an interrupted write is not an image of the sequence.
    write_image(&cams[0].1.join(".img3.tmp.png"), (40, 30), 0);
    let files = camera_files("cam0", &cams[0].1).unwrap();
    let names: Vec<_> = files
        .iter()
        .map(|p| p.file_name().unwrap().to_str().unwrap())
        .collect();
    assert_eq!(names, ["img1.png", "img2.png", "img10.png"]);

    let options = IngestOptions { image_fps: 2.0 };
    let streams = ingest(&cams, &options, &NoProgress).unwrap();
    for c in &streams.cameras {
        assert_eq!(c.kind, SourceKind::Images);
        assert_eq!(c.timestamps, [0.0, 0.5, 1.0]);
        assert_eq!((c.video.width, c.video.height), (40, 30));
        assert_eq!(c.video.frame_count, 3);
        assert!((c.video.fps - 2.0).abs() < 1e-12);
        assert!(c.audio.is_none());
    }
    // Stills have no sound: that is not worth a warning.
    assert!(streams.warnings.is_empty(), "{:?}", streams.warnings);

    // Auto sync takes image k of every camera as the same moment.
    let sync = synchronise(&streams, &SyncConfig::default(), &NoProgress).unwrap();
    assert_eq!(sync.method, SyncMethod::Timestamps);
    assert!(sync.cameras.iter().all(|c| c.offset_s == 0.0));
    assert!(sync.notes.iter().any(|n| n.contains("image sequence")));

    let out = dir.path().join("work/frames");
    let config = FramesConfig {
        long_side: 40,
        ..Default::default()
    };
    let index = extract(&streams, &sync, &config, &out, &NoProgress).unwrap();
    assert_eq!(index.frames.len(), 3);
    for (k, frame) in index.frames.iter().enumerate() {
        assert!((frame.time_s - 0.5 * k as f64).abs() < 1e-9);
        for (c, view) in frame.views.iter().enumerate() {
            assert_eq!(view.source_frame, k);
            let img = image::open(out.join(&view.file)).unwrap().to_rgb8();
            assert_eq!(img.dimensions(), (40, 30));
            let want = (20 * c + 60 * k) as i32;
            let got = img.get_pixel(20, 15)[0] as i32;
            assert!((got - want).abs() <= 1, "cam{c} image {k}: {got} != {want}");
        }
    }
}

#[test]
fn jpeg_sequences_decode_through_ffmpeg() {
    let dir = tempfile::tempdir().unwrap();
    let cam = dir.path().join("cam0");
    std::fs::create_dir_all(&cam).unwrap();
    for k in 0..2u8 {
        write_image(&cam.join(format!("{k:06}.jpg")), (64, 48), 40 + 100 * k);
    }
    let streams = ingest(
        &[("cam0".into(), cam)],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let c = &streams.cameras[0];
    assert_eq!(c.video.codec, "mjpeg");
    assert_eq!(c.timestamps, [0.0, 1.0 / 30.0]);
    let sync = synchronise(&streams, &SyncConfig::default(), &NoProgress).unwrap();
    let out = dir.path().join("frames");
    let index = extract(&streams, &sync, &FramesConfig::default(), &out, &NoProgress).unwrap();
    assert_eq!(index.frames.len(), 2);
    for (k, frame) in index.frames.iter().enumerate() {
        let img = image::open(out.join(&frame.views[0].file))
            .unwrap()
            .to_rgb8();
        let got = img.get_pixel(32, 24)[0] as i32;
        let want = 40 + 100 * k as i32;
        assert!((got - want).abs() <= 3, "image {k}: {got} != {want}");
    }
}

#[test]
fn bad_sequences_get_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let cams = write_sequences(dir.path(), 1, &["0.png", "1.png"]);
    let odd = cams[0].1.join("2.png");
    write_image(&odd, (30, 40), 0);
    let e = ingest(&cams, &IngestOptions::default(), &NoProgress).unwrap_err();
    assert!(matches!(e, IngestError::ImageSize { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("2.png") && msg.contains("30×40") && msg.contains("40×30"),
        "{msg}"
    );
    std::fs::remove_file(&odd).unwrap();

    let e = ingest(&cams, &IngestOptions { image_fps: 0.0 }, &NoProgress).unwrap_err();
    assert!(e.to_string().contains("image_fps"), "{e}");
}
