//! The `init` stage: the initial point cloud, from MASt3R-style point maps (an ONNX model
//! run here on pairs of the first aligned frames, or point maps exported beforehand),
//! else the poses stage's sparse points, else a random cloud (`calib::init`,
//! docs/init.md), into `points.ply` and `init.json`.

use std::path::PathBuf;

use anyhow::Context;
use calib::init::{InitConfig, InitInputs, ViewImage};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use shared_types::atomic::write_atomic;

use crate::engine_inputs::time_mapping;
use crate::layout::Capture;
use crate::stage_context::StageContext;

/// `[init]` settings: the initialiser's own. `model` (the ONNX point-map model) and
/// `pointmaps` (a folder of exported point maps) are relative to the capture directory.
pub type InitSettings = InitConfig;

/// The capture files the stage reads: the `model` file and the `pointmaps` folder, when set.
pub fn inputs(capture: &Capture, settings: &InitSettings) -> Vec<PathBuf> {
    [&settings.model, &settings.pointmaps]
        .into_iter()
        .flatten()
        .map(|path| capture.resolve(path))
        .collect()
}

/// The `init` stage.
pub fn run(ctx: &StageContext, settings: &InitSettings) -> anyhow::Result<()> {
    let frames_dir = ctx.stage_dir("frames");
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let poses_dir = ctx.stage_dir("poses");
    let poses = PosesFile::read(&poses_dir.join("cameras.json"))?;
    let first = index
        .frames
        .first()
        .context("the frames stage wrote no frames; rerun it")?;
    let mapping = time_mapping(&index);
    let images = index
        .cameras
        .iter()
        .zip(&first.views)
        .map(|(camera, view)| ViewImage {
            camera: camera.name.clone(),
            path: frames_dir.join(&view.file),
            time: mapping.model_time(view.timestamp_s),
        })
        .collect();
    let sparse = poses
        .points_file
        .as_ref()
        .map(|f| poses_dir.join(f))
        .filter(|p| p.exists());
    let mut config = settings.clone();
    config.model = config.model.map(|p| ctx.capture.resolve(&p));
    config.pointmaps = config.pointmaps.map(|p| ctx.capture.resolve(&p));
    let inputs = InitInputs {
        cameras: poses.set,
        images,
        sparse,
    };
    let report = calib::init::run_init(&inputs, &config, &ctx.out_dir, ctx.progress)?;
    write_atomic(
        &ctx.output("init.json"),
        &serde_json::to_vec_pretty(&report)?,
    )
    .context("cannot write init.json")?;
    Ok(())
}
