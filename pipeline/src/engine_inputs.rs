//! The outputs of the frames, poses and train stages as the engine takes them, for every
//! stage and command that hands them to the engine: the time mapping of the aligned
//! frames, the pinhole camera of each frames camera (with the map that undistorts its
//! images: undistortion happens here, once, and frames on disk stay as recorded), aligned
//! frames loaded and undistorted, the whole training dataset, the trained model, and the
//! render backend the engine draws with. This module only reads.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use calib::undistort::{Fit, UndistortMap};
use rayon::prelude::*;
use rig::frames::FramesIndex;
use serde::{Deserialize, Serialize};
use shared_types::{Camera, CameraSet, Progress};
use splat4d::gpu::AdapterPolicy;
use splat4d::render::gpu::GpuBackend;
use splat4d::train::{Dataset, ImageU8, View};
use splat4d::{Gaussians, RenderBackend, TimeMapping};

/// Which renderer draws images: `[engine] backend` in `capture.toml`, `--backend` on the
/// command line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// A hardware GPU when there is one, else the CPU (never a software GPU adapter, which
    /// is slower than the CPU engine).
    #[default]
    Auto,
    /// The CPU engine (the reference).
    Cpu,
    /// A hardware GPU through wgpu; an error when there is none.
    Gpu,
}

/// `[engine]`: the compute backend of the stages that render or train (`train`, `render`,
/// `eval`). Not a stage parameter: both backends draw the same images (within 1e-4) and
/// train to the same quality, so switching does not rerun anything; the backend used is
/// recorded in each stage's `stage.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EngineSettings {
    pub backend: BackendChoice,
    /// Time chunks (`[chunks]`) that train at once after the first: 0 for one per GPU
    /// (one at a time on the CPU). Each holds its own frames in memory.
    pub chunks_at_once: usize,
}

/// The backend that renders for `render`, `eval` and `pipeline render`, as `choice` asks,
/// logged. `SPLAT4D_GPU_SOFTWARE=1` lets `gpu` and `auto` use a software adapter (tests).
pub fn render_backend(choice: BackendChoice) -> anyhow::Result<Box<dyn RenderBackend>> {
    let backend = backend_for(choice, "rendering")?;
    tracing::info!("render backend: {}", backend.describe());
    Ok(backend)
}

/// The backend that trains the `train` stage, as `choice` (`[engine] backend`,
/// `--backend`) asks, under the same rules as [`render_backend`]: `auto` takes a hardware
/// GPU when there is one (never lavapipe unless `SPLAT4D_GPU_SOFTWARE=1`), else the CPU.
/// On the GPU the trainer runs the whole iteration there (`splat4d::train`).
pub fn training_backend_for(choice: BackendChoice) -> anyhow::Result<Box<dyn RenderBackend>> {
    let backend = backend_for(choice, "training")?;
    tracing::info!("training backend: {}", backend.describe());
    Ok(backend)
}

/// The backends that train time chunks side by side, one a lane: `[engine]
/// chunks_at_once` of them (0: one per GPU the backend choice allows, or one on the
/// CPU), and no more than `most` (the chunks there are to train at once; a GPU beyond
/// them is never opened). On GPUs lane `k` trains on the `k`th (wrapping around where
/// there are more lanes than GPUs); on the CPU the lanes share its cores.
pub fn training_lanes(
    engine: &EngineSettings,
    most: usize,
) -> anyhow::Result<Vec<Box<dyn RenderBackend>>> {
    let first = training_backend_for(engine.backend)?;
    let policy = AdapterPolicy::from_env();
    let gpus = match engine.backend {
        BackendChoice::Cpu => 0,
        _ => splat4d::gpu::Gpu::count(policy),
    };
    let on_gpu = gpus > 0 && first.as_gpu().is_some();
    let lanes = match engine.chunks_at_once {
        0 if on_gpu => gpus,
        0 => 1,
        n => n,
    }
    .min(most)
    .max(1);
    let mut backends = vec![first];
    for lane in 1..lanes {
        backends.push(if on_gpu {
            Box::new(
                GpuBackend::on_adapter(policy, lane)
                    .with_context(|| format!("the GPU of time-chunk lane {lane}"))?,
            )
        } else {
            Box::new(splat4d::CpuBackend)
        });
    }
    if lanes > 1 {
        let names: Vec<String> = backends.iter().map(|b| b.describe()).collect();
        tracing::info!("{lanes} time chunks train at once: {}", names.join("; "));
    }
    Ok(backends)
}

/// The CPU backend, for the benches that train (their timings stay comparable across
/// machines); the `train` stage uses [`training_backend_for`].
pub fn training_backend() -> Box<dyn RenderBackend> {
    let backend = Box::new(splat4d::CpuBackend);
    tracing::info!("training backend: {}", backend.describe());
    backend
}

