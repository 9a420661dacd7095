//! The trainer: random batches of (camera, frame) views, each at its frame's exact model
//! time; loss `(1 − λ)·L1 + λ·(1 − SSIM)`; Adam; colour-degree schedule; densification;
//! checkpoints, `log.csv`, progress; bit-identical resume; a NaN guard. Library only: it
//! knows nothing of capture directories or stage manifests (the `pipeline` crate does).
//!
//! Randomness is drawn from a ChaCha8 stream chosen by `(seed, iteration)`, so a run
//! resumed from a checkpoint replays exactly the batches and splits of the original.

mod backdrop_fit;
pub mod background;
pub mod checkpoint;
pub mod dataset;
pub mod densify;
mod device_step;
pub mod exposure;
mod frozen;
pub mod gpu;
pub mod log;
pub mod loss;
pub mod optim;
pub mod pseudo_view;
pub mod regularise;
mod step;

pub use crate::model::init::PointCloud;
pub use background::Background;
pub use dataset::{Dataset, FrameSource, ImageLoadError, ImageU8, View};
pub use step::ModelAccess;

use crate::decay::config::DecayConfig;
use crate::decay::gpu::GpuDecay;
use crate::decay::mlp::{Mlp, MlpAdam};
use crate::metrics::{mse, psnr_from_mse};
use crate::model::init::{InitOptions, SeedError, gaussians_from_points};
use crate::model::{ColourDegrees, Gaussians};
use crate::render::backdrop::save_backdrop;
use crate::render::{RenderBackend, RenderError, RenderOptions};
use crate::train::densify::{DensifyConfig, DensifyStats, densify_and_prune, reset_opacity};
use crate::train::device_step::DeviceStep;
use crate::train::optim::{Adam, LearningRates, colour_degrees_at};
use crate::train::pseudo_view::PseudoViewConfig;
use crate::train::step::{HostStep, Stepper};
use crate::{Progress, save_model};
use checkpoint::{Checkpoint, CheckpointError};
use log::{LogRow, TrainLog};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Views per optimiser step where `batch_size` is not set.
pub const DEFAULT_BATCH_SIZE: usize = 4;

/// Training parameters: the `[train]` section of `capture.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    pub iterations: u64,
    /// Training resolution as a fraction of the frames' size, in (0, 1]: 0.5 trains on
    /// images of half the width and height (about a quarter of the time per step); the
    /// model still renders at any size.
    pub resolution: f64,
    /// Views rendered per optimiser step (their gradients are averaged;
    /// [`DEFAULT_BATCH_SIZE`] by default).
    pub batch_size: usize,
    pub seed: u64,
    /// Weight λ of `(1 − SSIM)` in the loss.
    pub lambda_ssim: f64,
    /// What the model is drawn on (`"learned"`: a backdrop fitted behind the trained
    /// Gaussians, which train on the mean colour; `"mean"`: the training images' mean
    /// colour; [`Background`]).
    pub background: Background,
    /// With `background = "learned"`: texels around the backdrop's finest level (a power
    /// of two; 32 keeps only a smooth colour per direction).
    pub backdrop_size: usize,
    /// Colour storage (spatial SH degree ≤ 3, temporal degree ≤ 2).
    pub colour_degrees: ColourDegrees,
    /// The active colour degree grows every this many iterations (0: DC only).
    pub degree_every: u64,
    /// Initial opacity of the Gaussians made from the point cloud.
    pub init_opacity: f64,
    /// Initial temporal σ as a fraction of the sequence duration.
    pub init_time_scale: f64,
    /// Initial Gaussians on planar patches of the point cloud are disks this thick
    /// relative to their radius (0: balls, as 3DGS; see `model::init`).
    pub init_flatness: f64,
    /// Moving points of the init (time span 0, from point maps at several moments) start
    /// moving with the velocity of their nearest moving points at the neighbouring moments
    /// (`model::motion`; on by default, a no-op for clouds without such moments).
    pub init_velocity: bool,
    /// Largest allowed ratio of a Gaussian's longest spatial axis to its middle one
    /// (needles are reshaped into ribbons after every step; 0: no limit).
    pub max_anisotropy: f64,
    /// Divide each camera's frames by its exposure and white-balance gain, measured on the
    /// initial points' static surfaces, before training ([`exposure`]; the caller applies
    /// it, as the pipeline's train stage does).
    pub match_exposure: bool,
    pub lr: LearningRates,
    pub densify: DensifyConfig,
    /// Pseudo views beside the training cameras ([`pseudo_view`]).
    pub pseudo_views: PseudoViewConfig,
    /// Write a checkpoint every this many iterations (0: only at the end).
    pub checkpoint_every: u64,
    /// Checkpoints kept on disk (older ones are deleted).
    pub keep_checkpoints: usize,
    /// Update the progress message every this many iterations.
    pub report_every: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            iterations: 30_000,
            resolution: 1.0,
            batch_size: DEFAULT_BATCH_SIZE,
            seed: 0,
            lambda_ssim: 0.2,
            background: Background::Learned,
            backdrop_size: 1024,
            colour_degrees: ColourDegrees::FULL,
            degree_every: 1000,
            init_opacity: 0.1,
            init_time_scale: 0.2,
            init_flatness: 0.0,
            init_velocity: true,
            max_anisotropy: 0.0,
            match_exposure: true,
            lr: LearningRates::default(),
            densify: DensifyConfig::default(),
            pseudo_views: PseudoViewConfig::default(),
            checkpoint_every: 1000,
            keep_checkpoints: 3,
            report_every: 10,
        }
    }
}

