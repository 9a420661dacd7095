//! The stages of the 4C4D pipeline, declared once, in order. Each stage's parameters are
//! its own `capture.toml` section; its inputs are the capture files it reads plus the
//! outputs of the stages named in `after`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use rig::frames::FramesIndex;
use rig::ingest::Streams;
use rig::sync::SyncResult;

use crate::layout::Capture;
use crate::runner::Pipeline;
use crate::stage::{StageContext, StageDef};

/// Every camera's video files (training and held-out cameras).
fn raw_videos(capture: &Capture) -> Vec<PathBuf> {
    capture
        .all_cameras()
        .flat_map(|c| c.videos.iter().cloned())
        .collect()
}

fn read_streams(ctx: &StageContext) -> anyhow::Result<Streams> {
    Ok(Streams::read_json(
        &ctx.stage_dir("ingest").join("streams.json"),
    )?)
}

fn ingest(ctx: &StageContext) -> anyhow::Result<()> {
    let cameras: Vec<(String, PathBuf)> = ctx
        .capture
        .all_cameras()
        .map(|c| (c.name.clone(), c.dir.clone()))
        .collect();
    let streams = rig::ingest::ingest(&cameras, ctx.progress)?;
    streams.write_json(&ctx.output("streams.json"))?;
    Ok(())
}

fn sync(ctx: &StageContext) -> anyhow::Result<()> {
    let streams = read_streams(ctx)?;
    let result = rig::sync::synchronise(&streams, &ctx.config.sync, ctx.progress)?;
    for cam in &result.cameras {
        match cam.confidence {
            Some(c) => tracing::info!(
                "{}: offset {:+.4} s (confidence {c:.1})",
                cam.name,
                cam.offset_s
            ),
            None => tracing::info!("{}: offset {:+.4} s", cam.name, cam.offset_s),
        }
    }
    result.write_json(&ctx.output("sync.json"))?;
    Ok(())
}

fn frames(ctx: &StageContext) -> anyhow::Result<()> {
    let streams = read_streams(ctx)?;
    let sync = SyncResult::read_json(&ctx.stage_dir("sync").join("sync.json"))?;
    let index = rig::frames::extract(
        &streams,
        &sync,
        &ctx.config.frames,
        &ctx.out_dir,
        ctx.progress,
    )?;
    tracing::info!(
        "{} aligned frames at {:.3} fps",
        index.frames.len(),
        index.fps
    );
    let heldout_names = &ctx.config.capture.heldout;
    if !heldout_names.is_empty() {
        let (train, heldout) = crate::heldout::split_frames(&index, heldout_names)?;
        train.write_json(&ctx.output("frames.json"))?;
        heldout.write_json(&ctx.output(crate::heldout::HELDOUT_FILE))?;
        tracing::info!("held out from training: {}", heldout_names.join(", "));
    }
    Ok(())
}

fn poses(ctx: &StageContext) -> anyhow::Result<()> {
    let config = &ctx.config.poses;
    let heldout = &ctx.config.capture.heldout;
    let frames_dir = ctx.stage_dir("frames");
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    if let Some(calibration) = &ctx.capture.calibration {
        tracing::info!(
            "importing the calibration {} instead of solving poses",
            calibration.display()
        );
        let set = calib::import::import_calibration(calibration)
            .with_context(|| format!("cannot import {}", calibration.display()))?;
        // The calibration is for the recorded size; the engine sees the working size.
        let working_size = index.cameras.first().map(|c| (c.width, c.height));
        calib::poses::write_imported(&set, calibration, &ctx.out_dir, working_size, config.radius)?;
        return crate::heldout::split_poses(
            &ctx.out_dir,
            heldout,
            &format!("the calibration {}", calibration.display()),
        );
    }
    // Held-out cameras are posed with the training cameras, from their first frame too.
    let mut video_frames = first_frames(&index, &frames_dir)?;
    if !heldout.is_empty() {
        let held = FramesIndex::read_json(&frames_dir.join(crate::heldout::HELDOUT_FILE))?;
        video_frames.extend(first_frames(&held, &frames_dir)?);
    }
    let inputs = calib::poses::PosesInputs {
        video_frames,
        stills: ctx.capture.stills.clone(),
        working_size: None,
        config: config.clone(),
    };
    let out = calib::poses::solve(&inputs, &ctx.out_dir, ctx.progress)?;
    tracing::info!("poses solved: {} sparse points", out.points.len());
    crate::heldout::split_poses(&ctx.out_dir, heldout, "the COLMAP model")
}

