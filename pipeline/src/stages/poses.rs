//! The `poses` stage: every camera's pose, solved with COLMAP from each video camera's
//! first aligned frame plus the stills, or imported from the capture's calibration file
//! when there is one (`calib::poses`, `calib::import`), into `cameras.json`. With
//! held-out cameras they are posed with the training cameras and then split off into
//! `heldout.json` (see `crate::heldout`). An imported calibration must hold every camera
//! folder, training and held-out (`[poses] names` maps folders to its names), and each
//! camera's intrinsics are fitted to that camera's own video size (`streams.json`) and
//! working size (`frames.json`), see `calib::poses::select_cameras`. With `[poses]
//! intrinsics = "lens.yaml"` the lenses of that file (fitted the same way) are held fixed
//! while COLMAP solves the poses.

use std::path::{Path, PathBuf};

use anyhow::Context;
use calib::poses::{CaptureCamera, PosesConfig};
use rig::frames::FramesIndex;

use crate::heldout::{HELDOUT_FILE, split_poses};
use crate::stage_context::StageContext;
use crate::stages::ingest::read_streams;

/// `[poses]` settings: the pose solver's own (COLMAP options, minimum stills, rig radius,
/// the names of the camera folders in an imported calibration, known lenses).
pub type PosesSettings = PosesConfig;

/// The `poses` stage; `heldout` are the held-out camera names of `[capture] heldout`.
pub fn run(ctx: &StageContext, settings: &PosesSettings, heldout: &[String]) -> anyhow::Result<()> {
    let frames_dir = ctx.stage_dir("frames");
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let folders = capture_cameras(ctx, &index, heldout)?;
    if let Some(calibration) = &ctx.capture.calibration {
        tracing::info!(
            "importing the calibration {} instead of solving poses",
            calibration.display()
        );
        if let Some(lenses) = &settings.intrinsics {
            tracing::warn!(
                "[poses] intrinsics = {} is not used: the calibration {} gives the lenses too",
                lenses.display(),
                calibration.display()
            );
        }
        let options = calib::import::ImportOptions {
            units: settings.units,
        };
        let set = calib::import::import_calibration_with(calibration, &options)
            .with_context(|| format!("cannot import {}", calibration.display()))?;
        calib::poses::write_imported(
            &set,
            calibration,
            &ctx.out_dir,
            &folders,
            &settings.names,
            settings.radius,
        )?;
        return split_poses(
            &ctx.out_dir,
            heldout,
            &format!("the calibration {}", calibration.display()),
        );
    }
    let known_lenses = match &settings.intrinsics {
        None => Default::default(),
        Some(file) => {
            let path = ctx.capture.root.join(file);
            let lenses = calib::import::import_lenses(&path).with_context(|| {
                format!(
                    "cannot read the known lenses [poses] intrinsics = {}",
                    path.display()
                )
            })?;
            tracing::info!(
                "solving poses with the lenses of {} held fixed",
                path.display()
            );
            calib::poses::select_cameras(&lenses, &folders, &settings.names, &path)?
                .into_iter()
                .map(|c| (c.name, (c.intrinsics, c.distortion)))
                .collect()
        }
    };
    // Held-out cameras are posed with the training cameras, from their first frame too.
    let mut video_frames = first_frames(&index, &frames_dir)?;
    if !heldout.is_empty() {
        let held = FramesIndex::read_json(&frames_dir.join(HELDOUT_FILE))?;
        video_frames.extend(first_frames(&held, &frames_dir)?);
    }
    let inputs = calib::poses::PosesInputs {
        video_frames,
        stills: ctx.capture.stills.clone(),
        working_size: None,
        config: settings.clone(),
        known_lenses,
    };
    let out = calib::poses::solve(&inputs, &ctx.out_dir, ctx.progress)?;
    tracing::info!("poses solved: {} sparse points", out.points.len());
    split_poses(&ctx.out_dir, heldout, "the COLMAP model")
}

/// Every camera folder, training and held-out, with its own recorded size
/// (`streams.json`) and working size (`frames.json`).
fn capture_cameras(
    ctx: &StageContext,
    index: &FramesIndex,
    heldout: &[String],
) -> anyhow::Result<Vec<CaptureCamera>> {
    let mut cameras = index.cameras.clone();
    if !heldout.is_empty() {
        let held = FramesIndex::read_json(&ctx.stage_dir("frames").join(HELDOUT_FILE))?;
        cameras.extend(held.cameras);
    }
    let streams = read_streams(ctx)?;
    Ok(cameras
        .into_iter()
        .map(|c| CaptureCamera {
            recorded: streams
                .camera(&c.name)
                .map(|s| (s.video.width, s.video.height)),
            working: (c.width, c.height),
            name: c.name,
        })
        .collect())
}

/// (camera name, its first aligned frame) of every camera of a frames index.
pub fn first_frames(
    index: &FramesIndex,
    frames_dir: &Path,
) -> anyhow::Result<Vec<(String, PathBuf)>> {
    let first = index
        .frames
        .first()
        .context("the frames stage wrote no frames")?;
    Ok(index
        .cameras
        .iter()
        .zip(&first.views)
        .map(|(cam, view)| (cam.name.clone(), frames_dir.join(&view.file)))
        .collect())
}
