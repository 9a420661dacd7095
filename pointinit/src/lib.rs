//! The `init` stage: the starting point cloud of the 4D Gaussians, from MASt3R-style point
//! maps (an ONNX model run here with [`onnx`], or its outputs exported as `.npy`/`.npz`,
//! [`npy`]), each pair scaled into the posed cameras' world frame ([`pair_scale`]) and
//! fused ([`fuse`]); or triangulated with COLMAP and the known cameras at several moments
//! of the clip ([`moments`]), static points told from moving ones ([`statics`]); with the
//! fallback chain point maps → triangulated moments → sparse COLMAP points → a random
//! cloud in the cameras' common view volume, each fallback announced with `tracing::warn!`.
//!
//! Call [`run_init`] with [`InitInputs`] and an [`InitConfig`]; it writes
//! `<out_dir>/points.ply` (xyz, rgb, time; atomically) and returns an [`InitReport`].
//! The user-facing description is `docs/init.md`. This module reads no pipeline files
//! itself (frames index, stage manifests): the caller passes plain inputs.

pub mod fuse;
pub mod moment_maps;
pub mod moments;
pub mod npy;
pub mod onnx;
pub mod pair_scale;
pub mod statics;
pub mod sweep;

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec3;
use image::RgbImage;
use serde::{Deserialize, Serialize};
use shared_types::points::{PlyError, read_points_ply, write_points_ply};
use shared_types::{Camera, CameraSet, Progress};

use calib::colmap_runner::find_colmap;
use calib::undistort::{Fit, UndistortMap};
use fuse::{FusedPoint, colour_at, unproject};
pub use moments::{Moment, MomentReport};
use npy::{NpyError, OutputNames, PairMaps, PointMap};
use onnx::{ModelConfig, OnnxError, PointMapModel};
use pair_scale::{Relative, pixel_centre, ray_scale, sparse_scale};
use statics::StaticCounts;

/// Where the initial points should come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// `model` if set, else `pointmaps` if set, else triangulated moments (unless
    /// `moments` is 0), with the plane sweep's points added when they are fewer than
    /// `min_points` (COLMAP missing, wide baselines), else sparse points, else random.
    #[default]
    Auto,
    /// Run the ONNX model `model` (falls back when every pair is rejected).
    Onnx,
    /// Read exported point maps from `pointmaps` (falls back when every pair is rejected).
    Npy,
    /// Triangulate the known cameras' frames at `moments` moments with COLMAP (falls back
    /// to the sparse points when COLMAP is missing or no moment gives points).
    Triangulate,
    /// Dense plane-sweep stereo of the known cameras' frames at `moments` moments
    /// ([`sweep`]; falls back to triangulation, then the sparse points, when no depth is
    /// confirmed).
    Sweep,
    /// The sparse COLMAP points (falls back to random when there are none).
    Sparse,
    /// A random cloud in the cameras' common view volume.
    Random,
}

/// Which image pairs go through the model: `"all"` or a list of `[first, second]` names.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Pairs {
    Keyword(PairsKeyword),
    List(Vec<[String; 2]>),
}

/// The keyword form of [`Pairs`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairsKeyword {
    /// Every pair of cameras (ONNX: each unordered pair once, in camera order; exported
    /// maps: every pair present in the directory).
    All,
}

impl Default for Pairs {
    fn default() -> Self {
        Pairs::Keyword(PairsKeyword::All)
    }
}

