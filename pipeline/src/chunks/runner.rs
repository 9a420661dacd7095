//! Trains the chunks of a plan, each from its own frames and the init's points of its own
//! moments, into `work/train/chunks/NNN/` (its checkpoints, model and log: a chunk resumes
//! on its own, and a finished chunk, marked by its `chunk.json`, is not trained again),
//! then merges them into the stage's `model.bin`:
//!
//! 1. The first chunk trains like a whole clip (the static points and its moving ones).
//!    Its Gaussians that stand still over its frames become the static scene
//!    (`chunks/static.bin`, `static_scene::freeze`), refined on every camera's static
//!    plate of the whole clip (`plates`); its learned backdrop, background
//!    colour and exposure gains are the clip's (`chunks/shared.json`).
//! 2. Every later chunk trains its moving points on top of the static scene, frozen.
//! 3. `model.bin` = the static scene, then each chunk's moving Gaussians whose time centre
//!    lies in the part of the clip it owns (`Chunk::owns_time`).
//!
//! A run trains every chunk in order and merges; a run given one chunk
//! (`StageContext::chunk`: `pipeline run --only train --chunk K`, one Slurm job per chunk)
//! trains just that one and leaves the stage unfinished for the run that merges.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::Context;
use serde::{Deserialize, Serialize};
use shared_types::atomic::write_json;
use shared_types::{NoProgress, Progress};
use splat4d::Gaussians;
use splat4d::model::init::gaussians_from_points;
use splat4d::train::densify::gather_gaussians;
use splat4d::train::exposure::CameraGain;
use splat4d::train::{Background, PointCloud, Start, train_from};

use super::plan::{Chunk, ChunkPlan};
use super::{ChunkSettings, plates, static_scene};
use crate::engine_inputs::{EngineSettings, TrainRecord, load_dataset_window};
use crate::interrupt::Graceful;
use crate::stage_context::StageContext;
use crate::stages::train::{
    DecaySettings, StageHooks, TrainSettings, finished, initial_points, match_exposure,
};

/// The static scene's file under `work/train/`.
pub const STATIC_FILE: &str = "chunks/static.bin";
/// Where the static scene is refined on the plates, under `work/train/`.
const STATIC_DIR: &str = "chunks/static";
/// What the first chunk settles for the clip, under `work/train/`.
const SHARED_FILE: &str = "chunks/shared.json";
/// What the stage records of the chunks under `work/train/`.
pub const CHUNKS_RECORD: &str = "chunks.json";
/// What a finished chunk records in its folder (written last: its presence means done).
const CHUNK_DONE: &str = "chunk.json";
/// The first chunk's record, under `work/train/`.
const FIRST_DONE: &str = "chunks/000/chunk.json";

/// A finished chunk.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChunkRecord {
    pub index: usize,
    /// Aligned frames it trained on, `[first, end)`.
    pub window: (usize, usize),
    /// Model times of its first and last view.
    pub times: (f64, f64),
    pub iterations: u64,
    /// Gaussians it trained (beside the frozen static scene) at the end of training, and
    /// how many of them the merged model keeps as its own.
    pub gaussians: usize,
    pub kept: usize,
    pub seconds: f64,
    /// PSNR of its last batch, dB (`null` for a chunk with nothing to train).
    pub final_psnr: Option<f64>,
}

/// `work/train/chunks.json`: the plan, the static scene's size, and every chunk.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChunksRecord {
    pub plan: ChunkPlan,
    pub static_gaussians: usize,
    pub chunks: Vec<ChunkRecord>,
}

/// What the first chunk settles for the whole clip (`chunks/shared.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Shared {
    /// The colour every chunk trains on.
    background: [f32; 3],
    exposure: Vec<CameraGain>,
    /// A backdrop was fitted behind the first chunk (`work/train/backdrop.bin`).
    backdrop: bool,
    /// How far a Gaussian of the first chunk that stands still may drift
    /// (`static_scene::max_drift`).
    max_drift: f64,
}

/// One stage run's chunk training: the inputs every chunk shares.
struct Trainer<'a> {
    ctx: &'a StageContext<'a>,
    settings: &'a TrainSettings,
    chunks: &'a ChunkSettings,
    decay: &'a DecaySettings,
    frames_dir: PathBuf,
    cameras_file: PathBuf,
    points: PointCloud,
    /// One backend a lane of chunks trained side by side (`[engine] chunks_at_once`).
    backends: Vec<Box<dyn splat4d::RenderBackend>>,
    count: usize,
}

