//! `pipeline bench poses OUT_DIR`: how close COLMAP's camera poses get to the simulator's
//! true ones for each number of SIFT features (`max_num_features`) and working image size
//! (`max_image_size`), and how long each COLMAP step takes.
//!
//! The scene is `fixtures/poses.toml` (static, 640×480, 4 video cameras and 8 stills),
//! simulated once into `OUT_DIR/scenes/poses` and taken through ingest, sync (the shared
//! timestamps) and frames; every setting then solves the poses (`calib::poses::solve`,
//! otherwise the poses stage's defaults: deterministic, seed 0) in
//! `OUT_DIR/poses-runs/fF-sS/`, and the solved video cameras are compared with the truth
//! after a similarity alignment by [`pose_errors`].

use std::path::{Path, PathBuf};

use anyhow::Context;
use calib::poses::{PoseSource, PosesConfig, PosesFile, PosesInputs};
use shared_types::Camera;

use super::table::{BenchFiles, Table};
use super::{fixed, now, prepare_out_dir, simulate_once, sysinfo};
use crate::report::Reporter;

/// The pose scene (`fixtures/poses.toml`).
pub const POSES_SCENE: &str = include_str!("../../../fixtures/poses.toml");

/// The settings (key) columns.
pub const KEY_COLUMNS: [&str; 3] = ["scene", "max_num_features", "max_image_size"];

/// The measured (value) columns.
pub const VALUE_COLUMNS: [&str; 14] = [
    "max_rotation_deg",
    "mean_rotation_deg",
    "max_centre_pct",
    "mean_centre_pct",
    "registered_images",
    "points",
    "extraction_s",
    "matching_s",
    "mapping_s",
    "mapper_attempts",
    "total_s",
    "status",
    "computed_at",
    "machine",
];

/// Pose errors of solved cameras against the truth after the best similarity alignment
/// (`calib::similarity::compare`): rotation in degrees, camera centres in % of the rig
/// radius (mean distance of the true centres from their mean).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseErrors {
    pub max_rotation_deg: f64,
    pub mean_rotation_deg: f64,
    pub max_centre_pct: f64,
    pub mean_centre_pct: f64,
}

/// Compare `solved` with `truth` (matched by name; every solved camera must have a true
/// one, at least 3 of them).
pub fn pose_errors(solved: &[Camera], truth: &[Camera]) -> anyhow::Result<PoseErrors> {
    let (_, errors, radius) = calib::similarity::compare(solved, truth)
        .context("fewer than 3 solved cameras match a true one by name, or they are collinear")?;
    if errors.len() != solved.len() {
        anyhow::bail!(
            "{} solved cameras but only {} have a true camera of the same name",
            solved.len(),
            errors.len()
        );
    }
    let n = errors.len() as f64;
    let pct = |c: f64| 100.0 * c / radius;
    Ok(PoseErrors {
        max_rotation_deg: errors.iter().map(|e| e.rotation_deg).fold(0.0, f64::max),
        mean_rotation_deg: errors.iter().map(|e| e.rotation_deg).sum::<f64>() / n,
        max_centre_pct: errors.iter().map(|e| pct(e.centre)).fold(0.0, f64::max),
        mean_centre_pct: errors.iter().map(|e| pct(e.centre)).sum::<f64>() / n,
    })
}

/// One COLMAP setting of the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Setting {
    max_num_features: u32,
    max_image_size: u32,
}

/// The grid: every feature count with every image size (the frames are 640×480, so 640
/// is the full size); `quick`: the cheapest one.
fn grid(quick: bool) -> Vec<Setting> {
    if quick {
        return vec![Setting {
            max_num_features: 1024,
            max_image_size: 320,
        }];
    }
    let mut grid = Vec::new();
    for max_image_size in [320, 640] {
        for max_num_features in [1024, 2048, 4096, 8192] {
            grid.push(Setting {
                max_num_features,
                max_image_size,
            });
        }
    }
    grid
}

fn key(s: &Setting) -> Vec<String> {
    vec![
        "poses".into(),
        s.max_num_features.to_string(),
        s.max_image_size.to_string(),
    ]
}

/// The simulated capture, taken to aligned frames: what every setting solves from.
struct Prepared {
    video_frames: Vec<(String, PathBuf)>,
    stills: Vec<PathBuf>,
    truth: Vec<Camera>,
}

fn prepare(out_dir: &Path, reporter: &Reporter) -> anyhow::Result<Prepared> {
    let dir = out_dir.join("scenes/poses");
    simulate_once(
        POSES_SCENE,
        "bench scene poses (fixtures/poses.toml)",
        &dir,
        reporter,
    )?;
    let settings = dir.join(crate::layout::CONFIG_FILE);
    if !settings.exists() {
        // Static scene, no clap or flash: the cameras' own timestamps are the timeline.
        shared_types::atomic::write_atomic(&settings, b"[sync]\nmethod = \"timestamps\"\n")
            .with_context(|| format!("cannot write {}", settings.display()))?;
    }
    let capture = super::run_stages_to(&dir, "frames")?;
    let frames_dir = capture.work_dir().join("frames");
    let index = rig::frames::FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let (_, truth) = crate::simulate::truth_video_cameras(&dir)?;
    Ok(Prepared {
        video_frames: crate::stages::poses::first_frames(&index, &frames_dir)?,
        stills: capture.stills.clone(),
        truth,
    })
}

