//! Ingest of real video files made with ffmpeg: plain files, GoPro chapters, variable
//! frame rate / dropped frames, mismatch warnings, error messages, audio decoding, and a
//! real 4-camera recording made with Caliscope when it is present. That recording is not
//! part of the repository: the test looks for `caliscope-4cam/calibration/extrinsic/` (videos
//! `cam_0.mp4` … `cam_3.mp4` and Caliscope's `timestamps.csv`, one row per frame with the
//! camera in the second column and its time in the third) in `shared/data/` beside the
//! checkout or in `/work/shared/data/`, and skips when it is absent.

use crate::sync_support;

use std::path::{Path, PathBuf};

use rig::ingest::{IngestError, IngestOptions, Streams, camera_files, decode_audio, ingest};
use shared_types::atomic::temp_sibling;
use shared_types::progress::NoProgress;
use sync_support::{H264_AAC, cut, ffmpeg, ffmpeg_available};

/// testsrc2 + a 440 Hz sine, `seconds` long, at `fps` and `size`.
fn clip(path: &Path, seconds: f64, fps: u32, size: &str, extra: &[&str]) {
    let v = format!("testsrc2=size={size}:rate={fps}");
    let t = format!("{seconds}");
    let mut args = vec![
        "-f",
        "lavfi",
        "-i",
        &v,
        "-f",
        "lavfi",
        "-i",
        "sine=f=440:sample_rate=48000",
        "-t",
        &t,
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["-pix_fmt", "yuv420p"]);
    args.extend_from_slice(&H264_AAC);
    let p = path.to_string_lossy().to_string();
    args.push(&p);
    ffmpeg(&args);
}

