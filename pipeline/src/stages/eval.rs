//! The `eval` stage: metrics of the trained model on held-out views and, separately, on a
//! sample of the training views (`splat4d::eval`, docs/render-eval.md). Held-out views
//! are the frames of the cameras listed in `[capture] heldout` (a real capture, see
//! `crate::heldout`) or else the simulator's ground truth in `groundtruth/`. Where a view
//! has a moving-region mask (`crate::masks`), PSNR and SSIM inside it are reported too.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use glam::DVec3;
use rayon::prelude::*;
use rig::frames::FramesIndex;
use rig::sim::{HeldoutTimestamps, OffsetsFile};
use rig::sync::SyncResult;
use serde::{Deserialize, Serialize};
use shared_types::{Camera, CameraSet, WorldToCamera};
use splat4d::TimeMapping;
use splat4d::eval::EvalView;
use splat4d::train::exposure::{CameraGain, gain_of};

use crate::engine_inputs::{
    EngineSettings, TrainRecord, load_frame, load_trained_model, pinhole_cameras, time_mapping,
};
use crate::heldout::HELDOUT_FILE;
use crate::layout::Capture;
use crate::masks::{
    self, CAPTURE_MASKS_DIR, CameraFrames, MaskSource, PLATE_MASKS_DIR, PlateMasks,
};
use crate::stage_context::StageContext;

/// The simulator's ground truth in a capture directory (cameras, offsets, held-out views).
const GROUNDTRUTH_DIR: &str = "groundtruth";

/// `[eval]` settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalSettings {
    /// Another LPIPS network than the installed LPIPS-alex weights: an ONNX model
    /// (docs/render-eval.md says how to export one) or a `.safetensors` weights file.
    /// Relative to the capture directory. Unset: the installed weights
    /// (`scripts/setup.sh`); with none installed LPIPS is reported as skipped.
    pub lpips: Option<PathBuf>,
    /// Training views measured (evenly spread over cameras and frames; 0: none).
    pub train_views: usize,
    /// Every held-out frame is measured up to this many per held-out camera (evenly
    /// spread; 0: all).
    pub heldout_per_camera: usize,
    /// Without given masks (`masks/`, the simulator's), estimate the moving region of
    /// every view from its camera's static plate (`work/eval/plate_masks/`).
    pub plate_masks: bool,
}

impl Default for EvalSettings {
    fn default() -> Self {
        Self {
            lpips: None,
            train_views: 16,
            heldout_per_camera: 0,
            plate_masks: true,
        }
    }
}

/// The files the stage reads besides upstream outputs: the simulator's ground truth
/// (`groundtruth/`, when present), the user's moving-region masks (`masks/`, when
/// present) and the LPIPS network: the `lpips` file when set, else the installed weights
/// (so installing them reruns eval, which then reports LPIPS).
pub fn inputs(capture: &Capture, settings: &EvalSettings) -> Vec<PathBuf> {
    let mut inputs = vec![
        capture.root.join(GROUNDTRUTH_DIR),
        capture.root.join(CAPTURE_MASKS_DIR),
    ];
    match &settings.lpips {
        Some(path) => inputs.push(capture.resolve(path)),
        None => inputs.extend(splat4d::metrics::lpips::find_weights().ok().flatten()),
    }
    inputs
}

/// `n` evenly spread picks of `0..len` (all when `n` is 0 or ≥ `len`).
fn spread(len: usize, n: usize) -> Vec<usize> {
    if n == 0 || n >= len {
        return (0..len).collect();
    }
    (0..n).map(|k| k * len / n).collect()
}

