//! The `train` stage: the 4C4D Gaussian model trained on every aligned frame of the
//! training cameras (undistorted to pinhole cameras, at their exact timestamps), from the
//! init stage's points (`splat4d::train` with the opacity decay of `splat4d::decay`),
//! into `model.bin` and `log.csv`. It can stop cleanly on Ctrl-C (see `crate::interrupt`)
//! and continue from its checkpoint on the next run.

use anyhow::Context;
use splat4d::Gaussians;
use splat4d::decay::DecayConfig;
use splat4d::train::{
    ModelAccess, PointCloud, TrainConfig, TrainError, TrainHooks, TrainSummary, View,
};

use crate::engine_inputs::{EngineSettings, load_dataset};
use crate::interrupt::{Graceful, stop_requested};
use crate::stage_context::StageContext;
use shared_types::atomic::write_json;

/// `[train]` settings: the trainer's own (iterations, learning rates, densification, …).
pub type TrainSettings = TrainConfig;

/// `[decay]` settings: the 4C4D opacity decay the train stage trains with
/// (`variant = "none"`: plain 4DGS).
pub type DecaySettings = DecayConfig;

/// The stage's hooks: the method's hooks (4C4D decay, or none) plus the Ctrl-C stop.
pub(crate) struct StageHooks<'a> {
    pub inner: &'a mut dyn TrainHooks,
}

impl TrainHooks for StageHooks<'_> {
    fn opacity_factor(
        &mut self,
        iteration: u64,
        model: &Gaussians<f32>,
        view: &View,
    ) -> Option<Vec<f32>> {
        self.inner.opacity_factor(iteration, model, view)
    }
    fn factor_gradient(&mut self, iteration: u64, model: &Gaussians<f32>, gradient: &[f32]) {
        self.inner.factor_gradient(iteration, model, gradient)
    }
    fn after_step(&mut self, iteration: u64, model: &mut Gaussians<f32>) {
        self.inner.after_step(iteration, model)
    }
    fn save_state(&self) -> Vec<u8> {
        self.inner.save_state()
    }
    fn load_state(&mut self, state: &[u8]) {
        self.inner.load_state(state)
    }
    fn stop_requested(&mut self, iteration: u64) -> bool {
        stop_requested() || self.inner.stop_requested(iteration)
    }
    fn model_access(&self) -> ModelAccess {
        self.inner.model_access()
    }
    fn device_decay(&mut self) -> Option<splat4d::train::DeviceDecay<'_>> {
        self.inner.device_decay()
    }
}

/// The initial points: `work/init/points.ply`, else the poses stage's sparse points.
pub(crate) fn initial_points(ctx: &StageContext) -> anyhow::Result<PointCloud> {
    let init = ctx.stage_dir("init").join("points.ply");
    let path = if init.exists() {
        init
    } else {
        let sparse = ctx.stage_dir("poses").join("points3d.ply");
        tracing::warn!(
            "no {}; starting from the sparse pose points {}",
            init.display(),
            sparse.display()
        );
        sparse
    };
    shared_types::points::read_points_ply(&path)
        .with_context(|| format!("cannot read the initial points {}", path.display()))
}

/// Each camera's exposure gain measured on `dataset` and the points' static surfaces;
/// `dataset`'s frames divided by it.
pub(crate) fn match_exposure(
    dataset: &mut splat4d::train::Dataset,
    points: &PointCloud,
    progress: &dyn shared_types::Progress,
) -> Vec<splat4d::train::exposure::CameraGain> {
    progress.message("matching exposure");
    let gains = splat4d::train::exposure::estimate(dataset, points);
    splat4d::train::exposure::equalise(dataset, &gains);
    let text: Vec<String> = gains
        .iter()
        .map(|g| {
            format!(
                "{} [{:.3}, {:.3}, {:.3}]",
                g.camera, g.gain[0], g.gain[1], g.gain[2]
            )
        })
        .collect();
    tracing::info!("exposure gains (frames divided by): {}", text.join(", "));
    gains
}

/// A training run's outcome for the stage: the checkpoints it passed over on resuming are
/// logged as warnings, and a run stopped by Ctrl-C (or a cluster's signal) says how to go on.
pub(crate) fn finished(result: Result<TrainSummary, TrainError>) -> anyhow::Result<TrainSummary> {
    match result {
        Ok(summary) => {
            let then = match summary.started_at {
                0 => "no good checkpoint was left: started over".to_string(),
                it => format!("resumed from iteration {it}"),
            };
            for s in &summary.skipped_checkpoints {
                tracing::warn!("{s}; {then}");
            }
            Ok(summary)
        }
        Err(TrainError::Interrupted { iteration, .. }) => Err(anyhow::anyhow!(
            "training stopped after iteration {iteration} (a checkpoint was kept); run the same `pipeline run` again to continue from it, or add --force to start over"
        )),
        Err(e) => Err(e.into()),
    }
}