/// Train the chunks of `plan` (all, or the one `ctx.chunk` names) and, when all were
/// asked for, merge them into `model.bin`.
pub fn run(
    ctx: &StageContext,
    settings: &TrainSettings,
    chunks: &ChunkSettings,
    decay: &DecaySettings,
    engine: &EngineSettings,
    plan: &ChunkPlan,
) -> anyhow::Result<()> {
    // One lane for a single chunk (a cluster job); at most one a chunk after the first.
    let most = match ctx.chunk {
        Some(_) => 1,
        None => plan.chunks.len().saturating_sub(1),
    };
    let backends = crate::engine_inputs::training_lanes(engine, most)?;
    ctx.record_tool("training backend", &backends[0].describe());
    let trainer = Trainer {
        ctx,
        settings,
        chunks,
        decay,
        frames_dir: ctx.stage_dir("frames"),
        cameras_file: ctx.stage_dir("poses").join("cameras.json"),
        points: initial_points(ctx)?,
        backends,
        count: plan.chunks.len(),
    };
    let _graceful = Graceful::enter();
    match ctx.chunk {
        Some(k) => {
            let chunk = plan.chunks.get(k).with_context(|| {
                format!(
                    "there is no chunk {k}: the clip is cut into {} chunks (0..{}) by [chunks]",
                    plan.chunks.len(),
                    plan.chunks.len() - 1
                )
            })?;
            trainer.train(chunk, &trainer.stage_lane())
        }
        None => {
            let (first, rest) = plan
                .chunks
                .split_first()
                .context("a chunked clip has no chunks")?;
            let lanes = trainer.backends.len();
            tracing::info!(
                "training {} time chunks ([chunks]), {} iterations each: the first, then {}",
                plan.chunks.len(),
                settings.iterations,
                if lanes == 1 {
                    "the others one after another".to_string()
                } else {
                    format!("{lanes} at once ([engine] chunks_at_once)")
                }
            );
            trainer.train(first, &trainer.stage_lane())?;
            if lanes == 1 {
                for chunk in rest {
                    trainer.train(chunk, &trainer.stage_lane())?;
                }
            } else {
                trainer.train_side_by_side(rest)?;
            }
            merge(ctx, plan, settings.iterations)
        }
    }
}

/// What one chunk trains with: a backend, and where its progress goes.
struct Lane<'a> {
    backend: &'a dyn splat4d::RenderBackend,
    progress: &'a dyn Progress,
}