/// Ground-truth cameras moved into the poses' frame: the similarity that carries the
/// true video camera centres onto the solved (or imported and normalised) ones.
fn align_truth(truth: &CameraSet, poses: &CameraSet) -> anyhow::Result<impl Fn(&Camera) -> Camera> {
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for c in &poses.cameras {
        if let Some(t) = truth.get(&c.name) {
            src.push(t.world_to_camera.centre());
            dst.push(c.world_to_camera.centre());
        }
    }
    let Some(s) = calib::similarity::umeyama(&src, &dst) else {
        bail!(
            "cannot relate the ground-truth cameras to the solved ones (fewer than 3 shared, or collinear)"
        );
    };
    Ok(move |c: &Camera| {
        let centre: DVec3 = s.apply(c.world_to_camera.centre());
        let rotation = c.world_to_camera.rotation() * s.rotation.transpose();
        let mut out = c.clone();
        out.world_to_camera = WorldToCamera::from_parts(rotation, -(rotation * centre));
        out
    })
}

/// Held-out views of a simulated capture (cameras moved into the poses' frame), undistorted
/// into `gt_dir` when the held-out camera has a lens, with their `masks` where there are
/// any. Empty when the capture has no ground truth.
pub fn heldout_views(
    capture: &Capture,
    settings: &EvalSettings,
    poses: &CameraSet,
    mapping: &TimeMapping,
    gt_dir: &Path,
    masks: Option<&MaskSource>,
) -> anyhow::Result<Vec<EvalView>> {
    let truth_dir = capture.root.join(GROUNDTRUTH_DIR);
    let heldout_dir = truth_dir.join("heldout");
    if !heldout_dir.is_dir() {
        return Ok(Vec::new());
    }
    let read = |name: &str| -> anyhow::Result<String> {
        let path = truth_dir.join(name);
        std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))
    };
    let truth: CameraSet = serde_json::from_str(&read("cameras.json")?)
        .context("groundtruth/cameras.json is not a camera set")?;
    let offsets: OffsetsFile = serde_json::from_str(&read("offsets.json")?)
        .context("groundtruth/offsets.json is not the simulator's offsets file")?;
    // The common timeline is the sync reference camera's clock.
    let sync = SyncResult::read_json(&capture.work_dir().join("sync/sync.json"))?;
    let reference = sync
        .cameras
        .iter()
        .find(|c| c.offset_s == 0.0)
        .map(|c| c.name.clone())
        .unwrap_or_else(|| "cam0".into());
    let start = offsets
        .cameras
        .iter()
        .find(|c| c.name == reference)
        .map(|c| c.start_time_s)
        .context("groundtruth/offsets.json lacks the reference camera")?;
    let to_poses_frame = align_truth(&truth, poses)?;
    let mut views = Vec::new();
    let mut names: Vec<PathBuf> = std::fs::read_dir(&heldout_dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    names.sort();
    for dir in names {
        let stamps_path = dir.join("timestamps.json");
        let stamps: HeldoutTimestamps = serde_json::from_str(
            &std::fs::read_to_string(&stamps_path)
                .with_context(|| format!("cannot read {}", stamps_path.display()))?,
        )
        .with_context(|| {
            format!(
                "{} is not a held-out timestamps file",
                stamps_path.display()
            )
        })?;
        let camera = truth
            .get(&stamps.camera)
            .with_context(|| format!("groundtruth/cameras.json has no camera {}", stamps.camera))?;
        let camera = to_poses_frame(camera);
        let map = (!camera.distortion.is_none()).then(|| {
            calib::undistort::UndistortMap::new(&camera, calib::undistort::Fit::ValidPixels)
        });
        let pinhole = map.as_ref().map_or(camera.clone(), |m| m.pinhole().clone());
        for k in spread(stamps.times_s.len(), settings.heldout_per_camera) {
            let time = mapping.model_time(stamps.times_s[k] - start);
            if time < 0.0 || time > mapping.duration {
                continue; // outside the trained sequence
            }
            let source = dir.join(format!("{k:06}.png"));
            let found = masks.and_then(|m| m.for_simulated_image(&stamps.camera, k));
            let mask = view_mask(found, &source, map.as_ref(), gt_dir, &stamps.camera, k)?;
            let image_path = match &map {
                None => source,
                Some(map) => write_undistorted(&source, map, gt_dir, &stamps.camera, k)?,
            };
            views.push(EvalView {
                camera: pinhole.clone(),
                time,
                image_path,
                mask,
                gain: [1.0; 3],
            });
        }
    }
    Ok(views)
}