/// (camera name, its first aligned frame) of every camera of a frames index.
fn first_frames(index: &FramesIndex, frames_dir: &Path) -> anyhow::Result<Vec<(String, PathBuf)>> {
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

/// A stage's parameters: its own section, plus `heldout` (the held-out camera names) when
/// the capture has held-out cameras, so that listing them reruns the stage.
fn with_heldout(
    stage: &'static str,
) -> impl Fn(&crate::config::CaptureConfig) -> serde_json::Value {
    move |config| {
        let mut params = config.section(stage);
        if !config.capture.heldout.is_empty()
            && let Some(map) = params.as_object_mut()
        {
            map.insert("heldout".into(), config.capture.heldout.clone().into());
        }
        params
    }
}

/// The train stage's parameters: `[train]`, with `[decay]` under the key `decay`
/// (`status` then names a change `train.decay.variant`).
fn train_params(config: &crate::config::CaptureConfig) -> serde_json::Value {
    let mut params = config.section("train");
    if let Some(map) = params.as_object_mut() {
        map.insert("decay".into(), config.section("decay"));
    }
    params
}

/// The pipeline as `pipeline run` executes it.
pub fn pipeline() -> Pipeline {
    Pipeline {
        stages: vec![
            StageDef::new(
                "ingest",
                "probe every camera's videos: fps, size, per-frame timestamps, audio",
            )
            .inputs(raw_videos)
            .outputs(&["streams.json"])
            .run(ingest),
            StageDef::new(
                "sync",
                "find each camera's time offset from audio (clap) or a flash",
            )
            .after(&["ingest"])
            .inputs(raw_videos)
            .outputs(&["sync.json"])
            .run(sync),
            StageDef::new(
                "frames",
                "extract time-aligned frames at the working resolution",
            )
            .after(&["ingest", "sync"])
            .inputs(raw_videos)
            .params(with_heldout("frames"))
            .outputs(&["frames.json"])
            .run(frames),
            StageDef::new(
                "poses",
                "solve camera poses with COLMAP (4 views + stills) or import a calibration",
            )
            .after(&["frames"])
            .params(with_heldout("poses"))
            .inputs(|c| {
                let mut inputs = c.stills.clone();
                inputs.extend(c.calibration.clone());
                inputs
            })
            .outputs(&["cameras.json"])
            .run(poses),
            StageDef::new(
                "init",
                "initial point cloud from MASt3R-style point maps or COLMAP points",
            )
            .after(&["frames", "poses"])
            .outputs(&["points.ply", "init.json"])
            .run(crate::initial_points::run),
            StageDef::new("train", "train the 4C4D Gaussian model")
                .after(&["frames", "poses", "init"])
                .params(train_params)
                .outputs(&["model.bin", "log.csv"])
                .resumable()
                .run(crate::training::run),
            StageDef::new("render", "render videos along camera paths")
                .after(&["frames", "poses", "train"])
                .run(crate::rendering::run),
            StageDef::new(
                "eval",
                "metrics on held-out views (PSNR, SSIM, DSSIM, LPIPS)",
            )
            .after(&["sync", "frames", "poses", "train"])
            .inputs(|c| vec![c.root.join("groundtruth")])
            .params(with_heldout("eval"))
            .outputs(&["metrics.json", "per_frame.csv"])
            .run(crate::evaluation::run),
            StageDef::new("export", "PLY / .splatv exports and a browser viewer")
                .after(&["frames", "poses", "train"])
                .outputs(&["export.json"])
                .run(crate::exporting::run),
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upstream_stages_come_first() {
        let p = pipeline();
        for (i, stage) in p.stages.iter().enumerate() {
            for up in &stage.after {
                let j = p
                    .stages
                    .iter()
                    .position(|s| s.name == *up)
                    .expect("known upstream");
                assert!(j < i, "{} reads {} which comes later", stage.name, up);
            }
        }
    }
}
