//! Exports of a trained 4D model for people and other tools (docs/export.md):
//! per-timestep 3DGS PLY frames (SuperSplat, Brush), glTF with `KHR_gaussian_splatting`
//! (three.js, Babylon.js, PlayCanvas, CesiumJS), the native 4D model as PLY, a `.splatv`
//! for splaTV-style players and a self-contained browser viewer that draws the native 4D
//! model from one compact file (`web4d`). [`export_all`] writes
//! them all; the submodules hold one format each. Every file is written to a temporary
//! name and renamed when complete.

pub mod bake;
pub mod gltf;
pub mod ply3d;
pub mod ply4d;
pub mod splatv;
pub mod viewer;
pub mod web4d;

use crate::model::Gaussians;
use crate::{CameraSet, Progress};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use bake::{Frame3d, Splat3d, bake_frame};
pub use ply3d::{read_frame_ply, write_frame_ply};
pub use ply4d::{read_model_ply, write_model_ply};
pub use splatv::write_splatv;
pub use viewer::find_viewer_bundle;

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("cannot write or read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not a file this exporter reads: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("the model is inconsistent: {0}; re-train or re-load it")]
    InconsistentModel(String),
    #[error("no export times given; pass at least one model time")]
    NoTimes,
    #[error(
        "the browser viewer bundle is missing (looked for index.html in {looked_in} and beside the executable); run `scripts/setup.sh` to build it (npm ci + build in viewer/), set SPLAT4D_VIEWER_DIST to a built viewer/dist, or export without the viewer"
    )]
    ViewerBundleMissing { looked_in: PathBuf },
}

/// Write `bytes` to `path` atomically (`crate::atomic`); creates parent folders.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ExportError> {
    crate::atomic::write_atomic(path, bytes).map_err(|source| ExportError::Io {
        path: path.into(),
        source,
    })
}

/// Settings of [`export_all`]: the `[export]` section of `capture.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExportOptions {
    /// Number of evenly spaced time steps to export (`None`: one per aligned frame of the
    /// capture); see [`ExportOptions::times`].
    pub steps: Option<usize>,
    /// Per-timestep Gaussians whose `opacity · ω(t)` is below this are dropped (1/255: the
    /// renderer skips such splats entirely).
    pub min_opacity: f64,
    /// Write `frames/NNNN.ply` (a 3DGS PLY per time step: large, so only on request).
    pub frames: bool,
    /// Write glTF (`KHR_gaussian_splatting`): `scene.glb` at the middle export time, or
    /// with `gltf_every = k` every k-th export time as `gltf/NNNN.glb`.
    pub gltf: bool,
    /// Every how many export times a `.glb` is written (0: only `scene.glb`).
    pub gltf_every: usize,
    /// Write `model4d.ply`.
    pub model4d: bool,
    /// Write `scene.splatv` (on request: the viewer plays the model itself).
    pub splatv: bool,
    /// Write `viewer/` (needs the built bundle, see [`viewer::find_viewer_bundle`]).
    pub viewer: bool,
    /// The viewer's model in files of about this many seconds of the clip, which the
    /// page loads ahead of the playhead and drops behind it (the static scene is one
    /// more file, always loaded): a long clip never sits whole in the browser. 0, or a
    /// clip up to 1.5 × this long: one file.
    pub segment_seconds: f64,
    /// The built viewer bundle; `None` = find it (see [`viewer::find_viewer_bundle`]).
    #[serde(skip)]
    pub viewer_bundle: Option<PathBuf>,
    /// The colour the model was trained on (`[train] background`): the viewer draws it
    /// behind the splats, as render and eval do. Not a setting: the export stage takes it
    /// from the training record.
    #[serde(skip)]
    pub background: [f32; 3],
    /// The learned backdrop the model was trained on, when it was: the viewer draws it
    /// instead of `background`. Taken from the training record, like `background`.
    #[serde(skip)]
    pub backdrop: Option<crate::render::backdrop::Backdrop>,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            steps: None,
            min_opacity: 1.0 / 255.0,
            frames: false,
            gltf: true,
            gltf_every: 0,
            model4d: true,
            splatv: false,
            viewer: true,
            segment_seconds: 5.0,
            viewer_bundle: None,
            background: [0.0; 3],
            backdrop: None,
        }
    }
}

/// One written 3DGS frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub path: PathBuf,
    /// Model time.
    pub t: f64,
    /// Gaussians written / dropped at this time.
    pub kept: usize,
    pub dropped: usize,
}

/// What [`export_all`] wrote.
#[derive(Clone, Debug, Serialize)]
pub struct ExportReport {
    pub gaussians: usize,
    pub frames: Vec<FrameReport>,
    /// The `.glb` files, with their model times.
    pub gltf: Vec<(PathBuf, f64)>,
    pub model4d: Option<PathBuf>,
    pub splatv: Option<PathBuf>,
    /// Splats in the `.splatv` (fully transparent ones are left out).
    pub splatv_splats: usize,
    /// `viewer/index.html`.
    pub viewer_index: Option<PathBuf>,
    pub seconds: f64,
}

impl ExportReport {
    /// The same report with every path relative to `dir` (the folder the report is saved
    /// in): a stage exports into a temporary folder that is renamed when complete, and the
    /// paths it records must hold after the rename.
    pub fn relative_to(&self, dir: &Path) -> ExportReport {
        let rel = |p: &PathBuf| crate::eval::relative_path(dir, p);
        ExportReport {
            frames: self
                .frames
                .iter()
                .map(|f| FrameReport {
                    path: rel(&f.path),
                    ..f.clone()
                })
                .collect(),
            gltf: self.gltf.iter().map(|(p, t)| (rel(p), *t)).collect(),
            model4d: self.model4d.as_ref().map(rel),
            splatv: self.splatv.as_ref().map(rel),
            viewer_index: self.viewer_index.as_ref().map(rel),
            ..self.clone()
        }
    }
}