/// The `train` stage on one model of the whole clip (a clip cut into time chunks is
/// `crate::chunks::runner`'s).
pub fn run(
    ctx: &StageContext,
    settings: &TrainSettings,
    decay: &DecaySettings,
    engine: &EngineSettings,
) -> anyhow::Result<()> {
    let cameras_file = ctx.stage_dir("poses").join("cameras.json");
    ctx.progress.message("loading frames");
    let mut dataset = load_dataset(&ctx.stage_dir("frames"), &cameras_file, ctx.progress)?;
    let points = initial_points(ctx)?;
    let exposure = if settings.match_exposure {
        match_exposure(&mut dataset, &points, ctx.progress)
    } else {
        Vec::new()
    };
    tracing::info!(
        "training on {} views from {} points{}",
        dataset.views.len(),
        points.xyz.len(),
        if ctx.resume { " (resuming)" } else { "" }
    );
    let mut method = splat4d::decay::DecayHooks::new(decay)
        .map_err(|e| anyhow::anyhow!("capture.toml [decay]: {e}"))?;
    tracing::info!("opacity decay: {:?}", decay.variant);
    tracing::info!("{}", settings.densify.describe(settings.iterations));
    let mut hooks = StageHooks { inner: &mut method };
    let _graceful = Graceful::enter();
    let backend = crate::engine_inputs::training_backend_for(engine.backend)?;
    ctx.record_tool("training backend", &backend.describe());
    let summary = finished(splat4d::train::train(
        backend.as_ref(),
        settings,
        &dataset,
        &points,
        &ctx.out_dir,
        ctx.resume,
        &mut hooks,
        ctx.progress,
    ))?;
    tracing::info!(
        "trained {} iterations ({} this run) on {} (step on the {}) in {:.0} s: {} Gaussians, last batch PSNR {:.2} dB",
        summary.iterations,
        summary.iterations - summary.started_at,
        backend.describe(),
        summary.placement,
        summary.seconds,
        summary.gaussians,
        summary.final_psnr
    );
    tracing::info!(
        "background: {:?} ({:?})",
        summary.background,
        settings.background
    );
    if summary.pruned_unseen > 0 {
        let min = settings.densify.min_cameras;
        let where_ = if min == 1 {
            "in no training camera's image".to_string()
        } else {
            format!("inside fewer than {min} training cameras' images")
        };
        tracing::info!(
            "pruned {} Gaussians {where_} ([train.densify] min_cameras)",
            summary.pruned_unseen
        );
    }
    let record = crate::engine_inputs::TrainRecord {
        background: summary.background,
        exposure,
        backdrop: summary.backdrop.is_some(),
    };
    write_json(&ctx.output(crate::engine_inputs::TRAIN_RECORD), &record)
        .context("cannot write train.json")?;
    // What the decay did, as evidence (docs/decay.md "Is it working?").
    let model = splat4d::model::file::load_model(&summary.model_path)?;
    let report = splat4d::decay::report::report(&method, &model);
    write_json(&ctx.output("decay.json"), &report).context("cannot write decay.json")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine_inputs::{BackendChoice, training_backend_for};
    use splat4d::decay::{DecayHooks, DecayVariant};

    fn access(variant: DecayVariant) -> ModelAccess {
        let mut method = DecayHooks::new(&DecayConfig {
            variant,
            ..DecayConfig::default()
        })
        .unwrap();
        StageHooks { inner: &mut method }.model_access()
    }

    #[test]
    fn the_decay_decides_how_the_gpu_trains_and_cpu_is_honoured() {
        assert_eq!(access(DecayVariant::None), ModelAccess::None);
        for v in [DecayVariant::Constant, DecayVariant::Pow, DecayVariant::Exp] {
            assert_eq!(access(v), ModelAccess::EveryStep);
        }
        assert_eq!(access(DecayVariant::Neural), ModelAccess::OpacityFactor);
        let cpu = training_backend_for(BackendChoice::Cpu).unwrap();
        assert!(cpu.describe().starts_with("cpu"));
        assert!(cpu.as_gpu().is_none());
    }
}