impl TrainConfig {
    /// How the Gaussians are made from the init's points.
    pub fn init_options(&self) -> InitOptions {
        InitOptions {
            opacity: self.init_opacity,
            time_scale_fraction: self.init_time_scale,
            capacity: self.colour_degrees,
            seed: self.seed,
            flatness: self.init_flatness,
            velocity: self.init_velocity,
        }
    }
}

/// Densifications a shortened schedule keeps in its window ([`TrainConfig::with_iterations`]).
pub const MIN_DENSIFICATIONS: u64 = 5;

impl TrainConfig {
    /// This configuration shortened (or lengthened) to `iterations`, with every schedule
    /// that counts iterations (colour degree, densification window, opacity reset,
    /// position decay) scaled by the same factor; checkpoints only at the end. The
    /// densification interval is how many views the statistics gather, so it is kept, but
    /// a shortened schedule whose window would hold fewer than [`MIN_DENSIFICATIONS`]
    /// densifications gets a shorter one (a 300-step run of the demo's 2000-step schedule
    /// densified not at all).
    pub fn with_iterations(&self, iterations: u64) -> Self {
        let s = iterations as f64 / self.iterations.max(1) as f64;
        let scale = |n: u64| (n as f64 * s).round() as u64;
        let mut c = self.clone();
        c.iterations = iterations;
        c.degree_every = scale(self.degree_every).max(1);
        c.densify.from_iteration = scale(self.densify.from_iteration);
        c.densify.until_iteration = scale(self.densify.until_iteration);
        if iterations < self.iterations && c.densify.count() < MIN_DENSIFICATIONS {
            let window = c
                .densify
                .until_iteration
                .saturating_sub(c.densify.from_iteration);
            c.densify.every = (window / MIN_DENSIFICATIONS).max(1);
        }
        c.densify.opacity_reset_every = scale(self.densify.opacity_reset_every);
        c.lr.position_decay_steps = scale(self.lr.position_decay_steps);
        c.checkpoint_every = 0;
        c
    }
}