/// `choice` as a backend; `what` (e.g. `rendering`) names the work in the fallback's log.
fn backend_for(choice: BackendChoice, what: &str) -> anyhow::Result<Box<dyn RenderBackend>> {
    let policy = AdapterPolicy::from_env();
    Ok(match choice {
        BackendChoice::Cpu => Box::new(splat4d::CpuBackend),
        BackendChoice::Gpu => Box::new(
            GpuBackend::new(policy).context("[engine] backend = \"gpu\" (or --backend gpu)")?,
        ),
        BackendChoice::Auto => match GpuBackend::new(policy) {
            Ok(gpu) => Box::new(gpu),
            Err(e) => {
                tracing::info!("no GPU backend ({e}); {what} on the CPU");
                Box::new(splat4d::CpuBackend)
            }
        },
    })
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
    load_dataset_window(frames_dir, cameras_file, None, progress)
}

/// [`load_dataset`] of the aligned frames `window` (positions in `frames.json`; `None`:
/// all): a time chunk loads only its own frames. The time mapping is the whole clip's.
pub fn load_dataset_window(
    frames_dir: &Path,
    cameras_file: &Path,
    window: Option<std::ops::Range<usize>>,
    progress: &dyn Progress,
) -> anyhow::Result<Dataset> {
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let poses = PosesFile::read(cameras_file)?;
    let cameras = pinhole_cameras(&index, &poses.set, cameras_file)?;
    let mapping = time_mapping(&index);
    let window = window.unwrap_or(0..index.frames.len());
    let jobs: Vec<(usize, PathBuf, f64)> = index
        .frames
        .get(window.clone())
        .with_context(|| {
            format!(
                "{} has {} frames, not the frames {window:?}; rerun the train stage with --force",
                frames_dir.join("frames.json").display(),
                index.frames.len()
            )
        })?
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

/// What the train stage records beside the model (`work/train/train.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainRecord {
    /// The colour the model was trained on (`[train] background` resolved; `"mean"`
    /// becomes the training images' mean colour): every render of the model uses it.
    pub background: [f32; 3],
    /// Each training camera's exposure gain its frames were divided by
    /// (`splat4d::train::exposure`; empty: the frames as filmed).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exposure: Vec<splat4d::train::exposure::CameraGain>,
    /// A backdrop was fitted behind the model (`[train] background = "learned"`,
    /// `work/train/backdrop.bin`): it is drawn behind the model, and `background` is
    /// only the colour the Gaussians trained on and the backdrop fades to.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub backdrop: bool,
}

impl TrainRecord {
    /// The backdrop fitted behind the model, when one was.
    pub fn load_backdrop(
        &self,
        work_dir: &Path,
    ) -> anyhow::Result<Option<splat4d::render::backdrop::Backdrop>> {
        if !self.backdrop {
            return Ok(None);
        }
        let path = work_dir.join("train").join(splat4d::train::BACKDROP_FILE);
        Ok(Some(splat4d::render::backdrop::load_backdrop(&path)?))
    }
}

/// Where the train stage records its [`TrainRecord`].
pub const TRAIN_RECORD: &str = "train.json";

/// What a capture's model was trained on: `work/train/train.json`, or, for a model trained
/// before the record existed, `[train] background` when it is a colour (and no exposure
/// gains).
pub fn trained_record(
    work_dir: &Path,
    setting: splat4d::train::Background,
) -> anyhow::Result<TrainRecord> {
    let path = work_dir.join("train").join(TRAIN_RECORD);
    match std::fs::read(&path) {
        Ok(bytes) => {
            let record: TrainRecord = serde_json::from_slice(&bytes).with_context(|| {
                format!(
                    "{} is corrupt; rerun the train stage (`pipeline run DIR --only train --force`)",
                    path.display()
                )
            })?;
            Ok(record)
        }
        Err(_) => match setting {
            splat4d::train::Background::Colour(c) => Ok(TrainRecord {
                background: c,
                exposure: Vec::new(),
                backdrop: false,
            }),
            splat4d::train::Background::Mean | splat4d::train::Background::Learned => bail!(
                "{} is missing, so the background the model was trained on is unknown; rerun the train stage (`pipeline run DIR --only train --force`)",
                path.display()
            ),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_train_one_at_a_time_on_the_cpu_unless_asked_for_more() {
        let lanes = |chunks_at_once| {
            training_lanes(
                &EngineSettings {
                    backend: BackendChoice::Cpu,
                    chunks_at_once,
                },
                4,
            )
            .unwrap()
        };
        assert_eq!(lanes(0).len(), 1);
        let three = lanes(3);
        assert_eq!(three.len(), 3);
        // No more lanes than chunks to train at once.
        assert_eq!(lanes(6).len(), 4);
        assert!(three.iter().all(|b| b.as_gpu().is_none()));
    }
}