/// Settings of the init stage (`capture.toml [init]`). Lengths marked "× rig radius" are
/// fractions of the mean distance of the cameras from their centroid, so they do not
/// depend on the scene's units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitConfig {
    pub source: Source,
    /// ONNX point-map model.
    pub model: Option<PathBuf>,
    /// Directory of exported point maps (`a__b.npz` or `a__b/*.npy`).
    pub pointmaps: Option<PathBuf>,
    /// Model input names (first image, second image).
    pub input_names: [String; 2],
    /// Model output names, also the array names in exported files.
    pub output_names: OutputNames,
    /// `[width, height]` the images are resized to for the model.
    pub input_size: [u32; 2],
    pub pairs: Pairs,
    /// Pixels with a lower confidence are dropped (MASt3R confidences are ≥ 1).
    pub min_confidence: f32,
    /// Voxel edge for downsampling, × rig radius (0: no downsampling).
    pub voxel_size: f64,
    /// At most this many points are written (random subset, seeded).
    pub max_points: usize,
    /// Points of the random fallback cloud.
    pub random_points: usize,
    /// A source that gives fewer points than this (a few dozen triangulated across wide
    /// baselines) is topped up with the random cloud (0: never).
    pub min_points: usize,
    pub seed: u64,
    /// A pair is rejected when its ray scale and sparse-point scale differ by more than
    /// this fraction.
    pub scale_tolerance: f64,
    /// A pair is rejected when its median reprojection error in the second camera exceeds
    /// this fraction of the map width; second-view pixels above it are dropped.
    pub max_residual: f64,
    /// Sparse points needed for the sparse scale check of a pair.
    pub min_sparse_matches: usize,
    /// A pair is rejected when more than this fraction of its pixels is not finite.
    pub max_non_finite: f64,
    /// Undistortion field of view for the images fed to the model (and to COLMAP).
    pub fit: Fit,
    /// Moments of the clip to triangulate (evenly spread over the aligned frames; 0: off).
    pub moments: usize,
    /// Triangulated points must be seen by at least this many cameras (≥ 2).
    pub min_track: usize,
    /// A triangulated point with a point of another moment this close is static, × rig
    /// radius; static points this close are merged.
    pub static_radius: f64,
    /// Add the poses stage's sparse points to the triangulated ones, as static points.
    pub merge_sparse: bool,
    /// The `colmap` binary for triangulation; `None`: `$COLMAP_BIN`, then `PATH`.
    pub colmap: Option<PathBuf>,
    /// Plane sweep: long side (pixels) the frames are shrunk to.
    pub sweep_size: u32,
    /// Plane sweep: most depth planes per camera (they are one pixel of motion apart).
    pub sweep_max_planes: usize,
    /// Plane sweep: least NCC of a pixel's best match for it to take a depth.
    pub sweep_min_score: f32,
    /// Plane sweep: cameras whose depth maps must agree on a point (≥ 2).
    pub sweep_min_views: usize,
}

impl Default for InitConfig {
    fn default() -> Self {
        let m = ModelConfig::default();
        Self {
            source: Source::Auto,
            model: None,
            pointmaps: None,
            input_names: m.input_names,
            output_names: m.output_names,
            input_size: m.input_size,
            pairs: Pairs::default(),
            min_confidence: 1.5,
            voxel_size: 0.004,
            max_points: 300_000,
            random_points: 50_000,
            min_points: 1000,
            seed: 0,
            scale_tolerance: 0.15,
            max_residual: 0.02,
            min_sparse_matches: 20,
            max_non_finite: 0.5,
            fit: Fit::ValidPixels,
            moments: 6,
            min_track: 2,
            static_radius: 0.008,
            merge_sparse: true,
            colmap: None,
            sweep_size: 320,
            sweep_max_planes: 512,
            sweep_min_score: 0.7,
            sweep_min_views: 2,
        }
    }
}

impl InitConfig {
    /// The model part of the settings.
    pub fn model_config(&self) -> ModelConfig {
        ModelConfig {
            input_names: self.input_names.clone(),
            output_names: self.output_names.clone(),
            input_size: self.input_size,
        }
    }

    /// The plane-sweep part of the settings.
    pub fn sweep_options(&self) -> sweep::SweepOptions {
        sweep::SweepOptions {
            size: self.sweep_size,
            max_planes: self.sweep_max_planes,
            min_score: self.sweep_min_score,
            min_views: self.sweep_min_views,
        }
    }
}

/// One image of a training camera: its first frame (distorted, at the cameras' working
/// size) and that frame's time (the model's time axis; written to each point).
#[derive(Clone, Debug, PartialEq)]
pub struct ViewImage {
    pub camera: String,
    pub path: PathBuf,
    pub time: f64,
}

/// What the init stage is given.
#[derive(Clone, Debug)]
pub struct InitInputs {
    /// The training cameras (`work/poses/cameras.json`), with their lens.
    pub cameras: CameraSet,
    /// First frame of each camera (if a camera has several, the earliest is used).
    pub images: Vec<ViewImage>,
    /// `work/poses/points3d.ply`, if the poses stage wrote one.
    pub sparse: Option<PathBuf>,
    /// Frames of every training camera at each moment to triangulate (the first config
    /// `moments` of them are used; empty: no triangulation).
    pub moments: Vec<Moment>,
}

/// Which source produced `points.ply`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UsedSource {
    Onnx,
    Npy,
    Triangulated,
    Swept,
    Sparse,
    Random,
}