/// Why training stopped without a model.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("invalid [train] setting: {0}")]
    Config(String),
    #[error(
        "the dataset has no views; check that the frames and poses stages produced images and cameras"
    )]
    NoViews,
    #[error(
        "view {index} (camera '{camera}') has a {image_w}×{image_h} image but a {camera_w}×{camera_h} camera; use View::at_image_size"
    )]
    ImageSize {
        index: usize,
        camera: String,
        image_w: u32,
        image_h: u32,
        camera_w: u32,
        camera_h: u32,
    },
    #[error(transparent)]
    Seed(#[from] SeedError),
    #[error("rendering view {index} failed: {source}")]
    Render { index: usize, source: RenderError },
    #[error("moving the training state to or from the GPU failed: {0}")]
    Device(RenderError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Backdrop(#[from] crate::render::backdrop::BackdropFileError),
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "training diverged at iteration {iteration}: {what} became NaN or infinite; no model was written{}. Try lower learning rates in [train.lr] (e.g. halve position_init and opacity) or a smaller batch",
        match last_checkpoint { Some(p) => format!(" (last good checkpoint: {})", p.display()), None => String::new() }
    )]
    NonFinite {
        iteration: u64,
        what: &'static str,
        last_checkpoint: Option<PathBuf>,
    },
    #[error(
        "all Gaussians were pruned at iteration {iteration}; lower [train.densify] min_opacity or raise max_world_size / max_screen_radius"
    )]
    EmptyModel { iteration: u64 },
    #[error("training was stopped after iteration {iteration}; checkpoint {} was written, rerun with --resume to continue", checkpoint.display())]
    Interrupted { iteration: u64, checkpoint: PathBuf },
    #[error("resume refused: {0}")]
    Resume(String),
}

/// What the caller can plug into every step: the 4C4D neural decay seam.
pub trait TrainHooks {
    /// A per-Gaussian render-opacity factor for this view (length = model size), or None.
    fn opacity_factor(
        &mut self,
        _iteration: u64,
        _model: &Gaussians<f32>,
        _view: &View,
    ) -> Option<Vec<f32>> {
        None
    }
    /// dLoss/d(factor) of the view rendered with the factor returned just before.
    fn factor_gradient(&mut self, _iteration: u64, _model: &Gaussians<f32>, _gradient: &[f32]) {}
    /// Called after each optimiser step (1-based `iteration`); may edit the model.
    fn after_step(&mut self, _iteration: u64, _model: &mut Gaussians<f32>) {}
    /// State saved into checkpoints (for bit-identical resume of stateful hooks).
    fn save_state(&self) -> Vec<u8> {
        Vec::new()
    }
    fn load_state(&mut self, _state: &[u8]) {}
    /// Polled after every iteration (1-based): `true` stops the run cleanly with a
    /// checkpoint at that iteration (wire Ctrl-C here); `--resume` continues it.
    fn stop_requested(&mut self, _iteration: u64) -> bool {
        false
    }
    /// What `opacity_factor`, `factor_gradient` and `after_step` do with the model. The
    /// GPU backend keeps the model on the device between host syncs: with
    /// [`ModelAccess::None`] the hooks see the host copy as of the last sync; with
    /// `EveryStep` the model comes to the host (and back) every step; with
    /// `OpacityFactor` (the default, safe for any hooks) the GPU backend takes the host
    /// path (render and backward on the GPU, loss and Adam on the host). Either is moot
    /// when [`TrainHooks::device_decay`] lends the decay to run on the device.
    fn model_access(&self) -> ModelAccess {
        ModelAccess::OpacityFactor
    }
    /// The 4C4D decay's settings and f_θ's state, when these hooks are that decay
    /// and a trainer may run it on its device. The GPU trainer then runs the decay's
    /// whole step on the device (visibility and the write-back; for the neural variant
    /// also τ, the factor gradient and f_θ's Adam; see `decay::gpu::GpuDecay`) and calls neither `opacity_factor` nor
    /// `factor_gradient`; `after_step` still comes, with the host model as of the last sync
    /// (the decay then has nothing to do in it). f_θ's state comes back at host syncs, so
    /// `save_state` sees it current. Other trainers ignore this and use the methods above.
    fn device_decay(&mut self) -> Option<DeviceDecay<'_>> {
        None
    }
}

/// Hooks that do nothing (plain 4DGS).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoHooks;
impl TrainHooks for NoHooks {
    fn model_access(&self) -> ModelAccess {
        ModelAccess::None
    }
}

