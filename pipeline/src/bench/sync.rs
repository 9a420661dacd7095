//! `pipeline bench sync OUT_DIR`: how close each sync method and setting gets to the
//! simulator's true camera offsets, and how long it takes.
//!
//! Scenes (simulated once into `OUT_DIR/scenes/`): `audio` is `fixtures/sync-audio.toml`
//! (a clap heard with acoustic delays), `audio-noise-0.03` and `-0.1` the same with 3× and
//! 10× the background noise; `flash-rolling-4ms` is `fixtures/sync-flash.toml` (a 10 ms
//! flash through a rolling shutter, 4 ms exposure) with the clap of `sync-audio.toml`
//! added, so audio and flash run on one capture; `flash-global-4ms` and `-30ms` have a
//! global shutter (the simulator needs readout + exposure within a frame, so a 30 ms
//! exposure only comes global). Settings: audio with or
//! without the clap window and the acoustic path correction (clap and camera positions
//! from the ground truth); flash with or without the readout and exposure times declared.
//! Each row is `rig::sync::synchronise` on the ingested streams, timed as the median of
//! [`REPEATS`] runs (decoding included, ingest not), its offsets compared with
//! `groundtruth/offsets.json` by [`offset_errors`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rig::ingest::Streams;
use rig::sim::OffsetsFile;
use rig::sync::audio::{AcousticConfig, AudioSyncConfig};
use rig::sync::{SyncConfig, SyncMethod, SyncResult};
use shared_types::progress::NoProgress;

use super::table::{BenchFiles, Table};
use super::{edit_scene, fixed, now, prepare_out_dir, simulate_once, sysinfo};
use crate::report::Reporter;

/// The audio sync scene (`fixtures/sync-audio.toml`).
pub const SYNC_AUDIO_SCENE: &str = include_str!("../../../fixtures/sync-audio.toml");
/// The flash sync scene (`fixtures/sync-flash.toml`).
pub const SYNC_FLASH_SCENE: &str = include_str!("../../../fixtures/sync-flash.toml");

/// Timed runs of each setting (the median is reported).
pub const REPEATS: usize = 3;

/// The settings (key) columns.
pub const KEY_COLUMNS: [&str; 7] = [
    "scene",
    "rolling_shutter",
    "method",
    "clap_window",
    "acoustic_correction",
    "readout_declared",
    "exposure_declared",
];

/// The measured (value) columns.
pub const VALUE_COLUMNS: [&str; 8] = [
    "max_error_ms",
    "mean_error_ms",
    "max_error_frames",
    "min_confidence",
    "sync_s",
    "status",
    "computed_at",
    "machine",
];

/// Per-camera error of a sync result against the simulator's truth, seconds, in the
/// result's camera order: found offset − (true start − reference camera's true start).
/// Fails when a camera (or the reference) is missing from the truth.
pub fn offset_errors(
    truth: &OffsetsFile,
    result: &SyncResult,
) -> anyhow::Result<Vec<(String, f64)>> {
    let start = |name: &str| {
        truth
            .cameras
            .iter()
            .find(|c| c.name == name)
            .map(|c| c.start_time_s)
            .with_context(|| format!("camera {name} is not in the simulator's offsets.json"))
    };
    let reference = start(&result.reference)?;
    result
        .cameras
        .iter()
        .map(|c| Ok((c.name.clone(), c.offset_s - (start(&c.name)? - reference))))
        .collect()
}

/// One simulated scene of the bench.
struct BenchScene {
    name: &'static str,
    text: String,
}

/// A sync method with its settings.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Method {
    Audio { clap_window: bool, acoustic: bool },
    Flash { readout: bool, exposure: bool },
}

/// One point of the grid: a scene (index into the scenes) and a method.
#[derive(Clone, Copy, Debug)]
struct Point {
    scene: usize,
    method: Method,
}

