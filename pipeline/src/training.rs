//! The `train` stage: training views from the frames and poses stages (undistorted once,
//! here, to the pinhole cameras the engine renders), the initial points, and the trainer.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use calib::undistort::{Fit, UndistortMap};
use rayon::prelude::*;
use rig::frames::FramesIndex;
use shared_types::{Camera, CameraSet, Progress};
use splat4d::train::{Dataset, ImageU8, PointCloud, TrainError, TrainHooks, View};
use splat4d::{Gaussians, TimeMapping};

use crate::stage::StageContext;

/// Set by the Ctrl-C handler while a stage that can stop cleanly (training) runs.
static STOP: AtomicBool = AtomicBool::new(false);
/// Whether a stage that can stop cleanly is running now.
static GRACEFUL: AtomicBool = AtomicBool::new(false);

/// What the Ctrl-C handler of `pipeline run` does: during training, ask the trainer to
/// stop at the end of the iteration (it writes a checkpoint; the next run resumes); at any
/// other time, or on a second Ctrl-C, exit at once (the runner notices the interrupted
/// stage on its next start).
pub fn on_interrupt() {
    if GRACEFUL.load(Ordering::SeqCst) && !STOP.swap(true, Ordering::SeqCst) {
        eprintln!(
            "\nstopping after this iteration (a checkpoint is written); press Ctrl-C again to quit now"
        );
        return;
    }
    std::process::exit(130);
}

/// Ask the running (or the next) training to stop cleanly after its current iteration,
/// as a first Ctrl-C does.
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// Marks a clean-stop section for [`on_interrupt`]; clears the request when dropped.
struct Graceful;

impl Graceful {
    fn enter() -> Self {
        GRACEFUL.store(true, Ordering::SeqCst);
        Graceful
    }
}

impl Drop for Graceful {
    fn drop(&mut self) {
        GRACEFUL.store(false, Ordering::SeqCst);
        STOP.store(false, Ordering::SeqCst);
    }
}

/// The stage's hooks: the method's hooks (4C4D decay, or none) plus the Ctrl-C stop.
struct StageHooks<'a> {
    inner: &'a mut dyn TrainHooks,
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
        STOP.load(Ordering::SeqCst) || self.inner.stop_requested(iteration)
    }
}

/// The time mapping of a frames index: model time 0 at the first output frame, one model
/// unit per 30 frames (the 4DGS convention), the sequence as long as its frames.
pub fn time_mapping(index: &FramesIndex) -> TimeMapping {
    let duration = index.frames.len() as f64 / index.fps;
    TimeMapping::frames_over_30(index.start_s, index.fps, duration)
}

/// The pinhole camera of each frames camera and, for a camera with a lens, the map that
/// undistorts its images. Cameras are rescaled to the frames' size.
pub fn pinhole_cameras(
    index: &FramesIndex,
    cameras: &CameraSet,
    cameras_file: &Path,
) -> anyhow::Result<Vec<(Camera, Option<UndistortMap>)>> {
    index
        .cameras
        .iter()
        .map(|images| {
            let Some(camera) = cameras.get(&images.name) else {
                bail!(
                    "{} has no camera '{}' (the frames stage wrote images for it); rerun the poses stage: `pipeline run CAPTURE --from poses --force`",
                    cameras_file.display(),
                    images.name
                );
            };
            let mut camera = camera.clone();
            camera.intrinsics = camera.intrinsics.scaled_to(images.width, images.height);
            if camera.distortion.is_none() {
                Ok((camera, None))
            } else {
                let map = UndistortMap::new(&camera, Fit::ValidPixels);
                Ok((map.pinhole().clone(), Some(map)))
            }
        })
        .collect()
}