impl Trainer<'_> {
    /// The first backend, reporting to the stage's progress: the lane of the first chunk
    /// and of chunks trained one at a time.
    fn stage_lane(&self) -> Lane<'_> {
        Lane {
            backend: self.backends[0].as_ref(),
            progress: self.ctx.progress,
        }
    }

    /// Train `chunks` (none of them the first) on every backend at once, each lane
    /// taking the next chunk when it is done with one; the stage's progress counts
    /// chunks. After a failure no lane starts another chunk (those running finish or
    /// stop at their checkpoints), and the first error is returned.
    fn train_side_by_side(&self, chunks: &[Chunk]) -> anyhow::Result<()> {
        let progress = self.ctx.progress;
        progress.start(chunks.len() as u64, "chunks");
        progress.message(&format!("{} chunks at once", self.backends.len()));
        let next = AtomicUsize::new(0);
        let failed = AtomicBool::new(false);
        let results: Vec<anyhow::Result<()>> = std::thread::scope(|scope| {
            let handles: Vec<_> = self
                .backends
                .iter()
                .map(|backend| {
                    let (next, failed) = (&next, &failed);
                    scope.spawn(move || {
                        let lane = Lane {
                            backend: backend.as_ref(),
                            progress: &NoProgress,
                        };
                        while !failed.load(Ordering::SeqCst) {
                            let Some(chunk) = chunks.get(next.fetch_add(1, Ordering::SeqCst))
                            else {
                                break;
                            };
                            if let Err(e) = self.train(chunk, &lane) {
                                failed.store(true, Ordering::SeqCst);
                                return Err(e);
                            }
                            tracing::info!("chunk {}/{}: done", chunk.index + 1, self.count);
                            progress.advance(1);
                        }
                        Ok(())
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("a chunk's training panicked")))
                })
                .collect()
        });
        progress.finish();
        results.into_iter().collect()
    }

    /// Train `chunk` into its folder on `lane`, unless it is done already.
    fn train(&self, chunk: &Chunk, lane: &Lane) -> anyhow::Result<()> {
        let ctx = self.ctx;
        let dir = ctx.output(chunk.dir_name());
        if dir.join(CHUNK_DONE).exists() {
            tracing::info!("chunk {}: finished earlier, kept", chunk.index + 1);
            return Ok(());
        }
        let label = format!(
            "chunk {}/{} (frames {}..{})",
            chunk.index + 1,
            self.count,
            chunk.window.start,
            chunk.window.end
        );
        self.train_in(chunk, &dir, &label, lane)
            .with_context(|| label.clone())
    }

    fn train_in(&self, chunk: &Chunk, dir: &Path, label: &str, lane: &Lane) -> anyhow::Result<()> {
        let ctx = self.ctx;
        let first_chunk = chunk.index == 0;
        // A later chunk trains on what the first one settled.
        let shared = if first_chunk {
            None
        } else {
            Some(load_shared(ctx)?)
        };
        lane.progress.message(&format!("{label}: loading frames"));
        let mut dataset = load_dataset_window(
            &self.frames_dir,
            &self.cameras_file,
            Some(chunk.window.clone()),
            lane.progress,
        )?;
        let mapping = dataset.time_mapping;
        let times = window_times(&dataset);
        let exposure = match &shared {
            Some((s, _)) => {
                splat4d::train::exposure::equalise(&mut dataset, &s.exposure);
                s.exposure.clone()
            }
            None if self.settings.match_exposure => {
                match_exposure(&mut dataset, &self.points, ctx.progress)
            }
            None => Vec::new(),
        };
        let frozen = shared.as_ref().map(|(_, scene)| scene);
        let first_times = if first_chunk {
            times
        } else {
            read_json::<ChunkRecord>(&ctx.output(FIRST_DONE))?.times
        };
        let points = points_of(&self.points, chunk, times, first_times);
        let mut record = ChunkRecord {
            index: chunk.index,
            window: (chunk.window.start, chunk.window.end),
            times,
            iterations: 0,
            gaussians: 0,
            kept: 0,
            seconds: 0.0,
            final_psnr: None,
        };
        if points.xyz.is_empty() {
            if first_chunk {
                anyhow::bail!(
                    "the init gave it no points; rerun the init stage (`pipeline run CAPTURE --from init --force`)"
                );
            }
            tracing::warn!(
                "{label}: the init placed no moving points in it; it adds nothing to the static scene"
            );
            std::fs::create_dir_all(dir)?;
            return write_json(&dir.join(CHUNK_DONE), &record).context("cannot write chunk.json");
        }
        tracing::info!("{label}: training from {} points", points.xyz.len());
        lane.progress.message(&format!("{label}: training"));
        let mut config = self.settings.clone();
        if let Some((s, _)) = &shared {
            config.background = Background::Colour(s.background);
        }
        let mut first = match frozen {
            Some(scene) => scene.clone(),
            None => Gaussians::new(config.colour_degrees, mapping),
        };
        // The init's heuristics (temporal σ, which moments are one) see the chunk's span;
        // the model keeps the clip's time.
        let mut window_mapping = mapping;
        window_mapping.duration = (times.1 - times.0).max(1e-6);
        first.append(&gaussians_from_points(
            &points,
            window_mapping,
            &config.init_options(),
        )?);
        first.time = mapping;
        let frozen_count = frozen.map_or(0, |s| s.len());
        let start = Start::Model {
            model: &first,
            frozen: frozen_count,
            points: &points,
        };
        let summary = self.train_model(&config, &dataset, start, dir, lane)?;
        record.iterations = summary.iterations;
        record.gaussians = summary.gaussians - frozen_count;
        record.seconds = summary.seconds;
        record.final_psnr = Some(summary.final_psnr);
        if first_chunk {
            // The first chunk settles the clip's backdrop, colour, exposure and static scene.
            if let Some(path) = &summary.backdrop {
                copy(path, &ctx.output(splat4d::train::BACKDROP_FILE))?;
            }
            let model = splat4d::load_model(&summary.model_path)?;
            let seconds = (times.1 - times.0) / mapping.units_per_second;
            let drift = static_scene::max_drift(dataset.scene_extent(), seconds);
            let (still, _) = static_scene::split(&model, times, drift);
            let middle = 0.5 * (times.0 + times.1);
            let scene = static_scene::freeze(&model, &still, middle);
            tracing::info!(
                "static scene: {} of the first chunk's {} Gaussians stand still",
                scene.len(),
                model.len()
            );
            drop(dataset);
            let scene =
                self.refine_static(scene, middle, summary.background, &exposure, &points, lane)?;
            splat4d::save_model(&scene, &ctx.output(STATIC_FILE))?;
            let shared = Shared {
                background: summary.background,
                exposure,
                backdrop: summary.backdrop.is_some(),
                max_drift: drift,
            };
            write_json(&ctx.output(SHARED_FILE), &shared)
                .context("cannot write chunks/shared.json")?;
        }
        write_json(&dir.join(CHUNK_DONE), &record).context("cannot write chunk.json")
    }

    /// The first chunk's frozen static `scene` (at model time `time`) refined for
    /// `[chunks] static_steps` on every camera's static plate of the whole clip
    /// (`plates`), in `work/train/chunks/static/` (resumable like a chunk).
    fn refine_static(
        &self,
        scene: Gaussians<f32>,
        time: f64,
        background: [f32; 3],
        exposure: &[CameraGain],
        points: &PointCloud,
        lane: &Lane,
    ) -> anyhow::Result<Gaussians<f32>> {
        let steps = self.chunks.static_steps;
        if steps == 0 || scene.is_empty() {
            return Ok(scene);
        }
        let ctx = self.ctx;
        let label = "static scene";
        lane.progress.message(&format!(
            "{label}: the cameras' static plates of the whole clip ({} frames each)",
            plates::PLATE_FRAMES
        ));
        let mut plates = plates::plate_views(
            &self.frames_dir,
            &self.cameras_file,
            time as f32,
            lane.progress,
        )?;
        splat4d::train::exposure::equalise(&mut plates, exposure);
        lane.progress
            .message(&format!("{label}: refining on the plates, {steps} steps"));
        let config = plates::refine_config(self.settings, steps, background);
        let start = Start::Model {
            model: &scene,
            frozen: 0,
            points,
        };
        let summary = finished(train_from(
            lane.backend,
            &config,
            &plates,
            start,
            &ctx.output(STATIC_DIR),
            ctx.resume,
            &mut splat4d::train::NoHooks,
            lane.progress,
        ))
        .context("refining the static scene on the cameras' static plates")?;
        tracing::info!(
            "static scene refined on the plates: {:.2} dB on its last batch",
            summary.final_psnr
        );
        Ok(splat4d::load_model(&summary.model_path)?)
    }

    /// Train one chunk's model into `dir`, resuming from its checkpoints when there are.
    fn train_model(
        &self,
        config: &TrainSettings,
        dataset: &splat4d::train::Dataset,
        start: Start<'_>,
        dir: &Path,
        lane: &Lane,
    ) -> anyhow::Result<splat4d::train::TrainSummary> {
        let mut method = splat4d::decay::DecayHooks::new(self.decay)
            .map_err(|e| anyhow::anyhow!("capture.toml [decay]: {e}"))?;
        let mut hooks = StageHooks { inner: &mut method };
        let summary = finished(train_from(
            lane.backend,
            config,
            dataset,
            start,
            dir,
            self.ctx.resume,
            &mut hooks,
            lane.progress,
        ))?;
        let model = splat4d::load_model(&summary.model_path)?;
        let report = splat4d::decay::report::report(&method, &model);
        write_json(&dir.join("decay.json"), &report).context("cannot write decay.json")?;
        Ok(summary)
    }
}