/// The decay's settings and f_θ's state, lent to a trainer that runs the decay on
/// its device ([`TrainHooks::device_decay`]) instead of calling `opacity_factor`,
/// `factor_gradient` and `after_step` for it. The trainer keeps f_θ and its moments on the
/// device and writes them back here at its host syncs (checkpoints, a stop, the end), and
/// reports every decayed step in `last` and `skipped_updates`. It belongs to the hooks'
/// seam, like [`TrainHooks`]: the decay (`decay::DecayHooks`) lends it, the trainer's
/// device step (`device_step`, with `decay::gpu::GpuDecay`) uses it.
pub struct DeviceDecay<'a> {
    pub config: &'a DecayConfig,
    pub mlp: &'a mut Mlp<f32>,
    pub adam: &'a mut MlpAdam,
    pub last: &'a mut Option<StepStats>,
    pub skipped_updates: &'a mut u64,
}

/// What the decay did in the last step (for logs and tests): recorded by the decay's host
/// hooks, or by the trainer's device step through [`DeviceDecay::last`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepStats {
    /// 1-based optimiser step.
    pub iteration: u64,
    /// Gaussians visible in at least one view of the batch, and the rest.
    pub visible: usize,
    pub invisible: usize,
    /// Smallest, mean and largest factor applied to the stored opacities.
    pub min_factor: f64,
    pub mean_factor: f64,
    pub max_factor: f64,
}

/// Outcome of a finished run.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainSummary {
    pub iterations: u64,
    /// Iteration the run started from (0, or the resumed checkpoint).
    pub started_at: u64,
    /// Mean loss and PSNR of the last iteration's batch.
    pub final_loss: f64,
    pub final_psnr: f64,
    pub gaussians: usize,
    pub seconds: f64,
    pub model_path: PathBuf,
    /// Where the iterations ran: `host` (render and backward by the backend, loss and
    /// Adam on the host) or `gpu` (the whole step on the GPU).
    pub placement: &'static str,
    /// Checkpoints that were damaged or not this run's, passed over (and renamed
    /// `*.damaged`) on resuming, newest first.
    pub skipped_checkpoints: Vec<checkpoint::Skipped>,
    /// The background colour the model was trained on (`[train] background` resolved).
    pub background: [f32; 3],
    /// The learned backdrop's file, when the model was trained on one.
    pub backdrop: Option<PathBuf>,
    /// Gaussians this run pruned for lying inside too few training cameras' images
    /// (`[train.densify] min_cameras`).
    pub pruned_unseen: usize,
}

fn validate(config: &TrainConfig, dataset: &Dataset) -> Result<(), TrainError> {
    let bad = |s: &str| Err(TrainError::Config(s.into()));
    if config.batch_size == 0 {
        return bad("batch_size must be at least 1");
    }
    if !(config.resolution > 0.0 && config.resolution <= 1.0) {
        return bad("resolution must be in (0, 1] (a fraction of the frames' size)");
    }
    if !(0.0..=1.0).contains(&config.lambda_ssim) {
        return bad("lambda_ssim must be in [0, 1]");
    }
    if !config.colour_degrees.is_valid() {
        return bad("colour_degrees: spatial ≤ 3 and temporal ≤ 2");
    }
    if !config.lr.is_valid() {
        return bad("learning rates must be finite and ≥ 0");
    }
    if !(config.init_opacity > 0.0 && config.init_opacity < 1.0) {
        return bad("init_opacity must be in (0, 1)");
    }
    if !(config.max_anisotropy == 0.0 || config.max_anisotropy > 1.0) {
        return bad("max_anisotropy must be 0 (no limit) or greater than 1");
    }
    if !(config.backdrop_size.is_power_of_two() && (16..=8192).contains(&config.backdrop_size)) {
        return bad("backdrop_size must be a power of two from 16 to 8192 (texels around)");
    }
    if !(0.0..=1.0).contains(&config.init_flatness) {
        return bad("init_flatness must be in [0, 1] (0: round Gaussians)");
    }
    if let Some(problem) = config.pseudo_views.problem() {
        return bad(problem);
    }
    if dataset.views.is_empty() {
        return Err(TrainError::NoViews);
    }
    for (index, v) in dataset.views.iter().enumerate() {
        if !v.camera.distortion.is_none() {
            let camera = v.camera.name.clone();
            return Err(TrainError::Render {
                index,
                source: RenderError::DistortedCamera { camera },
            });
        }
        if !v.time.is_finite() {
            return Err(TrainError::Config(format!(
                "view {index} has a non-finite time"
            )));
        }
        let i = &v.camera.intrinsics;
        if (i.width, i.height) != (v.image.width, v.image.height)
            || v.image.data.len() != 3 * v.image.width as usize * v.image.height as usize
        {
            return Err(TrainError::ImageSize {
                index,
                camera: v.camera.name.clone(),
                image_w: v.image.width,
                image_h: v.image.height,
                camera_w: i.width,
                camera_h: i.height,
            });
        }
    }
    Ok(())
}