#[test]
fn a_plain_file_reports_frames_timestamps_and_audio() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cam = dir.path().join("cam0");
    std::fs::create_dir_all(&cam).unwrap();
    clip(&cam.join("clip.mp4"), 2.0, 30, "320x240", &[]);
    let streams = ingest(
        &[("cam0".into(), cam.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let c = &streams.cameras[0];
    assert_eq!(
        (c.video.width, c.video.height, c.video.frame_count),
        (320, 240, 60)
    );
    assert!((c.video.fps - 30.0).abs() < 1e-6);
    assert!(!c.video.variable_frame_rate);
    assert_eq!(c.video.gaps, 0);
    for (k, t) in c.timestamps.iter().enumerate() {
        assert!((t - k as f64 / 30.0).abs() < 1e-3, "frame {k} at {t}");
    }
    let audio = c.audio.as_ref().unwrap();
    assert_eq!((audio.sample_rate, audio.channels), (48_000, 1));
    let track = decode_audio(c).unwrap().unwrap();
    println!(
        "audio: {} samples from {:.4} s",
        track.samples.len(),
        track.start_s
    );
    assert!(
        (track.samples.len() as f64 / 48_000.0 - 2.0).abs() < 0.03,
        "{}",
        track.samples.len()
    );
    let rms =
        (track.samples.iter().map(|v| v * v).sum::<f32>() / track.samples.len() as f32).sqrt();
    assert!(rms > 0.05, "the sine is decoded: rms {rms}");
    // streams.json round trip, written atomically.
    let json = dir.path().join("work/ingest/streams.json");
    streams.write_json(&json).unwrap();
    assert_eq!(Streams::read_json(&json).unwrap(), streams);
    assert!(!temp_sibling(&json).exists());
}

#[test]
fn gopro_chapters_are_joined_in_order() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.mp4");
    clip(&whole, 3.0, 30, "160x120", &["-g", "15"]);
    let cam = dir.path().join("cam0");
    std::fs::create_dir_all(&cam).unwrap();
    // Chapter 2 sorts before chapter 1 by name only if numbers were ignored: GX02 < GX01 is false,
    // so name them so that a wrong (recording-first) order would be visible.
    for (name, from, len) in [("GX010042.MP4", "0", "1.5"), ("GX020042.MP4", "1.5", "1.5")] {
        cut(&whole, from, len, &cam.join(name));
    }
    let files = camera_files("cam0", &cam).unwrap();
    let names: Vec<_> = files
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().to_string())
        .collect();
    assert_eq!(names, ["GX010042.MP4", "GX020042.MP4"]);
    let streams = ingest(
        &[("cam0".into(), cam.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let c = &streams.cameras[0];
    assert_eq!(c.chapters.len(), 2);
    assert_eq!(c.video.frame_count, 90);
    assert!(
        (c.chapters[1].offset_s - 1.5).abs() < 0.02,
        "{:?}",
        c.chapters
    );
    let d: Vec<f64> = c.timestamps.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(
        d.iter().all(|d| (d - 1.0 / 30.0).abs() < 2e-3),
        "continuous across the join: {d:?}"
    );
    let track = decode_audio(c).unwrap().unwrap();
    assert!(
        (track.samples.len() as f64 / 48_000.0 - 3.0).abs() < 0.05,
        "{}",
        track.samples.len()
    );
    // A second recording in the same folder is refused with advice.
    std::fs::copy(cam.join("GX010042.MP4"), cam.join("GX010043.MP4")).unwrap();
    let err = camera_files("cam0", &cam).unwrap_err();
    assert!(matches!(err, IngestError::SeveralRecordings { .. }));
    assert!(err.to_string().contains("0042, 0043"), "{err}");
}

/// Camcorder files (AVCHD `.MTS`: MPEG-TS with 192-byte packets) are videos, and so is a
/// file whose name says nothing when its content is a container.
#[test]
fn transport_streams_and_unnamed_containers_are_videos() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cam = dir.path().join("cam0");
    std::fs::create_dir_all(&cam).unwrap();
    clip(
        &cam.join("00001.MTS"),
        1.0,
        25,
        "160x120",
        &["-f", "mpegts", "-mpegts_m2ts_mode", "1"],
    );
    let head = std::fs::read(cam.join("00001.MTS")).unwrap();
    assert_eq!((head[4], head[196]), (0x47, 0x47), "192-byte packets");
    std::fs::write(cam.join("notes.txt"), "not a video").unwrap();
    let streams = ingest(
        &[("cam0".into(), cam.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let c = &streams.cameras[0];
    assert_eq!(c.chapters.len(), 1, "{:?}", c.chapters);
    assert_eq!(c.video.frame_count, 25);

    let other = dir.path().join("cam1");
    std::fs::create_dir_all(&other).unwrap();
    clip(&other.join("take"), 1.0, 25, "160x120", &["-f", "mp4"]);
    let files = camera_files("cam1", &other).unwrap();
    assert_eq!(files, [other.join("take")]);
}

/// The first video and audio timestamps of `path` as FFmpeg reads them (its own clock).
fn raw_starts(path: &Path) -> (f64, f64) {
    let out = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-show_entries",
            "stream=codec_type,start_time",
        ])
        .args(["-of", "csv=p=0"])
        .arg(path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let start = |kind: &str| {
        text.lines()
            .find_map(|l| {
                let mut fields = l.split(',');
                (fields.next()? == kind).then(|| fields.next()?.parse::<f64>().ok())?
            })
            .unwrap_or_else(|| panic!("no {kind} start in {text}"))
    };
    (start("video"), start("audio"))
}

/// Camcorder files: an AVCHD `.MTS` starts its clock at the muxer's delay (1.4 s) and a
/// transport stream's 33-bit clock can wrap inside a file; their clocks start at 0 on
/// ingest with the delay between video and audio kept, so `timestamps` puts them beside an
/// MP4 (whose own clock is kept). An MXF's timecode (time of day) is not taken as a start.
#[test]
fn camcorder_clocks_start_at_zero_and_keep_their_audio_delay() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let h264 = H264_AAC.to_vec();
    let cams: [(&str, &str, f64, f64, Vec<&str>); 4] = [
        (
            "cam0",
            "00000.MTS",
            0.2,
            2.0,
            [h264.as_slice(), &["-f", "mpegts", "-mpegts_m2ts_mode", "1"]].concat(),
        ),
        (
            "cam1",
            "00001.ts",
            0.0,
            5.0,
            [
                h264.as_slice(),
                &["-output_ts_offset", "95441", "-f", "mpegts"],
            ]
            .concat(),
        ),
        (
            "cam2",
            "C0001.MXF",
            0.0,
            2.0,
            vec![
                "-c:v",
                "mpeg2video",
                "-c:a",
                "pcm_s16le",
                "-timecode",
                "10:00:00:00",
                "-f",
                "mxf",
            ],
        ),
        ("cam3", "GX010001.MP4", 0.2, 2.0, h264.clone()),
    ];
    let mut inputs = Vec::new();
    let mut raw = Vec::new();
    for (cam, file, audio_delay, seconds, out_args) in &cams {
        let folder = dir.path().join(cam);
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join(file);
        let (delay, t) = (audio_delay.to_string(), seconds.to_string());
        let mut args = vec!["-f", "lavfi", "-i", "testsrc2=size=320x240:rate=25"];
        args.extend([
            "-itsoffset",
            &delay,
            "-f",
            "lavfi",
            "-i",
            "sine=f=440:sample_rate=48000",
        ]);
        args.extend(["-t", &t, "-pix_fmt", "yuv420p"]);
        args.extend(out_args.iter().copied());
        let p = path.to_string_lossy().to_string();
        args.push(&p);
        ffmpeg(&args);
        raw.push(raw_starts(&path));
        inputs.push((cam.to_string(), folder));
    }
    // The cases are what they claim: the AVCHD clock starts late, the wrapped one is far
    // from 0 as FFmpeg unwraps it, the MXF carries a timecode and starts at 0.
    assert!(raw[0].0 > 1.0, "{raw:?}");
    assert!(raw[1].0.abs() > 1.0, "{raw:?}");
    assert!(raw[2].0.abs() < 1e-6, "{raw:?}");

    let streams = ingest(&inputs, &IngestOptions::default(), &NoProgress).unwrap();
    for (i, c) in streams.cameras.iter().enumerate() {
        let (video, audio) = raw[i];
        let transport = i < 2;
        let shift = if transport { video.min(audio) } else { 0.0 };
        let frames = (cams[i].3 * 25.0) as usize;
        assert_eq!(c.video.frame_count, frames, "{}", c.name);
        assert!(
            (c.timestamps[0] - (video - shift)).abs() < 1e-3,
            "{}: {:?}",
            c.name,
            c.timestamps
        );
        assert!(
            c.timestamps
                .windows(2)
                .all(|w| (w[1] - w[0] - 0.04).abs() < 1e-3),
            "{}: one frame every 40 ms, across the wrap: {:?}",
            c.name,
            c.timestamps
        );
        let track = decode_audio(c).unwrap().unwrap();
        assert!(
            (track.start_s - (audio - shift)).abs() < 1e-3,
            "{}: audio at {}",
            c.name,
            track.start_s
        );
        if transport {
            // The audio-to-video delay survives: the file's first timestamp becomes 0.
            assert!(
                c.timestamps[0].min(track.start_s).abs() < 1e-9,
                "{}",
                c.name
            );
        }
    }
    let cam0 = &streams.cameras[0];
    let audio0 = decode_audio(cam0).unwrap().unwrap();
    assert!(
        cam0.timestamps[0].abs() < 1e-3 && (audio0.start_s - 0.2).abs() < 0.03,
        "{}",
        audio0.start_s
    );
    // On one clock now: every camera's first frame within a frame of the others.
    let firsts: Vec<f64> = streams.cameras.iter().map(|c| c.timestamps[0]).collect();
    let spread = firsts.iter().cloned().fold(f64::MIN, f64::max)
        - firsts.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread < 0.04, "{firsts:?}");
}

/// A phone's display matrix (portrait, upside down) turns the frames as a player shows
/// them: the size in `streams.json` is the displayed one, and every decoded frame equals
/// what FFmpeg's own command line (which applies the matrix) decodes, at full size and
/// resized.
#[test]
fn rotated_phone_videos_come_out_as_displayed() {
    use rig::rotation::Rotation;
    use rig::source::{CameraSource, PixelLayout};
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Lossless 4:4:4, so the two decoders differ only by rounding.
    let stored = dir.path().join("stored.mp4");
    let s = stored.to_string_lossy().to_string();
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=96x48:rate=10",
        "-t",
        "0.5",
        "-c:v",
        "libx264",
        "-qp",
        "0",
        "-pix_fmt",
        "yuv444p",
        &s,
    ]);
    // `rotate` is how FFmpeg writes a display matrix; a player turns the frame by the
    // opposite angle (FFmpeg's convention, checked against its command line below).
    for (tag, rotation) in [
        ("90", Rotation::Clockwise270),
        ("180", Rotation::Half),
        ("270", Rotation::Clockwise90),
    ] {
        let cam = dir.path().join(format!("cam{tag}"));
        std::fs::create_dir_all(&cam).unwrap();
        let file = cam.join("phone.mp4");
        let f = file.to_string_lossy().to_string();
        let meta = format!("rotate={tag}");
        ffmpeg(&["-i", &s, "-c", "copy", "-metadata:s:v:0", &meta, &f]);
        let streams = ingest(
            &[("cam0".into(), cam.clone())],
            &IngestOptions::default(),
            &NoProgress,
        )
        .unwrap();
        let v = &streams.cameras[0].video;
        assert_eq!(v.rotation, rotation, "rotate={tag}");
        let displayed = rotation.turn_size((96, 48));
        assert_eq!((v.width, v.height), displayed, "rotate={tag}");
        for out_size in [None, Some((displayed.0 / 2, displayed.1 / 2))] {
            let mut source = streams.cameras[0]
                .open(PixelLayout::Rgb8, out_size)
                .unwrap();
            let frame = source.next_frame().unwrap().unwrap();
            let (w, h) = out_size.unwrap_or(displayed);
            assert_eq!((frame.width, frame.height), (w, h), "rotate={tag}");
            let scale = format!("scale={w}:{h}:flags=area");
            let out = std::process::Command::new("ffmpeg")
                .args(["-v", "error", "-i", &f, "-frames:v", "1", "-vf", &scale])
                .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
                .output()
                .unwrap();
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            assert_eq!(out.stdout.len(), frame.data.len(), "rotate={tag}");
            let mean_diff = frame
                .data
                .iter()
                .zip(&out.stdout)
                .map(|(a, b)| f64::from(a.abs_diff(*b)))
                .sum::<f64>()
                / frame.data.len() as f64;
            assert!(
                mean_diff < 3.0,
                "rotate={tag}, size {w}×{h}: mean difference {mean_diff} from ffmpeg's frame"
            );
        }
    }
}

