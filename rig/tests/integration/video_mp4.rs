//! The MP4 writer (`rig::video`): frames written are the frames decoded (count, duration,
//! content), sizes H.264 cannot take are refused, and nothing is left under the final
//! name until the file is complete.

use ffmpeg_next as ffmpeg;
use rig::video::{Mp4Writer, VideoError, VideoOptions};

/// Frame `i`: a horizontal ramp whose brightness follows `i`.
fn frame(i: usize, w: usize, h: usize) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(w * h * 3);
    for _y in 0..h {
        for x in 0..w {
            let v = (x * 255 / (w - 1)) as u8;
            rgb.extend_from_slice(&[v, (i * 20) as u8, 255 - v]);
        }
    }
    rgb
}

struct Decoded {
    frames: Vec<Vec<u8>>,
    pts: Vec<i64>,
    stream_seconds: f64,
    container_seconds: f64,
    fps: f64,
}

fn decode(path: &std::path::Path) -> Decoded {
    rig::video::init();
    let mut input = ffmpeg::format::input(&path).unwrap();
    let stream = input.streams().best(ffmpeg::media::Type::Video).unwrap();
    let index = stream.index();
    let tb = f64::from(stream.time_base());
    let stream_seconds = stream.duration() as f64 * tb;
    let fps = f64::from(stream.avg_frame_rate());
    let ctx = ffmpeg::codec::context::Context::from_parameters(stream.parameters()).unwrap();
    let mut decoder = ctx.decoder().video().unwrap();
    let container_seconds = input.duration() as f64 / f64::from(ffmpeg::ffi::AV_TIME_BASE);
    let (w, h) = (decoder.width(), decoder.height());
    let mut scaler = ffmpeg::software::scaling::Context::get(
        decoder.format(),
        w,
        h,
        ffmpeg::format::Pixel::RGB24,
        w,
        h,
        ffmpeg::software::scaling::Flags::BILINEAR,
    )
    .unwrap();
    let mut out = Decoded {
        frames: vec![],
        pts: vec![],
        stream_seconds,
        container_seconds,
        fps,
    };
    let mut receive = |decoder: &mut ffmpeg::decoder::Video, out: &mut Decoded| {
        let mut f = ffmpeg::frame::Video::empty();
        while decoder.receive_frame(&mut f).is_ok() {
            let mut rgb = ffmpeg::frame::Video::empty();
            scaler.run(&f, &mut rgb).unwrap();
            let stride = rgb.stride(0);
            let mut packed = Vec::new();
            for y in 0..h as usize {
                packed.extend_from_slice(&rgb.data(0)[y * stride..y * stride + 3 * w as usize]);
            }
            out.frames.push(packed);
            out.pts.push(f.pts().unwrap_or(-1));
        }
    };
    for (s, packet) in input.packets() {
        if s.index() == index {
            decoder.send_packet(&packet).unwrap();
            receive(&mut decoder, &mut out);
        }
    }
    decoder.send_eof().unwrap();
    receive(&mut decoder, &mut out);
    out
}

#[test]
fn frames_written_decode_with_the_right_count_duration_and_content() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("orbit.mp4");
    let (w, h, n, fps) = (64usize, 48usize, 12usize, 24.0);
    let mut writer = Mp4Writer::create(&path, w as u32, h as u32, &VideoOptions::new(fps)).unwrap();
    for i in 0..n {
        writer.push(&frame(i, w, h)).unwrap();
    }
    assert!(
        !path.exists(),
        "the final name appears only when the file is complete"
    );
    assert_eq!(writer.finish().unwrap(), path);
    let entries: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(entries.len(), 1, "no temporary file is left behind");

    let d = decode(&path);
    assert_eq!(d.frames.len(), n);
    assert_eq!(
        d.pts,
        (0..n as i64)
            .map(|i| i * d.pts.get(1).copied().unwrap_or(1))
            .collect::<Vec<_>>()
    );
    assert!((d.fps - fps).abs() < 1e-9, "fps {}", d.fps);
    let expected = n as f64 / fps; // 0.5 s
    assert!(
        (d.stream_seconds - expected).abs() < 1e-6,
        "stream duration {}",
        d.stream_seconds
    );
    assert!(
        (d.container_seconds - expected).abs() < 0.01,
        "container duration {}",
        d.container_seconds
    );
    // Content survives (crf 18 on smooth ramps): mean abs error of a few grey levels.
    for (i, got) in d.frames.iter().enumerate() {
        let want = frame(i, w, h);
        let err = got
            .iter()
            .zip(&want)
            .map(|(&a, &b)| (a as f64 - b as f64).abs())
            .sum::<f64>()
            / want.len() as f64;
        assert!(err < 4.0, "frame {i}: mean abs error {err}");
    }
}

#[test]
fn ntsc_rates_stay_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ntsc.mp4");
    let mut writer =
        Mp4Writer::create(&path, 32, 32, &VideoOptions::new(30000.0 / 1001.0)).unwrap();
    for i in 0..6 {
        writer.push(&frame(i, 32, 32)).unwrap();
    }
    writer.finish().unwrap();
    let d = decode(&path);
    assert_eq!(d.frames.len(), 6);
    assert!(
        (d.stream_seconds - 6.0 * 1001.0 / 30000.0).abs() < 1e-6,
        "{}",
        d.stream_seconds
    );
}

#[test]
fn sizes_and_frames_h264_cannot_take_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("odd.mp4");
    let e = Mp4Writer::create(&path, 33, 32, &VideoOptions::new(30.0))
        .err()
        .unwrap();
    assert!(
        matches!(e, VideoError::Invalid { .. }) && e.to_string().contains("even"),
        "{e}"
    );
    let e = Mp4Writer::create(&path, 32, 32, &VideoOptions::new(0.0))
        .err()
        .unwrap();
    assert!(matches!(e, VideoError::Invalid { .. }), "{e}");
    let mut writer = Mp4Writer::create(&path, 32, 32, &VideoOptions::new(30.0)).unwrap();
    let e = writer.push(&[0u8; 10]).unwrap_err();
    assert!(e.to_string().contains("expected 3072"), "{e}");
}