/// The RNG of one iteration: stream `iteration` of the run's seed.
fn iteration_rng(seed: u64, iteration: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(iteration);
    rng
}

/// `batch` distinct view indices (all of them, shuffled, when there are fewer).
fn sample_batch(rng: &mut ChaCha8Rng, views: usize, batch: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..views).collect();
    let k = batch.min(views);
    for i in 0..k {
        let j = i + (rng.next_u64() % (views - i) as u64) as usize;
        idx.swap(i, j);
    }
    idx.truncate(k);
    idx
}

fn all_finite(model: &Gaussians<f32>) -> bool {
    let v4 = |v: &Vec<[f32; 4]>| v.iter().flatten().all(|x| x.is_finite());
    v4(&model.means)
        && v4(&model.log_scales)
        && v4(&model.rot_left)
        && v4(&model.rot_right)
        && model.opacity_logits.iter().all(|x| x.is_finite())
        && model.colours.iter().all(|x| x.is_finite())
}

/// Where training starts.
#[derive(Clone, Copy, Debug)]
pub enum Start<'a> {
    /// Gaussians made from a point cloud (`model::init`, with the config's init options).
    Points(&'a PointCloud),
    /// A given first model whose first `frozen` Gaussians never change: a static scene
    /// trained earlier and shared by several time chunks (`pipeline`'s chunk runner).
    /// Adam, densification, opacity resets and the hooks leave them as they are, and the
    /// budget `max_gaussians` counts only the others. `points` places the learned backdrop.
    Model {
        model: &'a Gaussians<f32>,
        frozen: usize,
        points: &'a PointCloud,
    },
}

impl<'a> Start<'a> {
    fn points(&self) -> &'a PointCloud {
        match *self {
            Start::Points(p) | Start::Model { points: p, .. } => p,
        }
    }
    fn frozen(&self) -> usize {
        match *self {
            Start::Points(_) => 0,
            Start::Model { frozen, .. } => frozen,
        }
    }
}

/// Train a model on `dataset` from `init`, writing `out_dir/{ckpt/, model.bin, log.csv}`
/// and, with `background = "learned"`, the backdrop fitted behind it ([`BACKDROP_FILE`]).
/// With `resume`, continue from the newest complete checkpoint in `out_dir/ckpt` (a fresh
/// start when there is none). Every view is rendered and differentiated by `backend`; with
/// the GPU backend the whole iteration runs on the GPU (see [`TrainHooks::model_access`]
/// for hooks, and `docs/training.md`).
#[allow(clippy::too_many_arguments)]
pub fn train(
    backend: &dyn RenderBackend,
    config: &TrainConfig,
    dataset: &Dataset,
    init: &PointCloud,
    out_dir: &Path,
    resume: bool,
    hooks: &mut dyn TrainHooks,
    progress: &dyn Progress,
) -> Result<TrainSummary, TrainError> {
    train_from(
        backend,
        config,
        dataset,
        Start::Points(init),
        out_dir,
        resume,
        hooks,
        progress,
    )
}