/// Held-out views of a capture with `[capture] heldout` cameras: every aligned frame of
/// those cameras (`frames_dir/heldout.json`, thinned to `heldout_per_camera` per camera),
/// posed by `poses_dir/heldout.json`, undistorted to pinhole exactly as the train stage
/// undistorts its frames (copies in `gt_dir/<camera>/` where a lens needs it), at the
/// model time of each frame's exact timestamp, with their `masks` where there are any.
pub fn capture_heldout_views(
    frames_dir: &Path,
    poses_dir: &Path,
    settings: &EvalSettings,
    mapping: &TimeMapping,
    gt_dir: &Path,
    masks: Option<&MaskSource>,
) -> anyhow::Result<Vec<EvalView>> {
    let (index, _) = read_heldout_file(frames_dir, "frames", FramesIndex::read_json)?;
    let (poses, poses_path) = read_heldout_file(poses_dir, "poses", PosesFile::read)?;
    let cameras = pinhole_cameras(&index, &poses.set, &poses_path)?;
    let picks = (0..cameras.len())
        .flat_map(|c| {
            spread(index.frames.len(), settings.heldout_per_camera)
                .into_iter()
                .map(move |f| (f, c))
        })
        .collect::<Vec<_>>();
    frame_views(frames_dir, &index, &cameras, picks, mapping, gt_dir, masks)
}

/// `heldout.json` of the `stage` folder `dir` (the held-out cameras' frames or poses),
/// read with `read`; the error says which stage to rerun. Returns it with its path.
fn read_heldout_file<T, E>(
    dir: &Path,
    stage: &str,
    read: impl FnOnce(&Path) -> Result<T, E>,
) -> anyhow::Result<(T, PathBuf)>
where
    E: std::error::Error + Send + Sync + 'static,
{
    let path = dir.join(HELDOUT_FILE);
    let value = read(&path).with_context(|| {
        format!(
            "cannot read the held-out cameras' {stage} {}; rerun the {stage} stage (`pipeline run CAPTURE --from {stage} --force`)",
            path.display()
        )
    })?;
    Ok((value, path))
}

/// Eval views of the aligned frames `picks` (frame, camera index) of `index`, at the
/// model time of each frame's exact timestamp, with their `masks` where there are any;
/// undistorted copies in `gt_dir` where the camera has a lens.
fn frame_views(
    frames_dir: &Path,
    index: &FramesIndex,
    cameras: &[(Camera, Option<calib::undistort::UndistortMap>)],
    picks: Vec<(usize, usize)>,
    mapping: &TimeMapping,
    gt_dir: &Path,
    masks: Option<&MaskSource>,
) -> anyhow::Result<Vec<EvalView>> {
    picks
        .into_par_iter()
        .map(|(f, c)| {
            let view = &index.frames[f].views[c];
            let (camera, map) = &cameras[c];
            let source = frames_dir.join(&view.file);
            let found = match masks {
                Some(m) => m.for_view(&index.cameras[c].name, view)?,
                None => None,
            };
            let mask = view_mask(found, &source, map.as_ref(), gt_dir, &camera.name, f)?;
            let image_path = match map {
                None => source,
                Some(map) => write_undistorted(&source, map, gt_dir, &camera.name, f)?,
            };
            Ok(EvalView {
                camera: camera.clone(),
                time: mapping.model_time(view.timestamp_s),
                image_path,
                mask,
                gain: [1.0; 3],
            })
        })
        .collect()
}

/// The `found` mask of the ground-truth image `source` made ready for eval
/// (`masks::prepare`; a fitted copy goes to `gt_dir/<camera>/NNNNNN_mask.png`).
fn view_mask(
    found: Option<PathBuf>,
    source: &Path,
    map: Option<&calib::undistort::UndistortMap>,
    gt_dir: &Path,
    camera: &str,
    k: usize,
) -> anyhow::Result<Option<PathBuf>> {
    found
        .map(|mask| {
            let out = gt_dir.join(camera).join(format!("{k:06}_mask.png"));
            masks::prepare(&mask, source, map, &out)
        })
        .transpose()
}

