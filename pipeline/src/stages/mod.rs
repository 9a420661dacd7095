//! The stages of the 4C4D pipeline, declared once, in order: for each, the stages it
//! reads from, the capture files it reads, its parameters (its own `capture.toml`
//! section, plus any other setting it reads, so that changing it reruns the stage), the
//! outputs it must produce and the function that does the work.
//!
//! Each stage's work and its settings section live in its own module (`ingest`, `sync`,
//! `frames`, `poses`, `init`, `train`, `render`, `eval`, `export`); `config` gathers the
//! sections into `capture.toml`. A stage module never reads `capture.toml` itself: this
//! list hands each run function the settings it takes.

pub mod eval;
pub mod export;
pub mod frames;
pub mod ingest;
pub mod init;
pub mod poses;
pub mod render;
pub mod sync;
pub mod train;

use crate::config::CaptureConfig;
use crate::runner::Pipeline;
use crate::stage_context::StageContext;
use crate::stage_def::StageDef;

/// A stage's parameters: its own section, plus `heldout` (the held-out camera names) when
/// the capture has held-out cameras, so that listing them reruns the stage.
fn with_heldout(stage: &'static str) -> impl Fn(&CaptureConfig) -> serde_json::Value {
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
/// (`status` then names a change `train.decay.variant`) and `[chunks]` under `chunks`.
fn train_params(config: &CaptureConfig) -> serde_json::Value {
    let mut params = config.section("train");
    if let Some(map) = params.as_object_mut() {
        map.insert("decay".into(), config.section("decay"));
    }
    with_chunks(params, config)
}

/// `params` with `[chunks]` under the key `chunks` when it is not the default (so captures
/// trained before chunks existed keep their parameters).
fn with_chunks(mut params: serde_json::Value, config: &CaptureConfig) -> serde_json::Value {
    if config.chunks != crate::chunks::ChunkSettings::default()
        && let Some(map) = params.as_object_mut()
    {
        map.insert("chunks".into(), config.section("chunks"));
    }
    params
}

/// The `train` stage: one model of the whole clip, or, for a clip longer than
/// `[chunks] seconds`, one per time chunk merged into one (`crate::chunks`).
fn run_train(ctx: &StageContext, config: &CaptureConfig) -> anyhow::Result<()> {
    let index = rig::frames::FramesIndex::read_json(&ctx.stage_dir("frames").join("frames.json"))?;
    let plan = crate::chunks::plan::ChunkPlan::of_index(&index, &config.chunks);
    if plan.is_chunked() {
        crate::chunks::runner::run(
            ctx,
            &config.train,
            &config.chunks,
            &config.decay,
            &config.engine,
            &plan,
        )
    } else {
        train::run(ctx, &config.train, &config.decay, &config.engine)
    }
}

/// The pipeline as `pipeline run` executes it.
pub fn pipeline() -> Pipeline {
    Pipeline {
        stages: vec![
            StageDef::new(
                "ingest",
                "probe every camera's videos: fps, size, per-frame timestamps, audio",
            )
            .inputs(|c, _| c.all_videos())
            .outputs(&["streams.json"])
            .run(|ctx, config| ingest::run(ctx, &config.ingest)),
            StageDef::new(
                "sync",
                "find each camera's time offset from audio (clap) or a flash",
            )
            .after(&["ingest"])
            .inputs(|c, _| c.all_videos())
            .outputs(&["sync.json"])
            .run(|ctx, config| sync::run(ctx, &config.sync)),
            StageDef::new(
                "frames",
                "extract time-aligned frames at the working resolution",
            )
            .after(&["ingest", "sync"])
            .inputs(|c, _| c.all_videos())
            .params(with_heldout("frames"))
            .outputs(&["frames.json"])
            .run(|ctx, config| frames::run(ctx, &config.frames, &config.capture.heldout)),
            StageDef::new(
                "poses",
                "solve camera poses with COLMAP (4 views + stills) or import a calibration",
            )
            .after(&["ingest", "frames"])
            .params(with_heldout("poses"))
            .inputs(|c, config| {
                let mut inputs = c.stills.clone();
                inputs.extend(c.calibration.clone());
                inputs.extend(config.poses.intrinsics.as_ref().map(|f| c.root.join(f)));
                inputs
            })
            .outputs(&["cameras.json"])
            .run(|ctx, config| poses::run(ctx, &config.poses, &config.capture.heldout)),
            StageDef::new(
                "init",
                "initial point cloud from MASt3R-style point maps or COLMAP points",
            )
            .after(&["frames", "poses"])
            .inputs(|c, config| init::inputs(c, &config.init))
            .outputs(&["points.ply", "init.json"])
            .params(|config| with_chunks(config.section("init"), config))
            .run(|ctx, config| init::run(ctx, &config.init, &config.chunks)),
            StageDef::new("train", "train the 4C4D Gaussian model")
                .after(&["frames", "poses", "init"])
                .params(train_params)
                .outputs(&["model.bin", "log.csv", crate::engine_inputs::TRAIN_RECORD])
                .resumable()
                .on_engine()
                .run(run_train),
            StageDef::new("render", "render videos along camera paths")
                .after(&["frames", "poses", "train"])
                .output_one_of(&render::OUTPUTS)
                .on_engine()
                .run(|ctx, config| {
                    let trained = crate::engine_inputs::trained_record(
                        &ctx.capture.work_dir(),
                        config.train.background,
                    )?;
                    render::run(ctx, &config.render, &trained, &config.engine)
                }),
            StageDef::new(
                "eval",
                "metrics on held-out views (PSNR, SSIM, DSSIM, LPIPS)",
            )
            .after(&["sync", "frames", "poses", "train"])
            .inputs(|c, config| eval::inputs(c, &config.eval))
            .params(with_heldout("eval"))
            .outputs(&["metrics.json", "per_frame.csv"])
            .on_engine()
            .run(|ctx, config| {
                let trained = crate::engine_inputs::trained_record(
                    &ctx.capture.work_dir(),
                    config.train.background,
                )?;
                eval::run(
                    ctx,
                    &config.eval,
                    &config.capture.heldout,
                    &trained,
                    &config.engine,
                    config.plate_masks(),
                )
            }),
            StageDef::new("export", "PLY / .splatv exports and a browser viewer")
                .after(&["frames", "poses", "train"])
                .outputs(&["export.json"])
                .run(|ctx, config| {
                    let trained = crate::engine_inputs::trained_record(
                        &ctx.capture.work_dir(),
                        config.train.background,
                    )?;
                    export::run(ctx, &config.export, &trained)
                }),
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