/// Load an aligned frame image, undistorted when `map` is given.
pub fn load_frame(path: &Path, map: Option<&UndistortMap>) -> anyhow::Result<ImageU8> {
    let image = image::open(path)
        .with_context(|| {
            format!(
                "cannot read the frame {}; rerun the frames stage (`pipeline run CAPTURE --from frames --force`)",
                path.display()
            )
        })?
        .to_rgb8();
    let image = match map {
        Some(map) => map
            .apply(&image)
            .with_context(|| format!("cannot undistort {}", path.display()))?,
        None => image,
    };
    let (width, height) = image.dimensions();
    Ok(ImageU8 {
        width,
        height,
        data: image.into_raw(),
    })
}

/// Every (camera, frame) of the frames stage as a training view at its own exact
/// timestamp, undistorted to the pinhole cameras.
pub fn load_dataset(
    frames_dir: &Path,
    cameras_file: &Path,
    progress: &dyn Progress,
) -> anyhow::Result<Dataset> {
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let poses = PosesFile::read(cameras_file)?;
    let cameras = pinhole_cameras(&index, &poses.set, cameras_file)?;
    let mapping = time_mapping(&index);
    let jobs: Vec<(usize, PathBuf, f64)> = index
        .frames
        .iter()
        .flat_map(|frame| {
            frame
                .views
                .iter()
                .enumerate()
                .map(|(c, v)| (c, frames_dir.join(&v.file), v.timestamp_s))
        })
        .collect();
    if jobs.is_empty() {
        bail!(
            "{} lists no frames; rerun the frames stage",
            frames_dir.join("frames.json").display()
        );
    }
    progress.start(jobs.len() as u64, "images");
    let views = jobs
        .par_iter()
        .map(|(c, path, timestamp)| {
            let (camera, map) = &cameras[*c];
            let image = load_frame(path, map.as_ref())?;
            progress.advance(1);
            let time = mapping.model_time(*timestamp) as f32;
            Ok(View::at_image_size(camera.clone(), time, image))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(Dataset {
        views,
        time_mapping: mapping,
    })
}

/// The trained model of a capture (`work/train/model.bin`).
pub fn load_trained_model(work_dir: &Path) -> anyhow::Result<Gaussians<f32>> {
    let path = work_dir.join("train/model.bin");
    splat4d::load_model(&path).with_context(|| {
        format!(
            "cannot load the trained model {}; run the train stage first",
            path.display()
        )
    })
}

/// The initial points: `work/init/points.ply`, else the poses stage's sparse points.
fn initial_points(ctx: &StageContext) -> anyhow::Result<PointCloud> {
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

/// The `train` stage.
pub fn run(ctx: &StageContext) -> anyhow::Result<()> {
    let cameras_file = ctx.stage_dir("poses").join("cameras.json");
    ctx.progress.message("loading frames");
    let dataset = load_dataset(&ctx.stage_dir("frames"), &cameras_file, ctx.progress)?;
    let points = initial_points(ctx)?;
    tracing::info!(
        "training on {} views from {} points{}",
        dataset.views.len(),
        points.xyz.len(),
        if ctx.resume { " (resuming)" } else { "" }
    );
    let decay = &ctx.config.decay;
    let mut method = splat4d::decay::DecayHooks::new(decay)
        .map_err(|e| anyhow::anyhow!("capture.toml [decay]: {e}"))?;
    tracing::info!("opacity decay: {:?}", decay.variant);
    let mut hooks = StageHooks { inner: &mut method };
    let _graceful = Graceful::enter();
    let summary = match splat4d::train::train(
        &ctx.config.train,
        &dataset,
        &points,
        &ctx.out_dir,
        ctx.resume,
        &mut hooks,
        ctx.progress,
    ) {
        Ok(summary) => summary,
        Err(TrainError::Interrupted { iteration, .. }) => bail!(
            "training stopped after iteration {iteration} (a checkpoint was kept); run the same `pipeline run` again to continue from it, or add --force to start over"
        ),
        Err(e) => return Err(e.into()),
    };
    tracing::info!(
        "trained {} iterations ({} this run) in {:.0} s: {} Gaussians, last batch PSNR {:.2} dB",
        summary.iterations,
        summary.iterations - summary.started_at,
        summary.seconds,
        summary.gaussians,
        summary.final_psnr
    );
    Ok(())
}