/// What the first chunk settled, and the static scene; an error naming what is missing
/// when the first chunk has not finished.
fn load_shared(ctx: &StageContext) -> anyhow::Result<(Shared, Gaussians<f32>)> {
    let path = ctx.output(SHARED_FILE);
    if !path.exists() {
        anyhow::bail!(
            "it trains on the first chunk's static scene, and the first chunk has not finished ({} is missing); train chunk 0 first (`pipeline run CAPTURE --only train --chunk 0`, or the whole stage)",
            path.display()
        );
    }
    let shared: Shared = read_json(&path)?;
    let scene = splat4d::load_model(&ctx.output(STATIC_FILE))?;
    Ok((shared, scene))
}

/// The first and last model time of a chunk's views.
fn window_times(dataset: &splat4d::train::Dataset) -> (f64, f64) {
    dataset
        .views
        .iter()
        .map(|v| v.time as f64)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
            (lo.min(t), hi.max(t))
        })
}

/// The init's points `chunk` trains from: the moving points (seen at one moment) of the
/// moments within its window's model times `times`, and the static points it is the first
/// to see. A static point seen over a span of the clip that reaches the first chunk's
/// window (`first`) belongs to the first chunk (which makes the shared static scene);
/// one seen only later, to the chunk that owns the middle of its span; a static point
/// without times, to the first chunk. The first chunk's static points have their time
/// clamped into its window `times` (their span kept): a wall seen over a minute would
/// otherwise be centred half a minute away and fade across the window it trains on, and
/// it becomes part of the static scene only if it holds over the whole window.
pub fn points_of(
    points: &PointCloud,
    chunk: &Chunk,
    times: (f64, f64),
    first: (f64, f64),
) -> PointCloud {
    let within = |t: f64, (a, b): (f64, f64)| t >= a - 1e-6 && t <= b + 1e-6;
    let keep: Vec<usize> = (0..points.xyz.len())
        .filter(|&i| {
            let t = points.time.as_ref().map(|t| t[i] as f64);
            let span = points.time_span.as_ref().map(|s| s[i] as f64);
            match (t, span) {
                (Some(t), Some(0.0)) => within(t, times),
                (Some(t), Some(span)) => {
                    let seen_first =
                        t - 0.5 * span <= first.1 + 1e-6 && t + 0.5 * span >= first.0 - 1e-6;
                    match chunk.index {
                        0 => seen_first || chunk.owns_time(t),
                        _ => !seen_first && chunk.owns_time(t),
                    }
                }
                _ => chunk.index == 0,
            }
        })
        .collect();
    let pick = |v: &Option<Vec<f32>>| v.as_ref().map(|v| keep.iter().map(|&i| v[i]).collect());
    let mut cloud = PointCloud {
        xyz: keep.iter().map(|&i| points.xyz[i]).collect(),
        rgb: keep.iter().map(|&i| points.rgb[i]).collect(),
        time: pick(&points.time),
        time_span: pick(&points.time_span),
    };
    if let (0, Some(t), Some(span)) = (chunk.index, &mut cloud.time, &cloud.time_span) {
        for (t, _) in t.iter_mut().zip(span).filter(|(_, s)| **s > 0.0) {
            *t = t.clamp(times.0 as f32, times.1 as f32);
        }
    }
    cloud
}