/// The outcome of one image pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairReport {
    pub first: String,
    pub second: String,
    /// Aligned frame of the pair's images, when point maps of several moments were used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<usize>,
    pub accepted: bool,
    /// Why it was rejected (`None` when accepted).
    pub reason: Option<String>,
    /// Scale applied to the pair's maps (`None` when no scale was found).
    pub scale: Option<f64>,
    /// Scale from the second view's rays.
    pub ray_scale: Option<f64>,
    /// Scale from the sparse points, and how many points gave it.
    pub sparse_scale: Option<f64>,
    pub sparse_matches: usize,
    /// Median reprojection error in the second camera (fraction of the map width).
    pub residual: Option<f64>,
    /// Pixels of both maps, non-finite pixels, confident finite pixels, points kept.
    pub pixels: usize,
    pub non_finite: usize,
    pub confident: usize,
    pub points: usize,
}

/// What [`run_init`] did, for the log and `stage.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InitReport {
    pub source: UsedSource,
    /// Each fallback taken, with its reason, in order.
    pub fallbacks: Vec<String>,
    pub pairs: Vec<PairReport>,
    /// Each triangulated moment (empty when triangulation did not run).
    #[serde(default)]
    pub moments: Vec<MomentReport>,
    /// Each swept moment (empty when the sweep did not run).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sweeps: Vec<sweep::SweepReport>,
    /// Static/moving split of the triangulated points (zero unless triangulated).
    #[serde(default)]
    pub statics: StaticCounts,
    /// Points before downsampling (from the source), after voxel downsampling, written.
    pub points_before: usize,
    pub points_after_voxel: usize,
    pub points_written: usize,
    /// Voxel edge used, in world units.
    pub voxel: f64,
    /// The written cloud (the pipeline records it relative to `work/init/`).
    pub output: PathBuf,
    pub seconds: f64,
}

