//! Test captures made here: a scene with ambient sound, a clap and a flash, filmed by
//! cameras that start at known scene times, encoded to real MP4 files with the `ffmpeg`
//! command-line tool (H.264 + AAC, as a GoPro writes). Shared by the ingest, sync and
//! frames integration tests.
#![allow(dead_code)]

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::process::Command;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub const RATE: u32 = 48_000;
pub const CLAP_T: f64 = 1.5;
pub const FLASH_T: f64 = 2.3;

/// True when the `ffmpeg` tool is installed; tests print why they skip otherwise.
pub fn ffmpeg_available() -> bool {
    let ok = Command::new("ffmpeg")
        .arg("-version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        let why = "the ffmpeg command-line tool is not installed (apt-get install ffmpeg)";
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "under CI=true: {why}"
        );
        eprintln!("SKIPPED: {why}");
    }
    ok
}

/// Runs ffmpeg with `args`, panicking with its stderr on failure (test inputs only).
pub fn ffmpeg(args: &[&str]) {
    let out = Command::new("ffmpeg")
        .args(["-y", "-hide_banner", "-loglevel", "error"])
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "ffmpeg {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// ffmpeg's output options for a file as a camera writes it: H.264 video, AAC audio.
pub const H264_AAC: [&str; 6] = ["-c:v", "libx264", "-preset", "ultrafast", "-c:a", "aac"];

/// Cuts `len` seconds starting at `from` (seconds, as ffmpeg reads them) out of `input`
/// into `out`, re-encoded as a camera writes it ([`H264_AAC`]).
pub fn cut(input: &Path, from: &str, len: &str, out: &Path) {
    let (input, out) = (input.to_string_lossy(), out.to_string_lossy());
    let mut args = vec!["-ss", from, "-i", &input, "-t", len];
    args.extend_from_slice(&H264_AAC);
    args.push(&out);
    ffmpeg(&args);
}

/// Analytic scene sound: ambient tones plus a band-limited clap at `clap_t` (`CLAP_T`).
pub struct SceneSound {
    ambient: Vec<(f64, f64, f64)>,
    clap: Vec<(f64, f64, f64)>,
    clap_t: f64,
}

impl SceneSound {
    /// 20 ambient tones and a clap of 40 at [`CLAP_T`].
    pub fn new(seed: u64) -> Self {
        Self::with_tones(seed, 20, 40, CLAP_T)
    }

    /// `ambient` random tones and a clap of `clap` tones at scene time `clap_t`.
    pub fn with_tones(seed: u64, ambient: usize, clap: usize, clap_t: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut tones = |n: usize, lo: f64, hi: f64, amp: f64| {
            (0..n)
                .map(|_| {
                    (
                        lo + (hi - lo) * rng.random::<f64>(),
                        amp * (0.5 + rng.random::<f64>()),
                        TAU * rng.random::<f64>(),
                    )
                })
                .collect::<Vec<_>>()
        };
        SceneSound {
            ambient: tones(ambient, 80.0, 6000.0, 0.004),
            clap: tones(clap, 300.0, 12_000.0, 0.05),
            clap_t,
        }
    }

    pub fn at(&self, t: f64) -> f64 {
        let mut v: f64 = self
            .ambient
            .iter()
            .map(|(f, a, p)| a * (TAU * f * t + p).sin())
            .sum();
        let x = t - self.clap_t;
        if x.abs() < 0.03 {
            let env = (-0.5 * (x / 0.004).powi(2)).exp();
            v += env
                * self
                    .clap
                    .iter()
                    .map(|(f, a, p)| a * (TAU * f * x + p).sin())
                    .sum::<f64>();
        }
        v
    }
}

/// What a camera's microphone records.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mic {
    /// The scene.
    Scene,
    /// Digital silence (a muted camera).
    Silent,
    /// No audio track at all.
    None,
}

/// A simulated camera of the test scene.
#[derive(Clone, Debug)]
pub struct TestCamera {
    /// Scene time of the first frame and first audio sample.
    pub start: f64,
    pub fps: f64,
    pub frames: usize,
    pub size: (usize, usize),
    /// Rolling-shutter readout (s); 0 = global shutter.
    pub readout: f64,
    /// Exposure time (s); 0 = instantaneous.
    pub exposure: f64,
    /// Flash on during [FLASH_T, FLASH_T + 1) when true.
    pub flash: bool,
    pub mic: Mic,
    /// Frame indices dropped from the file (their timestamps are missing).
    pub dropped: Vec<usize>,
}