/// Undistort a ground-truth image into `gt_dir/<camera>/NNNNNN.png`.
fn write_undistorted(
    source: &Path,
    map: &calib::undistort::UndistortMap,
    gt_dir: &Path,
    camera: &str,
    k: usize,
) -> anyhow::Result<PathBuf> {
    let image = load_frame(source, Some(map))?;
    let out = gt_dir.join(camera).join(format!("{k:06}.png"));
    std::fs::create_dir_all(out.parent().unwrap_or(gt_dir))?;
    let buffer = image::RgbImage::from_raw(image.width, image.height, image.data)
        .context("undistorted image has the wrong size")?;
    buffer
        .save(&out)
        .with_context(|| format!("cannot write {}", out.display()))?;
    Ok(out)
}

/// `n` (frame, camera) picks spread evenly over the frames of every camera in turn, so
/// that each camera is measured (all pairs when `n` ≥ frames × cameras).
fn train_picks(frames: usize, cameras: usize, n: usize) -> Vec<(usize, usize)> {
    if n == 0 || cameras == 0 {
        return Vec::new();
    }
    let per_camera = spread(frames, n.div_ceil(cameras));
    let mut picks: Vec<(usize, usize)> = (0..per_camera.len())
        .flat_map(|k| (0..cameras).map(move |c| (k, c)))
        .map(|(k, c)| (per_camera[k], c))
        .collect();
    picks.truncate(n);
    picks
}

/// A spread of the training views (undistorted copies in `gt_dir` where needed), with
/// their `masks` where there are any and their cameras' exposure `gains` (renders are
/// compared as each camera filmed them).
#[allow(clippy::too_many_arguments)]
fn train_views(
    ctx: &StageContext,
    settings: &EvalSettings,
    poses: &CameraSet,
    index: &FramesIndex,
    mapping: &TimeMapping,
    gt_dir: &Path,
    masks: Option<&MaskSource>,
    gains: &[CameraGain],
) -> anyhow::Result<Vec<EvalView>> {
    let cameras = pinhole_cameras(index, poses, &ctx.stage_dir("poses").join("cameras.json"))?;
    let picks = train_picks(
        index.frames.len(),
        index.cameras.len(),
        settings.train_views,
    );
    let mut views = frame_views(
        &ctx.stage_dir("frames"),
        index,
        &cameras,
        picks,
        mapping,
        gt_dir,
        masks,
    )?;
    for view in &mut views {
        view.gain = gain_of(gains, &view.camera.name);
    }
    Ok(views)
}

/// The LPIPS network: the file of `[eval] lpips` (a path relative to the capture) when it
/// is set, else the installed LPIPS-alex weights; `None` (with a warning saying how to
/// install them) when there are none.
pub fn load_lpips(
    capture: &Capture,
    settings: &EvalSettings,
) -> anyhow::Result<Option<splat4d::metrics::lpips::Lpips>> {
    use splat4d::metrics::lpips::{INSTALL_HINT, Lpips};
    let Some(path) = &settings.lpips else {
        let lpips = Lpips::installed().context("cannot load the installed LPIPS weights")?;
        match &lpips {
            Some(net) => tracing::debug!("LPIPS: {} from {}", net.kind(), net.path().display()),
            None => tracing::warn!("LPIPS skipped: no weights installed; {INSTALL_HINT}"),
        }
        return Ok(lpips);
    };
    let path = capture.resolve(path);
    let lpips = Lpips::load(&path).with_context(|| {
        format!(
            "[eval] lpips = {}: cannot load the LPIPS model",
            path.display()
        )
    })?;
    Ok(Some(lpips))
}