fn scenes() -> anyhow::Result<Vec<BenchScene>> {
    let clap = [
        ("audio.sample_rate", toml::Value::from(48_000)),
        ("audio.noise", 0.01.into()),
        ("audio.clap_time", 0.7.into()),
        (
            "audio.clap_position",
            toml::Value::Array(vec![0.0.into(), (-0.5).into(), 1.2.into()]),
        ),
        ("audio.clap_gain", 0.8.into()),
        ("audio.acoustic_delay", true.into()),
    ];
    let flash = |readout: f64, shutter: f64| {
        edit_scene(
            SYNC_FLASH_SCENE,
            &[
                ("flash.readout", readout.into()),
                ("flash.shutter", shutter.into()),
            ],
        )
    };
    let noisy = |noise: f64| edit_scene(SYNC_AUDIO_SCENE, &[("audio.noise", noise.into())]);
    let scene = |name, text| BenchScene { name, text };
    Ok(vec![
        scene(AUDIO, SYNC_AUDIO_SCENE.to_string()),
        scene("audio-noise-0.03", noisy(0.03)?),
        scene("audio-noise-0.1", noisy(0.1)?),
        scene(FLASH_ROLLING, edit_scene(SYNC_FLASH_SCENE, &clap)?),
        scene("flash-global-4ms", flash(0.0, 0.004)?),
        scene("flash-global-30ms", flash(0.0, 0.03)?),
    ])
}

/// The scene `fixtures/sync-audio.toml`.
const AUDIO: &str = "audio";
/// `fixtures/sync-flash.toml` (rolling shutter, 4 ms exposure) with a clap added.
const FLASH_ROLLING: &str = "flash-rolling-4ms";

/// The grid: every audio setting on the audio scenes and on `flash-rolling-4ms` (audio
/// and flash on one capture), every flash setting on the flash scenes (declaring the
/// readout only where the shutter rolls). `quick`: four rows on two scenes.
fn grid(scenes: &[BenchScene], quick: bool) -> Vec<Point> {
    let a = |clap_window, acoustic| Method::Audio {
        clap_window,
        acoustic,
    };
    let f = |readout, exposure| Method::Flash { readout, exposure };
    let index = |name: &str| scenes.iter().position(|s| s.name == name).unwrap_or(0);
    let (audio, rolling) = (index(AUDIO), index(FLASH_ROLLING));
    if quick {
        return vec![
            Point {
                scene: audio,
                method: a(true, false),
            },
            Point {
                scene: audio,
                method: a(true, true),
            },
            Point {
                scene: rolling,
                method: f(true, true),
            },
            Point {
                scene: rolling,
                method: f(false, false),
            },
        ];
    }
    let mut points = Vec::new();
    for (scene, s) in scenes.iter().enumerate() {
        if s.name.starts_with("audio") || s.name == FLASH_ROLLING {
            for clap_window in [true, false] {
                for acoustic in [false, true] {
                    points.push(Point {
                        scene,
                        method: a(clap_window, acoustic),
                    });
                }
            }
        }
    }
    for (scene, s) in scenes.iter().enumerate() {
        if !s.name.starts_with("flash") {
            continue;
        }
        let readouts: &[bool] = if s.name.starts_with("flash-rolling") {
            &[true, false]
        } else {
            &[false]
        };
        for &readout in readouts {
            for exposure in [true, false] {
                points.push(Point {
                    scene,
                    method: f(readout, exposure),
                });
            }
        }
    }
    points
}

/// A simulated, ingested scene: its streams and truth.
struct Prepared {
    rolling_shutter: String,
    streams: Streams,
    truth: OffsetsFile,
    cameras: shared_types::CameraSet,
}

fn yes_no(b: bool) -> String {
    if b { "yes" } else { "no" }.to_string()
}