/// [`train`] from `origin`: a point cloud, or a model with frozen Gaussians at its front.
#[allow(clippy::too_many_arguments)]
pub fn train_from(
    backend: &dyn RenderBackend,
    config: &TrainConfig,
    dataset: &Dataset,
    origin: Start<'_>,
    out_dir: &Path,
    resume: bool,
    hooks: &mut dyn TrainHooks,
    progress: &dyn Progress,
) -> Result<TrainSummary, TrainError> {
    let init = origin.points();
    let frozen = origin.frozen();
    if let Start::Model { model, frozen, .. } = origin {
        if frozen > model.len() {
            return Err(TrainError::Config(format!(
                "{frozen} frozen Gaussians in a model of {}",
                model.len()
            )));
        }
        if model.capacity != config.colour_degrees {
            return Err(TrainError::Config(
                "the starting model's colour degrees differ from colour_degrees".into(),
            ));
        }
    }
    let mut guarded = frozen::KeepFrozen {
        inner: hooks,
        frozen,
    };
    let hooks: &mut dyn TrainHooks = &mut guarded;
    validate(config, dataset)?;
    // Resolved on the full-size images, so the colour does not depend on `resolution`.
    let background = config.background.resolve(dataset);
    let scaled;
    let dataset = if config.resolution < 1.0 {
        scaled = dataset.downscaled(config.resolution);
        &scaled
    } else {
        dataset
    };
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| TrainError::Io { path, source }
    };
    std::fs::create_dir_all(out_dir).map_err(io(out_dir))?;
    let ckpt_dir = out_dir.join("ckpt");
    let extent = dataset.scene_extent() as f32;
    let cameras = dataset.cameras();
    let mut pruned_unseen = 0;

    let fingerprint = checkpoint::fingerprint(dataset);
    let (resumed, skipped_checkpoints) = if resume {
        checkpoint::latest_good(&ckpt_dir, fingerprint)?
    } else {
        (None, Vec::new())
    };
    for s in &skipped_checkpoints {
        progress.message(&s.to_string());
    }
    let latest = resumed.as_ref().map(|c| c.iteration);
    let (mut model, mut adam, mut stats, start) = match resumed {
        Some(c) => {
            let it = c.iteration;
            if c.seed != config.seed {
                return Err(TrainError::Resume(format!(
                    "checkpoint {it} was made with seed {}, the config says {}; restore the seed or start afresh",
                    c.seed, config.seed
                )));
            }
            if c.model.capacity != config.colour_degrees {
                return Err(TrainError::Resume(
                    "the checkpoint's colour degrees differ from the config".into(),
                ));
            }
            if let Start::Model { model, frozen, .. } = origin
                && !frozen::has_prefix(&c.model, model, frozen)
            {
                return Err(TrainError::Resume(format!(
                    "checkpoint {it} was trained on other frozen Gaussians than this run starts with; start afresh"
                )));
            }
            hooks.load_state(&c.hook_state);
            let mut adam = c.adam;
            adam.frozen = frozen;
            (c.model, adam, c.stats, it)
        }
        None => {
            let model = match origin {
                Start::Model { model, .. } => model.clone(),
                Start::Points(init) => {
                    gaussians_from_points(init, dataset.time_mapping, &config.init_options())?
                }
            };
            let mut adam = Adam::new(&model);
            adam.frozen = frozen;
            let stats = DensifyStats::new(model.len());
            (model, adam, stats, 0)
        }
    };
    // The learned backdrop is fitted after the last step; its sphere is set up first, so a
    // capture it does not suit fails before training.
    let backdrop = match config.background {
        Background::Learned => Some(
            backdrop_fit::sphere(dataset, init, background, config.backdrop_size).ok_or_else(|| {
                TrainError::Config(
                    "background = \"learned\" needs cameras that look at a common point; use \"mean\""
                        .into(),
                )
            })?,
        ),
        _ => None,
    };
    let log_path = out_dir.join("log.csv");
    let mut log = TrainLog::open(&log_path, latest).map_err(io(&log_path))?;
    let mut last_checkpoint = latest.map(|it| checkpoint::paths(&ckpt_dir, it).0);

    progress.start(config.iterations, "it");
    progress.advance(start.min(config.iterations));
    let started = Instant::now();
    let d = &config.densify;
    let (mut final_loss, mut final_psnr) = (f64::NAN, f64::NAN);
    let save_ckpt = |it: u64,
                     model: &Gaussians<f32>,
                     adam: &Adam,
                     stats: &DensifyStats,
                     hooks: &dyn TrainHooks| {
        let c = Checkpoint {
            iteration: it,
            seed: config.seed,
            model: model.clone(),
            adam: adam.clone(),
            stats: stats.clone(),
            hook_state: hooks.save_state(),
        };
        let p = checkpoint::save(&ckpt_dir, &c, fingerprint)?;
        checkpoint::prune(&ckpt_dir, config.keep_checkpoints);
        Ok::<PathBuf, TrainError>(p)
    };

    let access = hooks.model_access();
    // The decay runs on the device when the kernels cover it (f_θ's shape).
    let decay_on_device = backend.as_gpu().is_some()
        && hooks
            .device_decay()
            .is_some_and(|d| GpuDecay::supports(d.config));
    let mut stepper: Box<dyn Stepper + '_> = match backend.as_gpu() {
        Some(gpu) if access != ModelAccess::OpacityFactor || decay_on_device => {
            Box::new(DeviceStep::new(
                gpu, config, background, dataset, &model, &adam, &stats, hooks,
            )?)
        }
        _ => Box::new(HostStep::new(backend, config, background, dataset, &model)),
    };
    // The cap and hooks that touch the model run on the host every step (a decay on the
    // device touches the device's model only).
    let hooks_touch_model = access != ModelAccess::None && !decay_on_device;
    let model_every_step = config.max_anisotropy > 0.0 || hooks_touch_model;
    progress.message(&format!(
        "training on {} (step on the {})",
        backend.describe(),
        stepper.placement()
    ));
    for it in start..config.iterations {
        // `it` iterations are done; this step is iteration `it + 1`.
        let mut rng = iteration_rng(config.seed, it);
        model.active = colour_degrees_at(it, config.degree_every, model.capacity);
        let batch = sample_batch(&mut rng, dataset.views.len(), config.batch_size);
        let rates = config.lr.at(it, config.iterations, extent as f64);
        let batch_loss =
            stepper.step(it, &batch, &rates, &mut model, &mut adam, &mut stats, hooks)?;
        let (loss_sum, l1_sum, ssim_sum, psnr_sum) = batch_loss.sums();
        let nb = batch.len() as f64;
        if model_every_step {
            stepper.model_to_host(&mut model)?;
        }
        regularise::cap_anisotropy(&mut model, config.max_anisotropy);
        hooks.after_step(it + 1, &mut model);
        if let Start::Model { model: first, .. } = origin
            && frozen > 0
            && model_every_step
        {
            frozen::restore_prefix(&mut model, first, frozen);
        }
        if model_every_step {
            stepper.model_from_host(&model)?;
        }
        let done = it + 1;
        let in_window = d.in_window(done);
        let densify_now = d.densifies_at(done, config.iterations);
        // A reset needs steps to recover: none in the last half period (a reset on the last
        // step would leave a transparent model).
        let reset_now = in_window
            && d.opacity_reset_every > 0
            && done % d.opacity_reset_every == 0
            && 2 * (config.iterations - done) >= d.opacity_reset_every;
        let checkpoint_now = (config.checkpoint_every > 0 && done % config.checkpoint_every == 0)
            || done == config.iterations;
        if densify_now || reset_now || checkpoint_now {
            stepper.state_to_host(&mut model, &mut adam, &mut stats, hooks)?;
        }
        // Between syncs the GPU path checks the loss only (a non-finite parameter shows
        // in the next loss, or at the next sync).
        let what = if !loss_sum.is_finite() {
            Some("the loss")
        } else if stepper.host_model_current() && !all_finite(&model) {
            Some("a model parameter")
        } else {
            None
        };
        if let Some(what) = what {
            log.flush().map_err(io(&log_path))?;
            progress.finish();
            return Err(TrainError::NonFinite {
                iteration: done,
                what,
                last_checkpoint,
            });
        }

        // Density control.
        if densify_now {
            let prune_large = d.opacity_reset_every > 0 && done > d.opacity_reset_every;
            let scene = densify::Scene {
                extent,
                cameras: &cameras,
            };
            let report = densify_and_prune(
                &mut model,
                &mut adam,
                &mut stats,
                d,
                scene,
                prune_large,
                &mut rng,
            );
            pruned_unseen += report.unseen;
            if model.is_empty() {
                log.flush().map_err(io(&log_path))?;
                progress.finish();
                return Err(TrainError::EmptyModel { iteration: done });
            }
        }
        if reset_now {
            reset_opacity(&mut model, &mut adam, 0.01);
        }
        if densify_now || reset_now {
            stepper.state_from_host(&model, &adam, &stats)?;
        }

        final_loss = loss_sum / nb;
        final_psnr = psnr_sum / nb;
        let row = LogRow {
            iteration: done,
            loss: final_loss,
            l1: l1_sum / nb,
            ssim: ssim_sum / nb,
            psnr: final_psnr,
            gaussians: model.len(),
            elapsed_s: started.elapsed().as_secs_f64(),
        };
        log.write(&row).map_err(io(&log_path))?;
        progress.advance(1);
        if config.report_every > 0 && (done % config.report_every == 0 || done == config.iterations)
        {
            log.flush().map_err(io(&log_path))?;
            let rate = (done - start) as f64 / started.elapsed().as_secs_f64().max(1e-9);
            let eta = (config.iterations - done) as f64 / rate.max(1e-9);
            progress.message(&format!(
                "loss {:.4} psnr {:.2} dB {} gaussians {:.2} it/s eta {:.0}s",
                final_loss,
                final_psnr,
                model.len(),
                rate,
                eta
            ));
        }
        if checkpoint_now {
            log.flush().map_err(io(&log_path))?;
            last_checkpoint = Some(save_ckpt(done, &model, &adam, &stats, &*hooks)?);
        }
        if done < config.iterations && hooks.stop_requested(done) {
            log.flush().map_err(io(&log_path))?;
            let checkpoint = match &last_checkpoint {
                Some(p) if p.ends_with(format!("{done:06}.bin")) => p.clone(),
                _ => {
                    stepper.state_to_host(&mut model, &mut adam, &mut stats, hooks)?;
                    save_ckpt(done, &model, &adam, &stats, &*hooks)?
                }
            };
            progress.finish();
            return Err(TrainError::Interrupted {
                iteration: done,
                checkpoint,
            });
        }
    }
    log.flush().map_err(io(&log_path))?;
    let backdrop_path = match backdrop {
        Some(backdrop) => {
            let settings = backdrop_fit::FitSettings {
                lambda_ssim: config.lambda_ssim,
                seed: config.seed,
                iterations: config.iterations as usize,
            };
            let backdrop = backdrop_fit::learn_backdrop(
                backdrop, backend, &model, dataset, background, &settings, progress,
            )
            .map_err(|(index, source)| TrainError::Render { index, source })?;
            let path = out_dir.join(BACKDROP_FILE);
            save_backdrop(&backdrop, &path)?;
            Some(path)
        }
        None => None,
    };
    let model_path = out_dir.join(MODEL_FILE);
    save_model(&model, &model_path).map_err(CheckpointError::from)?;
    progress.finish();
    Ok(TrainSummary {
        iterations: config.iterations,
        started_at: start,
        final_loss,
        final_psnr,
        gaussians: model.len(),
        seconds: started.elapsed().as_secs_f64(),
        model_path,
        placement: stepper.placement(),
        background,
        backdrop: backdrop_path,
        pruned_unseen,
        skipped_checkpoints,
    })
}

/// The learned backdrop's file beside `model.bin` (`[train] background = "learned"`).
pub const BACKDROP_FILE: &str = "backdrop.bin";

/// The trained model's file in the output folder.
pub const MODEL_FILE: &str = "model.bin";

/// PSNR (dB) of `model` rendered at every view of `dataset` against its image.
pub fn evaluate_psnr(
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    dataset: &Dataset,
    background: [f32; 3],
) -> Result<Vec<f64>, TrainError> {
    let mut target = Vec::new();
    dataset
        .views
        .iter()
        .enumerate()
        .map(|(index, v)| {
            let options = RenderOptions {
                background,
                ..Default::default()
            };
            let r = backend
                .render(model, &v.camera, v.time, &options)
                .map_err(|source| TrainError::Render { index, source })?;
            v.image.to_f32_into(&mut target);
            Ok(psnr_from_mse(mse(&r.rgb, &target)))
        })
        .collect()
}