/// Errors of the init stage (a rejected pair is not an error: see [`PairReport`]).
#[derive(Debug, thiserror::Error)]
pub enum InitError {
    #[error("invalid [init] settings: {0}")]
    Config(String),
    #[error("cannot read frame {path}: {source}; rerun the frames stage")]
    Image {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(
        "frame {path} is {got:?} but camera {camera} is calibrated for {want:?}; rerun the frames stage at the working size"
    )]
    ImageSize {
        path: PathBuf,
        camera: String,
        got: (u32, u32),
        want: (u32, u32),
    },
    #[error(transparent)]
    Onnx(#[from] OnnxError),
    #[error(transparent)]
    Npy(#[from] NpyError),
    #[error(transparent)]
    Ply(#[from] PlyError),
    #[error("cannot create {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// A training camera ready for point maps or the sweep: pinhole twin, its undistorted
/// frame, that frame's time.
pub struct View {
    pub camera: Camera,
    pub image: RgbImage,
    pub time: f64,
}

/// Run the init stage: write `<out_dir>/points.ply` and report what was done.
pub fn run_init(
    inputs: &InitInputs,
    config: &InitConfig,
    out_dir: &Path,
    progress: &dyn Progress,
) -> Result<InitReport, InitError> {
    let start = Instant::now();
    let cameras = &inputs.cameras.cameras;
    if cameras.is_empty() {
        return Err(InitError::Config(
            "no cameras given; run the poses stage first".into(),
        ));
    }
    for img in &inputs.images {
        if inputs.cameras.get(&img.camera).is_none() {
            return Err(InitError::Config(format!(
                "frame {} belongs to camera {}, which is not in the poses",
                img.path.display(),
                img.camera
            )));
        }
    }
    let sparse = match &inputs.sparse {
        Some(p) if p.is_file() => read_points_ply(p)?,
        _ => shared_types::PointCloud::default(),
    };
    let sparse_xyz = sparse
        .xyz
        .iter()
        .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect::<Vec<_>>();
    let times = inputs.images.iter().map(|i| i.time).collect::<Vec<_>>();
    let moment_times = inputs.moments.iter().map(|m| m.time);
    let all_times = times
        .iter()
        .copied()
        .chain(moment_times)
        .collect::<Vec<_>>();
    let t_range = if all_times.is_empty() {
        (0.0, 0.0)
    } else {
        (
            all_times.iter().copied().fold(f64::INFINITY, f64::min),
            all_times.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let radius = fuse::rig_radius(cameras);
    let voxel = config.voxel_size.max(0.0) * radius;

    // Auto triangulates only when the caller gave moments (library callers may not).
    let triangulate = match config.source {
        Source::Triangulate | Source::Sweep => true,
        Source::Auto => config.moments > 0 && !inputs.moments.is_empty(),
        _ => false,
    };
    let mut fallbacks = Vec::new();
    let mut fall = |msg: String| {
        tracing::warn!("point init: {msg}");
        fallbacks.push(msg);
    };
    let pointmap_source = match config.source {
        Source::Onnx => match &config.model {
            Some(m) => Some((UsedSource::Onnx, m.clone())),
            None => return Err(InitError::Config("source = \"onnx\" needs `model`".into())),
        },
        Source::Npy => match &config.pointmaps {
            Some(d) => Some((UsedSource::Npy, d.clone())),
            None => {
                return Err(InitError::Config(
                    "source = \"npy\" needs `pointmaps`".into(),
                ));
            }
        },
        Source::Auto => match (&config.model, &config.pointmaps) {
            (Some(m), _) => Some((UsedSource::Onnx, m.clone())),
            (None, Some(d)) => Some((UsedSource::Npy, d.clone())),
            (None, None) => {
                let next = if triangulate {
                    "triangulating moments"
                } else {
                    "using the sparse COLMAP points"
                };
                fall(format!(
                    "no point-map model or exported point maps configured; {next}"
                ));
                None
            }
        },
        Source::Triangulate | Source::Sweep | Source::Sparse | Source::Random => None,
    };

    let mut pairs = Vec::new();
    let mut fused: Vec<FusedPoint> = Vec::new();
    let mut used = None;
    let mut moment_reports = Vec::new();
    let mut sweeps = Vec::new();
    let mut statics = StaticCounts::default();
    let mut raw_points = None;
    // Point maps of several moments are split into static and moving points (and already
    // downsampled); one moment's are downsampled below.
    let mut split = false;
    if let Some((kind, path)) = pointmap_source {
        let sets = moment_maps::sets(kind, &path, inputs, config);
        let model = match kind {
            UsedSource::Onnx => Some(PointMapModel::load(&path, &config.model_config())?),
            _ => None,
        };
        let mut timed = Vec::new();
        for (k, set) in sets.iter().enumerate() {
            let views = load_views(&inputs.cameras, set.views, config.fit)?;
            let (mut p, pts) = pointmap_points(
                kind,
                &set.dir,
                model.as_ref(),
                &views,
                &sparse_xyz,
                config,
                progress,
            )?;
            p.iter_mut().for_each(|r| r.frame = set.frame);
            pairs.extend(p);
            if sets.len() == 1 {
                fused = pts;
            } else {
                timed.extend(moment_maps::timed(&fuse::voxel_downsample(&pts, voxel), k));
            }
        }
        if sets.len() > 1 && !timed.is_empty() {
            let (pts, counts) = statics::split_static(
                &timed,
                &sparse_extra(config, &sparse_xyz, &sparse.rgb),
                config.static_radius.max(0.0) * radius,
                // Dense maps: static points as dense as moving ones (one per voxel).
                voxel,
                voxel,
                moment_maps::clip(&sets),
            );
            tracing::info!(
                "point init: point maps of {} moments: {} static points, {} moving points",
                sets.len(),
                counts.static_points,
                counts.dynamic_points
            );
            raw_points = Some(timed.len() + counts.sparse_merged);
            statics = counts;
            fused = pts;
            split = true;
        }
        if fused.is_empty() {
            fall(format!(
                "no usable point-map pair ({} of {} rejected); using the sparse COLMAP points",
                pairs.iter().filter(|p| !p.accepted).count(),
                pairs.len()
            ));
        } else {
            used = Some(kind);
        }
    }
    // Points of several moments (swept and/or triangulated), told static or moving below.
    let chosen = &inputs.moments[..inputs.moments.len().min(config.moments)];
    let mut timed = Vec::new();
    let mut timed_source = None;
    if used.is_none() && config.source == Source::Sweep {
        let points;
        (sweeps, points) = sweep_moments(chosen, &inputs.cameras, config, progress)?;
        if points.is_empty() {
            fall(format!(
                "the plane sweep confirmed no depth at {} moments; triangulating moments",
                chosen.len()
            ));
        } else {
            timed = points;
            timed_source = Some(UsedSource::Swept);
        }
    }
    if used.is_none() && timed.is_empty() && triangulate {
        let binary = find_colmap(config.colmap.as_deref());
        match (chosen.is_empty(), binary) {
            (true, _) => {
                fall("no moments to triangulate (`[init] moments` = 0 or no frames)".into())
            }
            (false, Err(e)) => fall(format!("cannot triangulate moments: {e}")),
            (false, Ok(binary)) => {
                let work = out_dir.join("triangulate");
                std::fs::create_dir_all(&work).map_err(|source| InitError::Io {
                    path: work.clone(),
                    source,
                })?;
                let (reports, points) = moments::triangulate_moments(
                    chosen,
                    &inputs.cameras,
                    config,
                    &binary,
                    &work,
                    progress,
                )?;
                moment_reports = reports;
                if points.is_empty() {
                    fall(format!(
                        "no moment gave triangulated points ({} tried; COLMAP logs in triangulate/mNN/logs/ of the init output)",
                        chosen.len()
                    ));
                } else {
                    timed = points;
                    timed_source = Some(UsedSource::Triangulated);
                }
            }
        }
        // Wide baselines or no COLMAP: too few points to train from. The plane sweep
        // needs only the known cameras.
        if config.source == Source::Auto && timed.len() < config.min_points && !chosen.is_empty() {
            fall(format!(
                "{} triangulated points (fewer than min_points = {}); adding the plane sweep's",
                timed.len(),
                config.min_points
            ));
            let points;
            (sweeps, points) = sweep_moments(chosen, &inputs.cameras, config, progress)?;
            if !points.is_empty() {
                timed.extend(points);
                timed_source = Some(UsedSource::Swept);
            }
        }
    }
    if let Some(source) = timed_source {
        let (pts, counts) = split_moments(
            &timed,
            chosen,
            config,
            &sparse_xyz,
            &sparse.rgb,
            radius,
            voxel,
        );
        raw_points = Some(timed.len() + counts.sparse_merged);
        statics = counts;
        fused = pts;
        used = Some(source);
    } else if used.is_none() && triangulate {
        fall("no moment gave points; using the sparse COLMAP points".into());
    }
    if used.is_none() && config.source != Source::Random {
        if sparse.xyz.is_empty() {
            fall(
                "no sparse COLMAP points; using a random cloud in the cameras' common view volume"
                    .into(),
            );
        } else {
            // The solve's points carry no moment: static over the clip's known range.
            let (t0, t1) = t_range;
            fused = sparse_xyz
                .iter()
                .zip(&sparse.rgb)
                .map(|(p, c)| FusedPoint {
                    xyz: *p,
                    rgb: c.map(f32::from),
                    time: 0.5 * (t0 + t1),
                    time_span: t1 - t0,
                })
                .collect();
            used = Some(UsedSource::Sparse);
        }
    }
    let points_before = raw_points.unwrap_or(fused.len());
    let (source, downsampled) = match used {
        Some(s @ (UsedSource::Onnx | UsedSource::Npy)) if !split => {
            (s, fuse::voxel_downsample(&fused, voxel))
        }
        Some(s) => (s, fused),
        None => (
            UsedSource::Random,
            fuse::random_cloud(cameras, config.random_points, t_range, config.seed),
        ),
    };
    let mut downsampled = downsampled;
    if source != UsedSource::Random && downsampled.len() < config.min_points {
        fall(format!(
            "only {} points from {source:?} (fewer than min_points = {}); adding a random cloud of {} points",
            downsampled.len(),
            config.min_points,
            config.random_points
        ));
        downsampled.extend(fuse::random_cloud(
            cameras,
            config.random_points,
            t_range,
            config.seed,
        ));
    }
    let points_before = if source == UsedSource::Random {
        downsampled.len()
    } else {
        points_before
    };
    let points_after_voxel = downsampled.len();
    let kept = fuse::cap(downsampled, config.max_points, config.seed);
    std::fs::create_dir_all(out_dir).map_err(|source| InitError::Io {
        path: out_dir.into(),
        source,
    })?;
    let output = out_dir.join("points.ply");
    write_points_ply(&fuse::to_cloud(&kept), &output)?;
    Ok(InitReport {
        source,
        fallbacks,
        pairs,
        moments: moment_reports,
        sweeps,
        statics,
        points_before,
        points_after_voxel,
        points_written: kept.len(),
        voxel,
        output,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Read and undistort each training camera's frame among `images` (the earliest, if a
/// camera has several).
fn load_views(
    cameras: &CameraSet,
    images: &[ViewImage],
    fit: Fit,
) -> Result<Vec<(String, View)>, InitError> {
    let mut views = Vec::new();
    for cam in &cameras.cameras {
        let Some(img) = images
            .iter()
            .filter(|i| i.camera == cam.name)
            .min_by(|a, b| a.time.total_cmp(&b.time))
        else {
            tracing::warn!(
                "point init: no frame for camera {}; it is left out",
                cam.name
            );
            continue;
        };
        let (camera, image) = pinhole_view(cam, &img.path, fit)?;
        views.push((
            cam.name.clone(),
            View {
                camera,
                image,
                time: img.time,
            },
        ));
    }
    Ok(views)
}

/// Sweep every moment of `moments` ([`sweep::sweep_moment`]): each moment's report and
/// all confirmed points.
fn sweep_moments(
    moments: &[Moment],
    cameras: &CameraSet,
    config: &InitConfig,
    progress: &dyn Progress,
) -> Result<(Vec<sweep::SweepReport>, Vec<statics::TimedPoint>), InitError> {
    let options = config.sweep_options();
    progress.start(moments.len() as u64, "moments swept");
    let (mut reports, mut points) = (Vec::new(), Vec::new());
    for (k, moment) in moments.iter().enumerate() {
        progress.message(&format!(
            "moment {}/{} (frame {})",
            k + 1,
            moments.len(),
            moment.frame
        ));
        let start = Instant::now();
        let views = load_views(cameras, &moment.views, config.fit)?;
        let views: Vec<&View> = views.iter().map(|(_, v)| v).collect();
        let (pts, mut report) = sweep::sweep_moment(&views, k, moment.time, &options);
        report.frame = moment.frame;
        report.seconds = start.elapsed().as_secs_f64();
        tracing::info!(
            "point init: moment {} (frame {}) swept: {} of {} pixels matched, {} confirmed",
            k + 1,
            moment.frame,
            report.matched,
            report.pixels,
            report.points
        );
        points.extend(pts);
        reports.push(report);
        progress.advance(1);
    }
    progress.finish();
    Ok((reports, points))
}

/// Points found at several `moments` told static or moving ([`statics::split_static`]),
/// with the pose solve's sparse points as static extras.
fn split_moments(
    points: &[statics::TimedPoint],
    moments: &[Moment],
    config: &InitConfig,
    sparse_xyz: &[DVec3],
    sparse_rgb: &[[u8; 3]],
    radius: f64,
    voxel: f64,
) -> (Vec<FusedPoint>, StaticCounts) {
    let clip = (
        moments.iter().map(|m| m.time).fold(f64::INFINITY, f64::min),
        moments
            .iter()
            .map(|m| m.time)
            .fold(f64::NEG_INFINITY, f64::max),
    );
    let static_radius = config.static_radius.max(0.0) * radius;
    let (pts, counts) = statics::split_static(
        points,
        &sparse_extra(config, sparse_xyz, sparse_rgb),
        static_radius,
        static_radius,
        voxel,
        clip,
    );
    tracing::info!(
        "point init: {} static points ({} sparse merged), {} moving points",
        counts.static_points,
        counts.sparse_merged,
        counts.dynamic_points
    );
    (pts, counts)
}

/// The pose solve's sparse points as static extras of a static/moving split, when
/// `merge_sparse` is set.
fn sparse_extra(config: &InitConfig, xyz: &[DVec3], rgb: &[[u8; 3]]) -> Vec<(DVec3, [f32; 3])> {
    if !config.merge_sparse {
        return Vec::new();
    }
    xyz.iter()
        .zip(rgb)
        .map(|(p, c)| (*p, c.map(f32::from)))
        .collect()
}

/// A frame of `cam` read from `path` (checked against the calibrated size), undistorted
/// to the camera's pinhole twin when it has a lens; with that pinhole camera.
pub(crate) fn pinhole_view(
    cam: &Camera,
    path: &Path,
    fit: Fit,
) -> Result<(Camera, RgbImage), InitError> {
    let rgb = image::open(path)
        .map_err(|source| InitError::Image {
            path: path.into(),
            source,
        })?
        .to_rgb8();
    let want = (cam.intrinsics.width, cam.intrinsics.height);
    if rgb.dimensions() != want {
        return Err(InitError::ImageSize {
            path: path.into(),
            camera: cam.name.clone(),
            got: rgb.dimensions(),
            want,
        });
    }
    if cam.distortion.is_none() {
        return Ok((cam.clone(), rgb));
    }
    let map = UndistortMap::new(cam, fit);
    let out = map
        .apply(&rgb)
        .map_err(|e| InitError::Config(format!("undistorting {}: {e}", path.display())))?;
    Ok((map.pinhole().clone(), out))
}

/// The pairs to process, as indices into `views`.
fn choose_pairs(
    kind: UsedSource,
    dir: &Path,
    views: &[(String, View)],
    config: &InitConfig,
) -> Result<Vec<(usize, usize)>, InitError> {
    let index = |name: &str| -> Result<usize, InitError> {
        views.iter().position(|(n, _)| n == name).ok_or_else(|| {
            InitError::Config(format!(
                "pair camera {name} has no frame or is not a training camera"
            ))
        })
    };
    Ok(match &config.pairs {
        Pairs::List(list) => {
            let mut out = Vec::new();
            for [a, b] in list {
                let (i, j) = (index(a)?, index(b)?);
                if i == j {
                    return Err(InitError::Config(format!(
                        "pair {a}/{b} uses one camera twice"
                    )));
                }
                out.push((i, j));
            }
            out
        }
        Pairs::Keyword(PairsKeyword::All) => {
            let n = views.len();
            let all = (0..n).flat_map(|i| (0..n).map(move |j| (i, j)));
            match kind {
                UsedSource::Npy => all
                    .filter(|&(i, j)| i != j && npy::has_pair(dir, &views[i].0, &views[j].0))
                    .collect(),
                _ => all.filter(|&(i, j)| i < j).collect(),
            }
        }
    })
}

/// Run/read every pair, align it, and return the reports and the fused (not downsampled)
/// points of the accepted pairs.
fn pointmap_points(
    kind: UsedSource,
    path: &Path,
    model: Option<&PointMapModel>,
    views: &[(String, View)],
    sparse: &[DVec3],
    config: &InitConfig,
    progress: &dyn Progress,
) -> Result<(Vec<PairReport>, Vec<FusedPoint>), InitError> {
    if model.is_none() && !path.is_dir() {
        return Err(InitError::Npy(NpyError::Io {
            path: path.into(),
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "point-map directory not found",
            ),
        }));
    }
    let pairs = choose_pairs(kind, path, views, config)?;
    progress.start(pairs.len() as u64, "pairs");
    let mut reports = Vec::new();
    let mut points = Vec::new();
    for (i, j) in pairs {
        let ((na, a), (nb, b)) = (&views[i], &views[j]);
        progress.message(&format!("{na}/{nb}"));
        let maps = match model {
            Some(m) => Some(m.run(&a.image, &b.image)?),
            None => match npy::read_pair(path, na, nb, &config.output_names) {
                Ok(m) => Some(m),
                Err(NpyError::MissingPair { .. }) => None,
                Err(e) => return Err(e.into()),
            },
        };
        let (report, pts) = match maps {
            Some(maps) => align_pair(na, a, nb, b, &maps, sparse, config),
            None => (
                rejected(na, nb, "no exported point maps for this pair".into()),
                vec![],
            ),
        };
        if let Some(r) = &report.reason {
            tracing::warn!("point init: pair {na}/{nb} rejected: {r}");
        } else {
            tracing::info!(
                "point init: pair {na}/{nb}: scale {:.4}, {} points",
                report.scale.unwrap_or(f64::NAN),
                report.points
            );
        }
        reports.push(report);
        points.extend(pts);
        progress.advance(1);
    }
    progress.finish();
    Ok((reports, points))
}

fn rejected(first: &str, second: &str, reason: String) -> PairReport {
    PairReport {
        first: first.into(),
        second: second.into(),
        frame: None,
        accepted: false,
        reason: Some(reason),
        scale: None,
        ray_scale: None,
        sparse_scale: None,
        sparse_matches: 0,
        residual: None,
        pixels: 0,
        non_finite: 0,
        confident: 0,
        points: 0,
    }
}

/// Which pixels are finite and confident; and how many are not finite.
fn valid_mask(map: &PointMap, min_confidence: f32) -> (Vec<bool>, usize) {
    let mut non_finite = 0;
    let mask = (0..map.points.len())
        .map(|i| {
            let p = map.points[i];
            let c = map.confidence.as_ref().map_or(f32::INFINITY, |c| c[i]);
            let finite = p.iter().all(|v| v.is_finite()) && !c.is_nan();
            if !finite {
                non_finite += 1;
            }
            finite && c >= min_confidence
        })
        .collect();
    (mask, non_finite)
}

/// Align one pair and turn its confident pixels into world points.
fn align_pair(
    na: &str,
    a: &View,
    nb: &str,
    b: &View,
    maps: &PairMaps,
    sparse: &[DVec3],
    config: &InitConfig,
) -> (PairReport, Vec<FusedPoint>) {
    let (m1, m2) = (&maps.first, &maps.second);
    let (mut v1, nf1) = valid_mask(m1, config.min_confidence);
    let (v2, nf2) = valid_mask(m2, config.min_confidence);
    for (v, p) in v1.iter_mut().zip(&m1.points) {
        *v &= p[2] > 0.0;
    }
    let mut report = rejected(na, nb, String::new());
    report.pixels = m1.points.len() + m2.points.len();
    report.non_finite = nf1 + nf2;
    report.confident = v1.iter().chain(&v2).filter(|v| **v).count();
    let reject = |mut r: PairReport, reason: String| {
        r.reason = Some(reason);
        (r, vec![])
    };
    if report.non_finite as f64 > config.max_non_finite * report.pixels as f64 {
        let msg = format!(
            "{} of {} pixels are not finite (NaN/inf)",
            report.non_finite, report.pixels
        );
        return reject(report, msg);
    }
    let scaled = |v: &View, m: &PointMap| Camera {
        intrinsics: v
            .camera
            .intrinsics
            .scaled_to(m.width as u32, m.height as u32),
        ..v.camera.clone()
    };
    let (ca, cb) = (scaled(a, m1), scaled(b, m2));
    let rel = Relative::between(&ca, &cb);
    let ray = ray_scale(&cb, &rel, m2, &v2);
    let sp = sparse_scale(&ca, m1, &v1, sparse, config.min_sparse_matches);
    report.ray_scale = ray.map(|r| r.scale);
    report.residual = ray.map(|r| r.residual);
    report.sparse_scale = sp.map(|s| s.0);
    report.sparse_matches = sp.map_or(0, |s| s.1);
    let scale = match (ray, sp) {
        (Some(r), _) if r.residual > config.max_residual => {
            let msg = format!(
                "second view does not fit its camera: median reprojection error {:.2}% of the width (limit {:.2}%)",
                100.0 * r.residual,
                100.0 * config.max_residual
            );
            return reject(report, msg);
        }
        (Some(r), Some((s, _))) => {
            if (r.scale / s).ln().abs() > (1.0 + config.scale_tolerance).ln() {
                let msg = format!(
                    "scale from rays {:.4} disagrees with scale from sparse points {:.4}",
                    r.scale, s
                );
                return reject(report, msg);
            }
            r.scale
        }
        (Some(r), None) => r.scale,
        (None, Some((s, _))) => s,
        (None, None) => {
            return reject(
                report,
                "scale not determined (no baseline or too few confident pixels, and no sparse points)".into(),
            );
        }
    };
    report.scale = Some(scale);
    let mut pts = Vec::new();
    for (i, p) in m1.points.iter().enumerate() {
        if v1[i] {
            let pc = pixel_centre(i, m1.width);
            pts.push(FusedPoint {
                xyz: unproject(&ca, pc, scale * p[2] as f64),
                rgb: colour_at(&a.image, pc, m1.width, m1.height),
                time: a.time,
                time_span: 0.0,
            });
        }
    }
    let max_px = config.max_residual * m2.width as f64;
    for (i, p) in m2.points.iter().enumerate() {
        if !v2[i] {
            continue;
        }
        let x = scale * (rel.rotation * DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            + rel.translation;
        if x.z <= 1e-9 {
            continue;
        }
        let pc = pixel_centre(i, m2.width);
        let proj = cb
            .intrinsics
            .to_pixels(glam::DVec2::new(x.x / x.z, x.y / x.z));
        if (proj - pc).length() > max_px {
            continue;
        }
        pts.push(FusedPoint {
            xyz: unproject(&cb, pc, x.z),
            rgb: colour_at(&b.image, pc, m2.width, m2.height),
            time: b.time,
            time_span: 0.0,
        });
    }
    report.accepted = true;
    report.reason = None;
    report.points = pts.len();
    (report, pts)
}
