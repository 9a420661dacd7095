//! Helpers shared by the simulator tests: fixture scenes, editing them, and reading back
//! the written MP4 files with FFmpeg.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use ffmpeg::{format, media, software};
use ffmpeg_next as ffmpeg;

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("fixtures")
        .join(name)
}

pub fn fixture_table(name: &str) -> toml::Table {
    std::fs::read_to_string(fixture(name))
        .unwrap()
        .parse()
        .unwrap()
}

/// The `i`-th `[[cameras.video]]` table.
pub fn video_cam(t: &mut toml::Table, i: usize) -> &mut toml::Table {
    t["cameras"]["video"].as_array_mut().unwrap()[i]
        .as_table_mut()
        .unwrap()
}

pub fn scene_of(t: &toml::Table, origin: &str) -> rig::sim::Scene {
    rig::sim::Scene::from_toml_str(&toml::to_string(t).unwrap(), origin).unwrap()
}

/// Presentation times (seconds) of the video packets of `path`, in order.
pub fn video_pts(path: &Path) -> Vec<f64> {
    ffmpeg::init().unwrap();
    let mut ictx = format::input(path).unwrap();
    let st = ictx.streams().best(media::Type::Video).unwrap();
    let (idx, tb) = (st.index(), st.time_base());
    let mut pts: Vec<f64> = ictx
        .packets()
        .filter(|(s, _)| s.index() == idx)
        .map(|(_, p)| p.pts().unwrap() as f64 * f64::from(tb))
        .collect();
    pts.sort_by(f64::total_cmp);
    pts
}

/// Decoded video frames of `path` as RGB8 (tightly packed), with their pts in seconds.
pub fn video_frames(path: &Path) -> Vec<(f64, Vec<u8>)> {
    ffmpeg::init().unwrap();
    let mut ictx = format::input(path).unwrap();
    let st = ictx.streams().best(media::Type::Video).unwrap();
    let (idx, tb) = (st.index(), st.time_base());
    let mut dec = ffmpeg::codec::context::Context::from_parameters(st.parameters())
        .unwrap()
        .decoder()
        .video()
        .unwrap();
    let mut scaler = software::scaling::Context::get(
        dec.format(),
        dec.width(),
        dec.height(),
        format::Pixel::RGB24,
        dec.width(),
        dec.height(),
        software::scaling::Flags::BILINEAR,
    )
    .unwrap();
    let mut out = Vec::new();
    let mut take = |dec: &mut ffmpeg::decoder::Video, out: &mut Vec<(f64, Vec<u8>)>| {
        let mut f = ffmpeg::frame::Video::empty();
        while dec.receive_frame(&mut f).is_ok() {
            let mut rgb = ffmpeg::frame::Video::empty();
            scaler.run(&f, &mut rgb).unwrap();
            let (w, h, stride) = (rgb.width() as usize, rgb.height() as usize, rgb.stride(0));
            let mut bytes = Vec::with_capacity(w * h * 3);
            for r in 0..h {
                bytes.extend_from_slice(&rgb.data(0)[r * stride..r * stride + w * 3]);
            }
            out.push((f.pts().unwrap() as f64 * f64::from(tb), bytes));
        }
    };
    for (s, p) in ictx.packets() {
        if s.index() == idx {
            dec.send_packet(&p).unwrap();
            take(&mut dec, &mut out);
        }
    }
    dec.send_eof().unwrap();
    take(&mut dec, &mut out);
    out
}

/// Decoded mono audio of `path`: (sample rate, samples, pts of the first decoded frame).
pub fn audio(path: &Path) -> Option<(u32, Vec<f32>, f64)> {
    ffmpeg::init().unwrap();
    let mut ictx = format::input(path).unwrap();
    let st = ictx.streams().best(media::Type::Audio)?;
    let (idx, tb) = (st.index(), st.time_base());
    let mut dec = ffmpeg::codec::context::Context::from_parameters(st.parameters())
        .unwrap()
        .decoder()
        .audio()
        .unwrap();
    let mut samples = Vec::new();
    let mut first_pts = None;
    let take =
        |dec: &mut ffmpeg::decoder::Audio, samples: &mut Vec<f32>, first: &mut Option<f64>| {
            let mut f = ffmpeg::frame::Audio::empty();
            while dec.receive_frame(&mut f).is_ok() {
                if first.is_none() {
                    *first = f.pts().map(|p| p as f64 * f64::from(tb));
                }
                samples.extend_from_slice(&f.plane::<f32>(0)[..f.samples()]);
            }
        };
    for (s, p) in ictx.packets() {
        if s.index() == idx {
            dec.send_packet(&p).unwrap();
            take(&mut dec, &mut samples, &mut first_pts);
        }
    }
    dec.send_eof().unwrap();
    take(&mut dec, &mut samples, &mut first_pts);
    Some((dec.rate(), samples, first_pts.unwrap_or(0.0)))
}

/// Every file under `dir` (relative path → bytes), sorted.
pub fn tree(dir: &Path) -> Vec<(String, Vec<u8>)> {
    fn walk(base: &Path, dir: &Path, out: &mut Vec<(String, Vec<u8>)>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                out.push((
                    p.strip_prefix(base).unwrap().display().to_string(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}