/// The merged model, its record and log: the static scene, then each chunk's moving
/// Gaussians of the time it owns.
fn merge(ctx: &StageContext, plan: &ChunkPlan, iterations: u64) -> anyhow::Result<()> {
    ctx.progress.message("merging the chunks");
    let (shared, scene) = load_shared(ctx)?;
    let mut model = scene.clone();
    let mut records = Vec::with_capacity(plan.chunks.len());
    for chunk in &plan.chunks {
        let dir = ctx.output(chunk.dir_name());
        let mut record: ChunkRecord = read_json(&dir.join(CHUNK_DONE))?;
        if record.gaussians > 0 {
            let trained = splat4d::load_model(&dir.join("model.bin"))?;
            // The chunk's own Gaussians: the first chunk's that move, a later chunk's
            // after the frozen static scene.
            let own: Vec<usize> = if chunk.index == 0 {
                static_scene::split(&trained, record.times, shared.max_drift).1
            } else {
                (scene.len()..trained.len()).collect()
            };
            let kept: Vec<usize> = own
                .into_iter()
                .filter(|&i| chunk.owns_time(trained.means[i][3] as f64))
                .collect();
            record.kept = kept.len();
            model.active = trained.active;
            model.append(&gather_gaussians(&trained, &kept));
        }
        records.push(record);
    }
    tracing::info!(
        "merged {} chunks: {} static and {} moving Gaussians",
        records.len(),
        scene.len(),
        model.len() - scene.len()
    );
    splat4d::save_model(&model, &ctx.output("model.bin"))?;
    let record = TrainRecord {
        background: shared.background,
        exposure: shared.exposure,
        backdrop: shared.backdrop,
    };
    write_json(&ctx.output(crate::engine_inputs::TRAIN_RECORD), &record)
        .context("cannot write train.json")?;
    write_json(
        &ctx.output(CHUNKS_RECORD),
        &ChunksRecord {
            plan: plan.clone(),
            static_gaussians: scene.len(),
            chunks: records,
        },
    )
    .context("cannot write chunks.json")?;
    join_logs(ctx, plan, iterations)
}