fn key(scenes: &[BenchScene], prepared: &[Option<Prepared>], p: &Point) -> Vec<String> {
    let rolling = prepared[p.scene]
        .as_ref()
        .map_or(String::new(), |s| s.rolling_shutter.clone());
    let (method, clap, acoustic, readout, exposure) = match p.method {
        Method::Audio {
            clap_window,
            acoustic,
        } => (
            "audio",
            yes_no(clap_window),
            yes_no(acoustic),
            String::new(),
            String::new(),
        ),
        Method::Flash { readout, exposure } => (
            "flash",
            String::new(),
            String::new(),
            if rolling == "off" {
                String::new()
            } else {
                yes_no(readout)
            },
            yes_no(exposure),
        ),
    };
    vec![
        scenes[p.scene].name.to_string(),
        rolling,
        method.to_string(),
        clap,
        acoustic,
        readout,
        exposure,
    ]
}

/// Simulate (once) and ingest (once) a scene under `OUT_DIR/scenes/NAME`.
fn prepare(scene: &BenchScene, out_dir: &Path, reporter: &Reporter) -> anyhow::Result<Prepared> {
    let dir = out_dir.join("scenes").join(scene.name);
    simulate_once(
        &scene.text,
        &format!("bench scene {}", scene.name),
        &dir,
        reporter,
    )?;
    let capture = super::run_stages_to(&dir, "ingest")?;
    let streams = Streams::read_json(&capture.work_dir().join("ingest/streams.json"))?;
    let truth: OffsetsFile = read_json(&dir.join("groundtruth/offsets.json"))?;
    let cameras: shared_types::CameraSet = read_json(&dir.join("groundtruth/cameras.json"))?;
    let rolling_shutter = match &truth.flash {
        Some(f) if f.readout_s > 0.0 => format!("{:.1} ms", f.readout_s * 1e3),
        Some(_) => "off".into(),
        None => String::new(),
    };
    Ok(Prepared {
        rolling_shutter,
        streams,
        truth,
        cameras,
    })
}

fn read_json<T: serde::de::DeserializeOwned>(path: &PathBuf) -> anyhow::Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{} is not what the simulator writes", path.display()))
}

/// The sync settings of a grid point on a prepared scene.
fn sync_config(method: Method, scene: &Prepared) -> anyhow::Result<SyncConfig> {
    let mut config = SyncConfig::default();
    match method {
        Method::Audio {
            clap_window,
            acoustic,
        } => {
            config.method = SyncMethod::Audio;
            config.audio = AudioSyncConfig {
                use_clap: clap_window,
                ..Default::default()
            };
            if acoustic {
                let audio = scene
                    .truth
                    .audio
                    .as_ref()
                    .context("the scene has no audio truth for the acoustic correction")?;
                config.acoustic = Some(AcousticConfig {
                    clap_position: audio.clap_position,
                    camera_positions: scene
                        .cameras
                        .cameras
                        .iter()
                        .map(|c| (c.name.clone(), c.world_to_camera.centre().to_array()))
                        .collect(),
                    speed_of_sound: audio.speed_of_sound_m_s,
                });
            }
        }
        Method::Flash { readout, exposure } => {
            config.method = SyncMethod::Flash;
            let flash = scene
                .truth
                .flash
                .as_ref()
                .context("the scene has no flash")?;
            if readout {
                config.readout_s = flash.readout_s;
            }
            if exposure {
                config.exposure_s = flash.shutter_s;
            }
        }
    }
    Ok(config)
}

/// Run one grid point: the value columns.
#[cfg(not(feature = "ffmpeg"))]
fn measure(_: &Point, _: &Prepared) -> anyhow::Result<Vec<String>> {
    Err(crate::without_ffmpeg("the sync bench"))
}