impl ExportOptions {
    /// The model times to export: `steps` (or `default_steps`) evenly spanning the model.
    pub fn times(&self, model: &Gaussians<f32>, default_steps: usize) -> Vec<f64> {
        even_times(model, self.steps.unwrap_or(default_steps))
    }
}

/// `count` model times evenly spanning `[0, duration]` (the frame times of an export).
pub fn even_times(model: &Gaussians<f32>, count: usize) -> Vec<f64> {
    let d = bake::colour_period(model);
    match count {
        0 => Vec::new(),
        1 => vec![0.5 * d],
        n => (0..n).map(|k| d * k as f64 / (n - 1) as f64).collect(),
    }
}

/// The `.glb` files [`export_all`] writes (path relative to the export folder, model
/// time): `scene.glb` at the middle of `times`, or every `gltf_every`-th time.
fn gltf_files(times: &[f64], opts: &ExportOptions) -> Vec<(String, f64)> {
    match (opts.gltf, opts.gltf_every) {
        (false, _) => Vec::new(),
        (true, 0) => times
            .get(times.len() / 2)
            .map(|&t| ("scene.glb".to_string(), t))
            .into_iter()
            .collect(),
        (true, k) => times
            .iter()
            .enumerate()
            .step_by(k)
            .map(|(i, &t)| (format!("gltf/{i:04}.glb"), t))
            .collect(),
    }
}

/// Mean camera centre: the viewpoint used to bake view-dependent colour into the
/// single-colour `.splatv`.
fn colour_viewpoint(cameras: &CameraSet) -> Option<[f64; 3]> {
    let n = cameras.cameras.len();
    (n > 0).then(|| {
        let s: glam::DVec3 = cameras
            .cameras
            .iter()
            .map(|c| c.world_to_camera.centre())
            .sum();
        (s / n as f64).to_array()
    })
}

/// Write every export of `model` into `out_dir`: `frames/NNNN.ply` (one 3DGS PLY per model
/// time in `times`), glTF, `model4d.ply`, `scene.splatv` and `viewer/` (the page, the
/// whole model as `model.4dgs` for the span of `times`, `scene.json`), as selected in
/// `opts`. `cameras` give the viewer's cameras, the `.splatv` camera list and the
/// viewpoint of the `.splatv`'s single colour.
pub fn export_all(
    model: &Gaussians<f32>,
    cameras: &CameraSet,
    times: &[f64],
    out_dir: &Path,
    opts: &ExportOptions,
    progress: &dyn Progress,
) -> Result<ExportReport, ExportError> {
    let start = std::time::Instant::now();
    model
        .check_consistent()
        .map_err(ExportError::InconsistentModel)?;
    if times.is_empty() && (opts.frames || opts.viewer || opts.gltf) {
        return Err(ExportError::NoTimes);
    }
    // Fail early, before any long work, when the viewer cannot be built.
    let bundle = match (opts.viewer, &opts.viewer_bundle) {
        (false, _) => None,
        (true, Some(b)) if b.join("index.html").is_file() => Some(b.clone()),
        (true, Some(b)) => {
            return Err(ExportError::ViewerBundleMissing {
                looked_in: b.clone(),
            });
        }
        (true, None) => Some(viewer::find_viewer_bundle()?),
    };
    let frames_total = if opts.frames { times.len() } else { 0 };
    let gltf_files = gltf_files(times, opts);
    let total = frames_total
        + gltf_files.len()
        + opts.viewer as usize
        + opts.model4d as usize
        + opts.splatv as usize;
    progress.start(total as u64, "files");
    let view = colour_viewpoint(cameras);
    let mut report = ExportReport {
        gaussians: model.len(),
        frames: Vec::new(),
        gltf: Vec::new(),
        model4d: None,
        splatv: None,
        splatv_splats: 0,
        viewer_index: None,
        seconds: 0.0,
    };

    if opts.model4d {
        let p = out_dir.join("model4d.ply");
        write_model_ply(model, &p)?;
        report.model4d = Some(p);
        progress.advance(1);
    }
    if opts.splatv {
        let p = out_dir.join("scene.splatv");
        let cams: Vec<_> = cameras
            .cameras
            .iter()
            .enumerate()
            .map(|(i, c)| splatv::SplatvCamera::from_camera(i, c))
            .collect();
        report.splatv_splats = write_splatv(model, &cams, view, &p)?;
        report.splatv = Some(p);
        progress.advance(1);
    }
    if opts.frames {
        for (k, &t) in times.iter().enumerate() {
            let frame = bake_frame(model, t, opts.min_opacity);
            let p = out_dir.join("frames").join(format!("{k:04}.ply"));
            write_frame_ply(&frame, &p)?;
            progress.message(&format!("t = {t:.3}: {} Gaussians", frame.splats.len()));
            report.frames.push(FrameReport {
                path: p,
                t,
                kept: frame.splats.len(),
                dropped: frame.dropped,
            });
            progress.advance(1);
        }
    }
    for (name, t) in gltf_files {
        let p = out_dir.join(name);
        gltf::write_glb(&bake_frame(model, t, opts.min_opacity), &p)?;
        report.gltf.push((p, t));
        progress.advance(1);
    }
    if let Some(bundle) = bundle {
        let index = viewer::write_viewer(
            model,
            cameras,
            times,
            &bundle,
            opts,
            &out_dir.join("viewer"),
        )?;
        report.viewer_index = Some(index);
        progress.advance(1);
    }
    report.seconds = start.elapsed().as_secs_f64();
    progress.finish();
    Ok(report)
}