/// `log.csv`: the chunks' logs one after another, iterations counted on across chunks.
fn join_logs(ctx: &StageContext, plan: &ChunkPlan, iterations: u64) -> anyhow::Result<()> {
    let mut text = format!("{}\n", splat4d::train::log::HEADER);
    for chunk in &plan.chunks {
        let path = ctx.output(chunk.dir_name()).join("log.csv");
        let Ok(log) = std::fs::read_to_string(&path) else {
            continue; // a chunk with nothing to train has no log
        };
        let offset = chunk.index as u64 * iterations;
        for line in log.lines().skip(1) {
            if let Some((it, rest)) = line.split_once(',')
                && let Ok(it) = it.parse::<u64>()
            {
                text.push_str(&format!("{},{rest}\n", it + offset));
            }
        }
    }
    shared_types::atomic::write_atomic(&ctx.output("log.csv"), text.as_bytes())
        .context("cannot write log.csv")
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> anyhow::Result<T> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_slice(&bytes).with_context(|| {
        format!(
            "{} is corrupt; rerun the train stage with --force",
            path.display()
        )
    })
}

fn copy(from: &Path, to: &Path) -> anyhow::Result<()> {
    let bytes = std::fs::read(from).with_context(|| format!("cannot read {}", from.display()))?;
    shared_types::atomic::write_atomic(to, &bytes)
        .with_context(|| format!("cannot write {}", to.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_chunk_takes_its_moments_and_the_static_points_it_sees_first() {
        // Three chunks of 1 s (model time = seconds here), no overlap.
        let times: Vec<f64> = (0..30).map(|f| f as f64 / 10.0).collect();
        let settings = ChunkSettings {
            seconds: 1.0,
            overlap_seconds: 0.0,
            ..ChunkSettings::default()
        };
        let plan = ChunkPlan::new(&times, 10.0, &settings);
        let windows = [(0.0, 0.9), (1.0, 1.9), (2.0, 2.9)];
        // (time, span): moving at 0.5, 1.5, 2.5; a wall seen all along; a wall seen from
        // 0.6 to 2.0; one seen only from 1.2 to 2.8 (centre 2.0); a point without times.
        let spans = [
            (0.5, 0.0),
            (1.5, 0.0),
            (2.5, 0.0),
            (1.5, 3.0),
            (1.3, 1.4),
            (2.0, 1.6),
        ];
        let cloud = PointCloud {
            xyz: (0..6).map(|i| [i as f32, 0.0, 0.0]).collect(),
            rgb: vec![[0; 3]; 6],
            time: Some(spans.iter().map(|s| s.0 as f32).collect()),
            time_span: Some(spans.iter().map(|s| s.1 as f32).collect()),
        };
        let xs = |k: usize| -> Vec<f32> {
            points_of(&cloud, &plan.chunks[k], windows[k], windows[0])
                .xyz
                .iter()
                .map(|p| p[0])
                .collect()
        };
        assert_eq!(xs(0), [0.0, 3.0, 4.0]);
        // The first chunk's walls move into its window; its moving point keeps its time.
        let first = points_of(&cloud, &plan.chunks[0], windows[0], windows[0]);
        assert_eq!(first.time.unwrap(), [0.5, 0.9, 0.9]);
        assert_eq!(first.time_span.unwrap(), [0.0, 3.0, 1.4]);
        let later = points_of(&cloud, &plan.chunks[2], windows[2], windows[0]);
        assert_eq!(later.time.unwrap(), [2.5, 2.0]);
        assert_eq!(xs(1), [1.0]);
        assert_eq!(xs(2), [2.0, 5.0]);
        let untimed = PointCloud {
            time: None,
            time_span: None,
            ..cloud.clone()
        };
        assert_eq!(
            points_of(&untimed, &plan.chunks[0], windows[0], windows[0])
                .xyz
                .len(),
            6
        );
        assert!(
            points_of(&untimed, &plan.chunks[1], windows[1], windows[0])
                .xyz
                .is_empty()
        );
    }
}
