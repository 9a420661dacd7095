//! The `export` stage: the trained model as per-timestep 3DGS PLY frames, the native 4D
//! PLY, a `.splatv` and the browser viewer (`splat4d::export`, docs/export.md), listed
//! in `export.json`.

use anyhow::Context;
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use shared_types::atomic::write_atomic;
use splat4d::export::ExportOptions;

use crate::engine_inputs::load_trained_model;
use crate::stage_context::StageContext;

/// `[export]` settings: the exporter's own (time steps, which files, viewer options).
pub type ExportSettings = ExportOptions;

/// The `export` stage.
pub fn run(ctx: &StageContext, options: &ExportSettings) -> anyhow::Result<()> {
    let model = load_trained_model(&ctx.capture.work_dir())?;
    let poses = PosesFile::read(&ctx.stage_dir("poses").join("cameras.json"))?;
    let index = FramesIndex::read_json(&ctx.stage_dir("frames").join("frames.json"))?;
    let times = options.times(&model, index.frames.len());
    let report = splat4d::export::export_all(
        &model,
        &poses.set,
        &times,
        &ctx.out_dir,
        options,
        ctx.progress,
    )?;
    tracing::info!(
        "exported {} time steps of {} Gaussians in {:.1} s{}",
        report.frames.len(),
        report.gaussians,
        report.seconds,
        match &report.viewer_index {
            Some(_) => format!(
                "; open {} in a browser",
                ctx.stage_dir("export").join("viewer/index.html").display()
            ),
            None => String::new(),
        }
    );
    write_atomic(
        &ctx.output("export.json"),
        &serde_json::to_vec_pretty(&report)?,
    )
    .context("cannot write export.json")?;
    Ok(())
}