/// Solve one setting: the value columns (a failed solve is a row with its reason).
fn measure(
    setting: &Setting,
    scene: &Prepared,
    runs_dir: &Path,
    reporter: &Reporter,
) -> anyhow::Result<Vec<String>> {
    let mut config = PosesConfig::default();
    config.colmap.max_num_features = setting.max_num_features;
    config.colmap.max_image_size = setting.max_image_size;
    let inputs = PosesInputs {
        video_frames: scene.video_frames.clone(),
        stills: scene.stills.clone(),
        working_size: None,
        config,
        known_lenses: Default::default(),
    };
    let dir = runs_dir.join(format!(
        "f{}-s{}",
        setting.max_num_features, setting.max_image_size
    ));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let progress = reporter.progress("colmap");
    let t = std::time::Instant::now();
    let solved = calib::poses::solve(&inputs, &dir, &progress);
    let total = t.elapsed().as_secs_f64();
    shared_types::Progress::finish(&progress);
    let tail = |status: String| vec![status, now(), sysinfo::describe_machine()];
    let output = match solved {
        Ok(o) => o,
        Err(e) => {
            let mut row = vec![String::new(); VALUE_COLUMNS.len() - 4];
            row.push(fixed(total, 2));
            let reason = e.to_string();
            let first = reason.lines().next().unwrap_or_default();
            row.extend(tail(format!("failed: {first}")));
            return Ok(row);
        }
    };
    let file: PosesFile = output.file;
    let errors = pose_errors(&file.set.cameras, &scene.truth)?;
    let (registered, timings) = match &file.source {
        PoseSource::Colmap {
            registered_images,
            timings,
            ..
        } => (*registered_images, *timings),
        PoseSource::Import { path } => {
            anyhow::bail!("the poses came from {}, not COLMAP", path.display())
        }
    };
    let mut row = vec![
        fixed(errors.max_rotation_deg, 4),
        fixed(errors.mean_rotation_deg, 4),
        fixed(errors.max_centre_pct, 3),
        fixed(errors.mean_centre_pct, 3),
        registered.to_string(),
        file.num_points.to_string(),
        fixed(timings.feature_extraction_s, 2),
        fixed(timings.matching_s, 2),
        fixed(timings.mapping_s, 2),
        timings.mapper_attempts.to_string(),
        fixed(total, 2),
    ];
    row.extend(tail("ok".into()));
    Ok(row)
}

/// Run the poses bench into `out_dir` (the full grid, or one setting with `quick`). Needs
/// COLMAP (`$COLMAP_BIN` or `colmap` on `PATH`).
pub fn run(out_dir: &Path, quick: bool, reporter: &Reporter) -> anyhow::Result<BenchFiles> {
    prepare_out_dir(out_dir)?;
    calib::colmap_runner::find_colmap(None)
        .context("the poses bench runs COLMAP: install it (scripts/setup.sh) or set COLMAP_BIN")?;
    let csv = out_dir.join("poses.csv");
    let mut table = Table::open(&csv, &KEY_COLUMNS, &VALUE_COLUMNS)?;
    let grid = grid(quick);
    // The capture is needed only when some setting is not in the table yet.
    let mut scene = None;
    let runs_dir = out_dir.join("poses-runs");
    let progress = reporter.progress("bench poses");
    let summary = table.fill(
        &grid,
        key,
        |setting| {
            let prepared = match &mut scene {
                Some(p) => p,
                None => scene.insert(prepare(out_dir, reporter)?),
            };
            measure(setting, prepared, &runs_dir, reporter)
        },
        &progress,
    )?;
    table.write_markdown(
        "Pose error against time",
        &header(&table),
        &["computed_at", "machine"],
        summary,
    )
}

/// The Markdown header: what was measured, on which scene and machines.
fn header(table: &Table) -> String {
    let machines = table.distinct("machine");
    format!(
        "COLMAP (`calib::poses::solve`: `RADIAL` lenses, one thread per step, RANSAC seed 0, \
         up to 5 mapper attempts) on the first frame of the 4 video cameras and the 8 stills of \
         fixtures/poses.toml (static, 640×480, scene seed 5), for each `[poses.colmap] \
         max_num_features` and `max_image_size`. Errors of the 4 video cameras against the \
         simulator's true cameras after a similarity alignment: rotation in degrees, centre \
         in % of the rig radius. Times in seconds per COLMAP step (`mapping_s` covers every \
         mapper attempt; `total_s` the whole solve).\n\nMachine: {}.",
        machines.join("; ")
    )
}