#[cfg(feature = "ffmpeg")]
fn measure(point: &Point, scene: &Prepared) -> anyhow::Result<Vec<String>> {
    let config = sync_config(point.method, scene)?;
    let mut times = Vec::new();
    let mut result = None;
    for _ in 0..REPEATS {
        let t = Instant::now();
        let r = rig::sync::synchronise(&scene.streams, &config, &NoProgress);
        times.push(t.elapsed().as_secs_f64());
        result.get_or_insert(r);
    }
    times.sort_by(f64::total_cmp);
    let seconds = fixed(times[times.len() / 2], 4);
    let result = match result {
        Some(Ok(r)) => r,
        Some(Err(e)) => {
            return Ok(vec![
                String::new(),
                String::new(),
                String::new(),
                String::new(),
                seconds,
                format!("failed: {e}"),
                now(),
                sysinfo::describe_machine(),
            ]);
        }
        None => anyhow::bail!("no sync run"),
    };
    let errors = offset_errors(&scene.truth, &result)?;
    // The reference camera's error is 0 by construction: measured over the others.
    let others: Vec<f64> = errors
        .iter()
        .filter(|(name, _)| *name != result.reference)
        .map(|(_, e)| e.abs())
        .collect();
    let max = others.iter().copied().fold(0.0, f64::max);
    let mean = others.iter().sum::<f64>() / others.len().max(1) as f64;
    let confidence = result
        .cameras
        .iter()
        .filter_map(|c| c.confidence)
        .fold(f64::INFINITY, f64::min);
    Ok(vec![
        fixed(max * 1e3, 3),
        fixed(mean * 1e3, 3),
        fixed(max * scene.truth.fps, 3),
        if confidence.is_finite() {
            fixed(confidence, 1)
        } else {
            String::new()
        },
        seconds,
        "ok".into(),
        now(),
        sysinfo::describe_machine(),
    ])
}

/// Run the sync bench into `out_dir` (the full grid, or a small one with `quick`).
pub fn run(out_dir: &Path, quick: bool, reporter: &Reporter) -> anyhow::Result<BenchFiles> {
    prepare_out_dir(out_dir)?;
    let csv = out_dir.join("sync.csv");
    let mut table = Table::open(&csv, &KEY_COLUMNS, &VALUE_COLUMNS)?;
    let scenes = scenes()?;
    let grid = grid(&scenes, quick);
    let mut prepared: Vec<Option<Prepared>> = scenes.iter().map(|_| None).collect();
    for p in &grid {
        if prepared[p.scene].is_none() {
            prepared[p.scene] = Some(prepare(&scenes[p.scene], out_dir, reporter)?);
        }
    }
    let progress = reporter.progress("bench sync");
    let summary = table.fill(
        &grid,
        |p| key(&scenes, &prepared, p),
        |p| {
            let scene = prepared[p.scene]
                .as_ref()
                .context("a scene of the grid was not prepared")?;
            measure(p, scene)
        },
        &progress,
    )?;
    table.write_markdown(
        "Sync error against time",
        &header(&table),
        &["computed_at", "machine"],
        summary,
    )
}

/// The Markdown header: what was measured, on which scenes and machines.
fn header(table: &Table) -> String {
    let machines = table.distinct("machine");
    format!(
        "Offsets found by `rig::sync::synchronise` against the simulator's true offsets \
         (`groundtruth/offsets.json`) on simulated 4-camera scenes (160×120, 30 fps, start \
         offsets up to 0.31 s with sub-frame phases; scene seeds fixed in the scene files: \
         sync-audio.toml 11, sync-flash.toml 12). `audio` = fixtures/sync-audio.toml (a clap \
         3–4 m from the cameras, acoustic delays on, noise 0.01), `audio-noise-N` the same \
         with background noise N; `flash-rolling-4ms` = fixtures/sync-flash.toml (a 10 ms \
         flash, rolling shutter read out in 26.6 ms, 4 ms exposure) with the clap added; \
         `flash-global-4ms` and `flash-global-30ms` have a global shutter and 4 or 30 ms \
         exposure. Errors over the three non-reference cameras (`max_error_frames` in \
         frames of 1/30 s); `sync_s` is the median of {REPEATS} runs (decoding included, \
         ingest not); `min_confidence` the lowest peak-to-sidelobe ratio (audio) or rise \
         over noise (flash); `auto` trusts audio from 10 and flash from 8. The acoustic \
         correction takes the clap and camera positions from the ground truth.\n\nMachine: {}.",
        machines.join("; ")
    )
}