impl TestCamera {
    pub fn new(start: f64) -> Self {
        TestCamera {
            start,
            fps: 30.0,
            frames: 120,
            size: (96, 72),
            readout: 0.0,
            exposure: 0.0,
            flash: true,
            mic: Mic::Scene,
            dropped: vec![],
        }
    }
}

/// Writes `dir/clip.mp4` for `cam` and returns the camera folder.
pub fn write_camera(dir: &Path, cam: &TestCamera, sound: &SceneSound, seed: u64) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let (w, h) = cam.size;
    let mut video = Vec::with_capacity(w * h * cam.frames);
    for k in 0..cam.frames {
        let t = cam.start + k as f64 / cam.fps;
        for r in 0..h {
            let end = t + r as f64 / h as f64 * cam.readout;
            let lit = if !cam.flash {
                0.0
            } else if cam.exposure > 0.0 {
                let overlap = end.min(FLASH_T + 1.0) - (end - cam.exposure).max(FLASH_T);
                (overlap / cam.exposure).clamp(0.0, 1.0)
            } else if (FLASH_T..FLASH_T + 1.0).contains(&end) {
                1.0
            } else {
                0.0
            };
            for x in 0..w {
                let base = 40.0 + (x * 60 / w) as f64;
                video.push((base + 150.0 * lit).round() as u8);
            }
        }
    }
    let raw_video = dir.join("video.raw");
    std::fs::write(&raw_video, &video).unwrap();
    let size = format!("{w}x{h}");
    let fps = format!("{}", cam.fps);
    let out = dir.join("clip.mp4");
    let mut args: Vec<String> = [
        "-f", "rawvideo", "-pix_fmt", "gray", "-s", &size, "-r", &fps, "-i",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.push(raw_video.to_string_lossy().into());
    let raw_audio = dir.join("audio.raw");
    if cam.mic != Mic::None {
        let duration = cam.frames as f64 / cam.fps;
        let n = (duration * f64::from(RATE)) as usize;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut bytes = Vec::with_capacity(4 * n);
        for i in 0..n {
            let t = cam.start + i as f64 / f64::from(RATE);
            let v = match cam.mic {
                Mic::Scene => sound.at(t) + 0.002 * (rng.random::<f64>() - 0.5),
                _ => 0.0,
            };
            bytes.extend_from_slice(&(v as f32).to_le_bytes());
        }
        std::fs::write(&raw_audio, bytes).unwrap();
        for a in ["-f", "f32le", "-ar", "48000", "-ac", "1", "-i"] {
            args.push(a.into());
        }
        args.push(raw_audio.to_string_lossy().into());
        for a in ["-c:a", "aac", "-b:a", "192k"] {
            args.push(a.into());
        }
    }
    if !cam.dropped.is_empty() {
        let cond: Vec<String> = cam.dropped.iter().map(|d| format!("eq(n\\,{d})")).collect();
        args.push("-vf".into());
        args.push(format!("select='not({})'", cond.join("+")));
        args.push("-fps_mode".into());
        args.push("vfr".into());
    }
    for a in [
        "-c:v",
        "libx264",
        "-preset",
        "ultrafast",
        "-qp",
        "10",
        "-pix_fmt",
        "yuv420p",
        "-g",
        "30",
    ] {
        args.push(a.into());
    }
    args.push(out.to_string_lossy().into());
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    ffmpeg(&refs);
    std::fs::remove_file(&raw_video).ok();
    std::fs::remove_file(&raw_audio).ok();
    dir.to_path_buf()
}

/// Writes every camera under `root/camN` and returns `(name, folder)` pairs for ingest.
pub fn write_capture(root: &Path, cams: &[TestCamera]) -> Vec<(String, PathBuf)> {
    let sound = SceneSound::new(11);
    cams.iter()
        .enumerate()
        .map(|(i, c)| {
            let name = format!("cam{i}");
            (
                name.clone(),
                write_camera(&root.join(&name), c, &sound, 100 + i as u64),
            )
        })
        .collect()
}