#[test]
fn variable_frame_rate_and_dropped_frames_keep_exact_timestamps() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let vfr = dir.path().join("vfr.mkv");
    // Frame n is shown at n/30 s for the first half, then every 1/20 s.
    clip(
        &vfr,
        2.0,
        30,
        "160x120",
        &[
            "-vf",
            "settb=1/1000,setpts='if(lt(N,30),N/30,1+(N-30)/20)/TB'",
            "-fps_mode",
            "passthrough",
            "-enc_time_base",
            "1/1000",
        ],
    );
    let drop = dir.path().join("drop.mp4");
    clip(
        &drop,
        2.0,
        30,
        "160x120",
        &["-vf", "select='not(between(n,10,12))'", "-fps_mode", "vfr"],
    );
    let streams = ingest(
        &[("cam0".into(), vfr.clone()), ("cam1".into(), drop.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let v = &streams.cameras[0];
    assert!(v.video.variable_frame_rate, "{:?}", v.video);
    assert_eq!(v.video.gaps, 0, "a slower rate is not a gap");
    let t0 = v.timestamps[0];
    assert!(
        (v.timestamps[29] - t0 - 29.0 / 30.0).abs() < 2e-3,
        "{:?}",
        &v.timestamps[25..35]
    );
    assert!(
        (v.timestamps[31] - t0 - 1.05).abs() < 2e-3,
        "{:?}",
        &v.timestamps[25..35]
    );
    let d = &streams.cameras[1];
    assert_eq!(
        (
            d.video.frame_count,
            d.video.gaps,
            d.video.variable_frame_rate
        ),
        (57, 1, false)
    );
    assert!((d.timestamps[10] - 13.0 / 30.0).abs() < 1e-3);
    println!("warnings: {:#?}", streams.warnings);
    assert!(
        streams
            .warnings
            .iter()
            .any(|w| w.contains("cam0") && w.contains("variable frame rate"))
    );
    assert!(
        streams
            .warnings
            .iter()
            .any(|w| w.contains("cam1") && w.contains("dropped"))
    );
}

#[test]
fn mismatched_cameras_are_warned_about() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.mp4");
    let b = dir.path().join("b.mp4");
    clip(&a, 1.0, 30, "320x240", &[]);
    clip(&b, 1.0, 25, "160x120", &["-an"]);
    let streams = ingest(
        &[("cam0".into(), a), ("cam1".into(), b)],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap();
    let w = streams.warnings.join("\n");
    println!("{w}");
    assert!(w.contains("cam1 runs at 25.000 fps but cam0 at 30.000 fps"));
    assert!(w.contains("cam1 is 160x120 but cam0 is 320x240"));
    assert!(w.contains("cam1 has no audio track"));
}

#[test]
fn missing_or_empty_inputs_fail_with_advice() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("cam0");
    std::fs::create_dir_all(&empty).unwrap();
    std::fs::write(empty.join("notes.txt"), "not a video").unwrap();
    let err = ingest(
        &[("cam0".into(), empty.clone())],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap_err();
    assert!(err.to_string().contains("no video file in"), "{err}");
    let err = ingest(
        &[("cam1".into(), dir.path().join("nope"))],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap_err();
    assert!(err.to_string().contains("does not exist"), "{err}");
    assert!(matches!(
        ingest(&[], &IngestOptions::default(), &NoProgress),
        Err(IngestError::NoCameras)
    ));
    let bogus = empty.join("broken.mp4");
    std::fs::write(&bogus, b"garbage").unwrap();
    let err = ingest(
        &[("cam0".into(), bogus)],
        &IngestOptions::default(),
        &NoProgress,
    )
    .unwrap_err();
    assert!(err.to_string().contains("broken.mp4"), "{err}");
}

/// The caliscope sample: four 1280×720 MP4s of a ChArUco board with the capture software's
/// own per-frame times in `timestamps.csv`.
#[test]
fn caliscope_recording_matches_its_timestamps_csv() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/caliscope-4cam/calibration/extrinsic");
    let root = if root.exists() {
        root
    } else {
        PathBuf::from("/work/shared/data/caliscope-4cam/calibration/extrinsic")
    };
    if !root.join("timestamps.csv").exists() {
        eprintln!(
            "SKIPPED: {} not found (the caliscope-4cam sample is not in the repository)",
            root.display()
        );
        return;
    }
    let cams: Vec<(String, PathBuf)> = (0..4)
        .map(|i| (format!("cam{i}"), root.join(format!("cam_{i}.mp4"))))
        .collect();
    let streams = ingest(&cams, &IngestOptions::default(), &NoProgress).unwrap();
    let csv = std::fs::read_to_string(root.join("timestamps.csv")).unwrap();
    let mut recorded: Vec<Vec<f64>> = vec![vec![]; 4];
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let cam: usize = f[1].parse().unwrap();
        recorded[cam].push(f[2].parse().unwrap());
    }
    for (i, c) in streams.cameras.iter().enumerate() {
        let mut rec = recorded[i].clone();
        rec.sort_by(f64::total_cmp);
        assert_eq!(
            c.video.frame_count,
            rec.len(),
            "cam{i}: one video frame per csv row"
        );
        assert_eq!((c.video.width, c.video.height), (1280, 720));
        // The files are written at a constant 6 fps; the csv holds the real capture times.
        let max_dev = c
            .timestamps
            .iter()
            .zip(&rec)
            .map(|(t, r)| ((t - c.timestamps[0]) - (r - rec[0])).abs())
            .fold(0.0, f64::max);
        let span_file = c.timestamps[c.timestamps.len() - 1] - c.timestamps[0];
        let span_csv = rec[rec.len() - 1] - rec[0];
        println!(
            "caliscope cam{i}: {} frames, {:.3} fps in the file, span {span_file:.3} s (csv {span_csv:.3} s), max deviation {:.1} ms",
            c.video.frame_count,
            c.video.fps,
            max_dev * 1e3
        );
        assert!(
            max_dev < 0.5 / 6.0,
            "cam{i}: file and csv times differ by {max_dev} s"
        );
    }
    assert!(
        streams.warnings.iter().all(|w| !w.contains("fps but")),
        "{:?}",
        streams.warnings
    );
}