/// The held-out views of a capture: its `[capture] heldout` cameras (`heldout_cameras`)
/// when it has some, else the simulator's `groundtruth/heldout/` (none: empty). Their
/// ground-truth images are written under `gt_dir`.
pub fn any_heldout_views(
    capture: &Capture,
    settings: &EvalSettings,
    heldout_cameras: &[String],
    poses: &CameraSet,
    mapping: &TimeMapping,
    gt_dir: &Path,
    masks: Option<&MaskSource>,
) -> anyhow::Result<Vec<EvalView>> {
    let work = capture.work_dir();
    if heldout_cameras.is_empty() {
        heldout_views(capture, settings, poses, mapping, gt_dir, masks)
    } else {
        capture_heldout_views(
            &work.join("frames"),
            &work.join("poses"),
            settings,
            mapping,
            gt_dir,
            masks,
        )
    }
}

/// The moving-region masks eval scores inside: the capture's `masks/` or the simulator's
/// ground truth ([`MaskSource::find`]), else, with `[eval] plate_masks`, masks estimated
/// from each camera's static plate (training and held-out cameras) into `plates_dir`.
pub fn moving_masks(
    capture: &Capture,
    settings: &EvalSettings,
    heldout_cameras: &[String],
    plates: PlateMasks,
    plates_dir: &Path,
) -> anyhow::Result<Option<MaskSource>> {
    let work = capture.work_dir();
    match MaskSource::find(&capture.root, &work.join("sync").join("sync.json"))? {
        None if settings.plate_masks => {
            let frames_dir = work.join("frames");
            let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
            let mut cameras = CameraFrames::of_index(&index);
            if !heldout_cameras.is_empty() {
                let (heldout, _) =
                    read_heldout_file(&frames_dir, "frames", FramesIndex::read_json)?;
                cameras.extend(CameraFrames::of_index(&heldout));
            }
            MaskSource::from_plates(&frames_dir, &cameras, plates, plates_dir)
        }
        found => Ok(found),
    }
}

/// The `eval` stage; `heldout_cameras` are the held-out camera names of `[capture] heldout`,
/// `trained` is what the model was trained on (views are rendered on its background, the
/// training views as their cameras filmed them).
pub fn run(
    ctx: &StageContext,
    settings: &EvalSettings,
    heldout_cameras: &[String],
    trained: &TrainRecord,
    engine: &EngineSettings,
    plates: PlateMasks,
) -> anyhow::Result<()> {
    let model = load_trained_model(&ctx.capture.work_dir())?;
    let poses = PosesFile::read(&ctx.stage_dir("poses").join("cameras.json"))?;
    let index = FramesIndex::read_json(&ctx.stage_dir("frames").join("frames.json"))?;
    let mapping = time_mapping(&index);
    let gt_dir = ctx.output("groundtruth");
    ctx.progress.message("moving-region masks");
    let masks = moving_masks(
        ctx.capture,
        settings,
        heldout_cameras,
        plates,
        &ctx.output(PLATE_MASKS_DIR),
    )?;
    let heldout = any_heldout_views(
        ctx.capture,
        settings,
        heldout_cameras,
        &poses.set,
        &mapping,
        &gt_dir.join("heldout"),
        masks.as_ref(),
    )?;
    if heldout.is_empty() {
        tracing::warn!(
            "no held-out views (no [capture] heldout cameras and no groundtruth/heldout/): only training views are measured, which shows fit, not novel-view quality"
        );
    }
    let train = train_views(
        ctx,
        settings,
        &poses.set,
        &index,
        &mapping,
        &gt_dir.join("train"),
        masks.as_ref(),
        &trained.exposure,
    )?;
    // Estimated masks are written to the stage's temporary folder: name where they end up.
    let estimated_dir = ctx.stage_dir("eval").join(PLATE_MASKS_DIR);
    log_masks(masks.as_ref(), &estimated_dir, &heldout, &train);
    let lpips = load_lpips(ctx.capture, settings)?;
    let backend = crate::engine_inputs::render_backend(engine.backend)?;
    ctx.record_tool("render backend", &backend.describe());
    let backdrop = trained.load_backdrop(&ctx.capture.work_dir())?;
    let report = splat4d::eval::evaluate(
        backend.as_ref(),
        &model,
        &heldout,
        &train,
        &ctx.out_dir,
        lpips.as_ref(),
        trained.background,
        backdrop.as_ref(),
        ctx.progress,
    )?;
    let show = |set: &str, m: &splat4d::eval::SetMetrics| {
        let f = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.4}"));
        let lpips_text = match (&lpips, m.lpips) {
            (None, _) => "skipped (no weights: run scripts/setup.sh)".to_string(),
            (Some(_), v) => f(v),
        };
        let darkest = m.darkest_frame.map_or(String::new(), |i| {
            let v = &m.frames[i];
            format!(
                "; darkest view {} at {:.3} s, {:.3} of the truth's brightness",
                v.camera, v.time_s, v.brightness
            )
        });
        tracing::info!(
            "{set}: {} views, PSNR {} dB, SSIM {}, DSSIM1 {}, DSSIM2 {}, LPIPS {lpips_text}{darkest}",
            m.frames.len(),
            f(m.psnr),
            f(m.ssim),
            f(m.dssim1),
            f(m.dssim2),
        );
    };
    show("held-out", &report.heldout);
    show("training", &report.train);
    for (set, m) in [("held-out", &report.heldout), ("training", &report.train)] {
        if let Some(moving) = &m.moving {
            show_moving(set, m, moving);
        }
    }
    Ok(())
}

/// Says where the moving-region masks come from and how many views have one, or that
/// there are none (then `metrics.json` says nothing about the moving region).
fn log_masks(
    source: Option<&MaskSource>,
    estimated_dir: &Path,
    heldout: &[EvalView],
    train: &[EvalView],
) {
    let count = |views: &[EvalView]| views.iter().filter(|v| v.mask.is_some()).count();
    let (h, t) = (count(heldout), count(train));
    match source {
        Some(source) if h + t > 0 => tracing::info!(
            "moving-region masks {}: {h} of {} held-out and {t} of {} training views",
            if source.estimated() {
                format!(
                    "estimated from each camera's static plate (where a frame differs from the median of the camera's frames; `[eval] plate_masks = false` turns this off), written to {}",
                    estimated_dir.display()
                )
            } else {
                format!("from {}", source.dir().display())
            },
            heldout.len(),
            train.len()
        ),
        _ => tracing::info!(
            "no moving-region masks (no {CAPTURE_MASKS_DIR}/<camera>/ in the capture, no groundtruth/masks/ for these views): moving-region metrics are not reported"
        ),
    }
}

/// Logs a set's moving-region means beside its whole-image ones.
fn show_moving(set: &str, whole: &splat4d::eval::SetMetrics, m: &splat4d::eval::MovingSummary) {
    let f = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
    let darkest_view = m.darkest_frame.map_or(String::new(), |i| {
        let v = &whole.frames[i];
        format!(": {} at {:.3} s", v.camera, v.time_s)
    });
    tracing::info!(
        "{set} moving region: {} views ({} with an empty mask left out), PSNR {} dB (whole image {}), SSIM {} (whole image {}), LPIPS {} (whole image {}), brightness {} of the truth's (darkest view {}{darkest_view}), mask fraction {}",
        m.frames,
        m.empty_masks,
        f(m.psnr, 2),
        f(whole.psnr, 2),
        f(m.ssim, 4),
        f(whole.ssim, 4),
        f(m.lpips, 3),
        f(whole.lpips, 3),
        f(m.brightness, 3),
        f(m.darkest, 3),
        f(m.mask_fraction, 3)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn training_views_cover_every_camera() {
        // 32 frames × 4 cameras, 16 views: 4 frames of each camera, spread over time.
        let picks = train_picks(32, 4, 16);
        assert_eq!(picks.len(), 16);
        for c in 0..4 {
            let frames: Vec<usize> = picks.iter().filter(|p| p.1 == c).map(|p| p.0).collect();
            assert_eq!(frames, [0, 8, 16, 24], "camera {c}");
        }
        assert_eq!(train_picks(3, 4, 100).len(), 12);
        assert_eq!(train_picks(10, 4, 6).len(), 6);
        assert!(train_picks(10, 4, 0).is_empty());
    }
}
