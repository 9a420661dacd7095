//! The `poses` stage: from the first aligned frame of each video camera plus the stills,
//! solve the rig with COLMAP (or take an imported calibration), normalise the scene, and
//! write `work/poses/cameras.json` + `work/poses/points3d.ply`.
//!
//! Normalisation: `x_norm = scale · (x_world − centre)` with `centre` the mean of the video
//! camera centres and `scale` chosen so the video cameras sit at mean distance
//! [`PosesConfig::radius`] (default 1) from it. Poses and points in the outputs are in the
//! normalised frame; `normalisation` in `cameras.json` maps back to COLMAP's (or the
//! imported calibration's) frame.
//!
//! Cameras in `cameras.json` keep the lens distortion that was solved; turning frames and
//! cameras into pinhole ones happens once, through [`crate::undistort`].

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};
use shared_types::{Camera, CameraSet, Progress, WorldToCamera};

use crate::colmap::ColmapModel;
use crate::colmap_runner::diagnose::Diagnosis;
use crate::colmap_runner::quality::{self, Degeneracy, QualityLimits};
use crate::colmap_runner::{
    ColmapConfig, ColmapError, ColmapTimings, MatchGraph, StillsCameras, VideoCameras, Workspace,
    find_colmap,
};
use crate::convert::{self, ConvertError};

/// Settings of the poses stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PosesConfig {
    pub colmap: ColmapConfig,
    /// Fewer stills than this is refused before COLMAP runs.
    pub min_stills: usize,
    /// Mean distance of the video cameras from the scene centre after normalisation.
    pub radius: f64,
}

impl Default for PosesConfig {
    fn default() -> Self {
        Self {
            colmap: ColmapConfig::default(),
            min_stills: 4,
            radius: 1.0,
        }
    }
}

/// What the poses stage is given.
#[derive(Clone, Debug)]
pub struct PosesInputs {
    /// (camera name, its first aligned frame), e.g. `("cam0", "work/frames/cam0/000000.png")`.
    pub video_frames: Vec<(String, PathBuf)>,
    /// Extra photos of the scene (`stills/`).
    pub stills: Vec<PathBuf>,
    /// Size the engine will see the video frames at; `None`: the frames' own size.
    pub working_size: Option<(u32, u32)>,
    pub config: PosesConfig,
}

/// `x_norm = scale · (x_world − centre)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    pub centre: [f64; 3],
    pub scale: f64,
}

impl Normalisation {
    pub const IDENTITY: Self = Self {
        centre: [0.0; 3],
        scale: 1.0,
    };

    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.scale * (p - DVec3::from_array(self.centre))
    }

    /// The same camera in the normalised frame: `t' = scale · (R·centre + t)`.
    pub fn apply_to_pose(&self, w2c: &WorldToCamera) -> WorldToCamera {
        let r = w2c.rotation();
        WorldToCamera::from_parts(
            r,
            self.scale * (r * DVec3::from_array(self.centre) + w2c.translation()),
        )
    }
}

/// Where the poses came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PoseSource {
    /// Solved by COLMAP; the model is in `model_dir` (relative to `work/poses/`).
    Colmap {
        model_dir: String,
        registered_images: usize,
        timings: ColmapTimings,
    },
    /// Imported from a calibration file.
    Import { path: PathBuf },
}

/// `work/poses/cameras.json`: a [`CameraSet`] (read it as one: extra fields are ignored)
/// plus the normalisation, where it came from and the sparse points file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PosesFile {
    #[serde(flatten)]
    pub set: CameraSet,
    pub normalisation: Normalisation,
    pub source: PoseSource,
    /// `points3d.ply` beside this file (normalised frame), if there are points.
    pub points_file: Option<String>,
    pub num_points: usize,
}

impl PosesFile {
    /// Read `work/poses/cameras.json`.
    pub fn read(path: &Path) -> Result<Self, PosesError> {
        let io = |source| PosesError::Io {
            path: path.to_path_buf(),
            source,
        };
        let text = std::fs::read_to_string(path).map_err(io)?;
        serde_json::from_str(&text).map_err(|e| {
            io(std::io::Error::other(format!(
                "not a poses cameras.json: {e}"
            )))
        })
    }
}

/// One sparse point, normalised frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparsePoint {
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
}

/// What [`solve`] produced.
#[derive(Clone, Debug)]
pub struct PosesOutput {
    pub file: PosesFile,
    pub points: Vec<SparsePoint>,
    pub cameras_json: PathBuf,
    pub points_ply: Option<PathBuf>,
}

/// Errors of the poses stage.
#[derive(Debug, thiserror::Error)]
pub enum PosesError {
    #[error(
        "no video frames were given to the poses stage (is work/frames/ empty? run the frames stage first)"
    )]
    NoVideoFrames,
    #[error("video camera name {0:?} appears twice")]
    DuplicateCamera(String),
    #[error(
        "only {got} stills in stills/, at least {min} are needed to connect the video cameras: take \
         more photos (8 recommended) walking in an arc between the cameras, or lower poses.min_stills"
    )]
    TooFewStills { got: usize, min: usize },
    #[error("cannot read image {path}: {reason}")]
    ImageUnreadable { path: PathBuf, reason: String },
    #[error(
        "image {path} is blank (pixel values vary by only {std_dev:.2} levels): COLMAP cannot find \
         features in it. Check the lens cap, exposure and that the right file was extracted"
    )]
    BlankImage { path: PathBuf, std_dev: f64 },
    #[error(
        "the stills share one camera but differ in size ({sizes}): set poses.colmap.stills_cameras = \
         \"per_image\" (different phones or zoom), or resize them to one size"
    )]
    StillSizesDiffer { sizes: String },
    #[error(
        "the video cameras share one camera (poses.colmap.video_cameras = \"shared\") but their \
         frames differ in size ({sizes}): use \"separate\" or \"auto\""
    )]
    VideoSizesDiffer { sizes: String },
    #[error(
        "COLMAP's solve looks degenerate in all {} attempts, so no poses were written:\n{}\n\
         This happens when the scene repeats itself (tiled floors, wallpaper, identical \
         objects) or the images overlap little. What to try: give the lens's focal length \
         (poses.colmap.video_focal_px) or import a calibration; add stills between the video \
         cameras; add non-repeating texture (posters, newspaper).\n{diagnosis}",
        attempts.len(),
        attempts.iter().enumerate().map(|(i, a)| format!("  attempt {}: {a}", i + 1)).collect::<Vec<_>>().join("\n")
    )]
    Degenerate {
        /// Per mapper attempt, what was wrong.
        attempts: Vec<String>,
        diagnosis: Diagnosis,
    },
    #[error("{0}")]
    Colmap(#[from] ColmapError),
    #[error(
        "COLMAP found no model: no good initial image pair (no two images share enough matched \
         features seen from different positions).\n{diagnosis}"
    )]
    NoInitialPair { diagnosis: Diagnosis },
    #[error("COLMAP did not register video camera(s) {}.\n{diagnosis}", missing.join(", "))]
    VideoNotRegistered {
        missing: Vec<String>,
        diagnosis: Diagnosis,
    },
    #[error(
        "COLMAP split the images into {} separate models and the video cameras are not all in one \
         ({}).\n{diagnosis}", groups.len(), groups.iter().enumerate().map(|(i, g)| format!("model {i}: {}", g.join(", "))).collect::<Vec<_>>().join("; ")
    )]
    SplitModels {
        groups: Vec<Vec<String>>,
        diagnosis: Diagnosis,
    },
    #[error(transparent)]
    Convert(#[from] ConvertError),
    #[error(
        "camera {camera} was calibrated at {}×{} but the working size is {}×{}: a different aspect \
         ratio means a crop, which cannot be handled by scaling; calibrate at the recording's \
         aspect ratio or set the working size to match",
        calibrated.0, calibrated.1, working.0, working.1
    )]
    AspectMismatch {
        camera: String,
        calibrated: (u32, u32),
        working: (u32, u32),
    },
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Pixel-value standard deviation (0–255) under which an image counts as blank.
pub const BLANK_STD_DEV: f64 = 1.0;

/// Run the poses stage with COLMAP: check inputs, build the workspace in
/// `out_dir/colmap/`, solve, check that every video camera registered in one model, and
/// write `out_dir/cameras.json` and `out_dir/points3d.ply`. On any error, neither file
/// exists afterwards (a previous run's are removed first).
pub fn solve(
    inputs: &PosesInputs,
    out_dir: &Path,
    progress: &dyn Progress,
) -> Result<PosesOutput, PosesError> {
    let cameras_json = out_dir.join("cameras.json");
    let points_ply = out_dir.join("points3d.ply");
    for stale in [&cameras_json, &points_ply] {
        if stale.exists() {
            std::fs::remove_file(stale).map_err(|source| PosesError::Io {
                path: stale.clone(),
                source,
            })?;
        }
    }
    let video_sizes = check_inputs(inputs)?;
    let config = &inputs.config;
    let binary = find_colmap(config.colmap.binary.as_deref())?;
    let ws_root = out_dir.join("colmap");
    let video_cameras = config.colmap.video_cameras.resolve(video_sizes.len() <= 1);
    let ws = Workspace::create(
        &ws_root,
        &inputs.video_frames,
        &inputs.stills,
        config.colmap.stills_cameras,
        video_cameras,
    )?;
    let attempts = config.colmap.max_attempts.max(1);
    progress.start(3, "COLMAP steps");
    let mut timings = ws.extract_and_match(&binary, &config.colmap, progress)?;
    let video: Vec<(&str, &str)> = ws
        .images
        .iter()
        .filter_map(|i| {
            i.video_camera
                .as_deref()
                .map(|c| (c, i.colmap_name.as_str()))
        })
        .collect();
    let video_names: Vec<&str> = video.iter().map(|v| v.1).collect();
    let all_names: Vec<&str> = ws.images.iter().map(|i| i.colmap_name.as_str()).collect();
    let prior = config
        .colmap
        .video_focal_px
        .map(|f| (f, video_names.as_slice()));
    let mut problems: Vec<String> = Vec::new();
    let mut last_error = None;
    let t0 = std::time::Instant::now();
    for attempt in 0..attempts {
        if attempt > 0 {
            progress.message(&format!(
                "COLMAP solve attempt {attempt} was rejected ({}); retrying with seed {} and \
                 stricter settings",
                problems.last().map(String::as_str).unwrap_or(""),
                config.colmap.random_seed.wrapping_add(attempt)
            ));
        }
        let mapped = ws.map(&binary, &config.colmap, attempt, progress);
        if attempt == 0 {
            progress.advance(1);
        }
        timings.mapper_attempts = attempt + 1;
        timings.mapping_s = t0.elapsed().as_secs_f64();
        let models = match mapped {
            Ok(models) => models,
            Err(ColmapError::StepFailed { no_model: true, .. }) => Vec::new(),
            Err(e) => return Err(e.into()),
        };
        let graph = MatchGraph::read(&ws.database()).unwrap_or_default();
        let diagnosis = Diagnosis::new(&ws, &graph, &models);
        if models.is_empty() {
            problems.push("no model (no good initial image pair)".into());
            last_error = Some(PosesError::NoInitialPair { diagnosis });
            continue;
        }
        let model_index = match pick_model(&models, &video, diagnosis.clone()) {
            Ok(i) => i,
            Err(e) => {
                problems.push(match &e {
                    PosesError::VideoNotRegistered { missing, .. } => {
                        format!("video camera(s) {} not registered", missing.join(", "))
                    }
                    _ => "the video cameras are split across models".into(),
                });
                last_error = Some(e);
                continue;
            }
        };
        let (model_dir, model) = &models[model_index];
        let found = quality::assess(model, &all_names, prior, &QualityLimits::default());
        if !found.is_empty() {
            problems.push(
                found
                    .iter()
                    .map(Degeneracy::to_string)
                    .collect::<Vec<_>>()
                    .join("; "),
            );
            last_error = Some(PosesError::Degenerate {
                attempts: problems.clone(),
                diagnosis,
            });
            continue;
        }
        progress.finish();
        let (cameras, points) = cameras_from_model(model, &video, inputs.working_size)?;
        let rel_model = model_dir
            .strip_prefix(out_dir)
            .unwrap_or(model_dir)
            .to_string_lossy()
            .into_owned();
        let source = PoseSource::Colmap {
            model_dir: rel_model,
            registered_images: model.images.len(),
            timings,
        };
        return write_outputs(out_dir, cameras, points, source, config.radius);
    }
    progress.finish();
    Err(match last_error {
        Some(PosesError::Degenerate { diagnosis, .. }) => PosesError::Degenerate {
            attempts: problems,
            diagnosis,
        },
        Some(e) => e,
        None => PosesError::Degenerate {
            attempts: problems,
            diagnosis: Diagnosis::new(&ws, &MatchGraph::default(), &[]),
        },
    })
}

/// The model holding every video camera (the largest such); otherwise the error that says
/// which video cameras did not register, or how they were split across models.
pub fn pick_model(
    models: &[(PathBuf, ColmapModel)],
    video: &[(&str, &str)],
    diagnosis: Diagnosis,
) -> Result<usize, PosesError> {
    if let Some(i) = models
        .iter()
        .position(|(_, m)| video.iter().all(|(_, n)| m.image_by_name(n).is_some()))
    {
        return Ok(i);
    }
    let model_of = |colmap_name: &str| {
        models
            .iter()
            .position(|(_, m)| m.image_by_name(colmap_name).is_some())
    };
    let missing: Vec<String> = video
        .iter()
        .filter(|(_, n)| model_of(n).is_none())
        .map(|(c, _)| c.to_string())
        .collect();
    if !missing.is_empty() {
        return Err(PosesError::VideoNotRegistered { missing, diagnosis });
    }
    let groups = (0..models.len())
        .map(|m| {
            video
                .iter()
                .filter(|(_, n)| model_of(n) == Some(m))
                .map(|(c, _)| c.to_string())
                .collect::<Vec<_>>()
        })
        .filter(|g| !g.is_empty())
        .collect();
    Err(PosesError::SplitModels { groups, diagnosis })
}

/// Normalise and write an imported (or otherwise known) camera set as the poses stage's
/// output, with no sparse points; intrinsics scaled to `working_size` when given.
pub fn write_imported(
    set: &CameraSet,
    from: &Path,
    out_dir: &Path,
    working_size: Option<(u32, u32)>,
    radius: f64,
) -> Result<PosesOutput, PosesError> {
    let stale = out_dir.join("points3d.ply");
    if stale.exists() {
        std::fs::remove_file(&stale).map_err(|source| PosesError::Io {
            path: stale,
            source,
        })?;
    }
    let mut cameras = set.cameras.clone();
    for c in &mut cameras {
        c.intrinsics = scale_intrinsics(&c.name, &c.intrinsics, working_size)?;
    }
    let source = PoseSource::Import {
        path: from.to_path_buf(),
    };
    write_outputs(out_dir, cameras, Vec::new(), source, radius)
}

/// Intrinsics for the working size; refuses a change of aspect ratio (a crop, not a resize).
pub fn scale_intrinsics(
    camera: &str,
    intr: &shared_types::Intrinsics,
    working_size: Option<(u32, u32)>,
) -> Result<shared_types::Intrinsics, PosesError> {
    let Some((w, h)) = working_size else {
        return Ok(*intr);
    };
    let (sx, sy) = (w as f64 / intr.width as f64, h as f64 / intr.height as f64);
    if (sx / sy - 1.0).abs() > 0.01 {
        return Err(PosesError::AspectMismatch {
            camera: camera.to_string(),
            calibrated: (intr.width, intr.height),
            working: (w, h),
        });
    }
    Ok(intr.scaled_to(w, h))
}

/// Engine cameras for the video cameras (names, COLMAP image names) of a COLMAP model, with
/// intrinsics scaled to `working_size`, plus the model's points (COLMAP's frame).
pub fn cameras_from_model(
    model: &ColmapModel,
    video: &[(&str, &str)],
    working_size: Option<(u32, u32)>,
) -> Result<(Vec<Camera>, Vec<SparsePoint>), PosesError> {
    let mut cameras = Vec::new();
    for &(cam, colmap_name) in video {
        let image =
            model
                .image_by_name(colmap_name)
                .ok_or_else(|| PosesError::VideoNotRegistered {
                    missing: vec![cam.to_string()],
                    diagnosis: Diagnosis {
                        images: Vec::new(),
                        num_models: 1,
                    },
                })?;
        let colmap_cam = model.cameras.get(&image.camera_id).ok_or_else(|| {
            PosesError::Colmap(ColmapError::Model(crate::colmap::ModelError::Malformed {
                path: PathBuf::from("images"),
                what: format!(
                    "image {} refers to missing camera {}",
                    image.name, image.camera_id
                ),
            }))
        })?;
        let (intrinsics, distortion) = convert::to_engine(colmap_cam)?;
        let intrinsics = scale_intrinsics(cam, &intrinsics, working_size)?;
        cameras.push(Camera {
            name: cam.to_string(),
            intrinsics,
            distortion,
            world_to_camera: WorldToCamera::from_parts(
                orthonormalise(image.rotation()),
                image.translation(),
            ),
        });
    }
    let points = model
        .points3d
        .values()
        .map(|p| SparsePoint {
            xyz: p.xyz,
            rgb: p.rgb,
        })
        .collect();
    Ok((cameras, points))
}

/// Centre on the mean video-camera centre and scale so the cameras sit at mean distance
/// `radius`. With one camera (or all at one spot) the points' median distance is used;
/// with neither, the scale stays 1.
pub fn normalisation_for(cameras: &[Camera], points: &[SparsePoint], radius: f64) -> Normalisation {
    let centres: Vec<DVec3> = cameras.iter().map(|c| c.world_to_camera.centre()).collect();
    if centres.is_empty() {
        return Normalisation::IDENTITY;
    }
    let centre = centres.iter().copied().sum::<DVec3>() / centres.len() as f64;
    let mut spread =
        centres.iter().map(|c| (*c - centre).length()).sum::<f64>() / centres.len() as f64;
    if spread < 1e-12 {
        let mut d: Vec<f64> = points
            .iter()
            .map(|p| (DVec3::from_array(p.xyz) - centre).length())
            .collect();
        d.sort_by(f64::total_cmp);
        spread = d.get(d.len() / 2).copied().unwrap_or(0.0);
    }
    let scale = if spread > 1e-12 && radius > 0.0 {
        radius / spread
    } else {
        1.0
    };
    Normalisation {
        centre: centre.to_array(),
        scale,
    }
}

fn write_outputs(
    out_dir: &Path,
    cameras: Vec<Camera>,
    points: Vec<SparsePoint>,
    source: PoseSource,
    radius: f64,
) -> Result<PosesOutput, PosesError> {
    let norm = normalisation_for(&cameras, &points, radius);
    let cameras: Vec<Camera> = cameras
        .into_iter()
        .map(|c| Camera {
            world_to_camera: norm.apply_to_pose(&c.world_to_camera),
            ..c
        })
        .collect();
    let points: Vec<SparsePoint> = points
        .into_iter()
        .map(|p| SparsePoint {
            xyz: norm.apply(DVec3::from_array(p.xyz)).to_array(),
            ..p
        })
        .collect();
    std::fs::create_dir_all(out_dir).map_err(|source| PosesError::Io {
        path: out_dir.to_path_buf(),
        source,
    })?;
    let points_ply = (!points.is_empty()).then(|| out_dir.join("points3d.ply"));
    if let Some(ply) = &points_ply {
        crate::colmap::write_atomically(ply, &points_to_ply(&points)).map_err(|source| {
            PosesError::Io {
                path: ply.clone(),
                source,
            }
        })?;
    }
    let file = PosesFile {
        set: CameraSet::new(cameras),
        normalisation: norm,
        source,
        points_file: points_ply.as_ref().map(|_| "points3d.ply".to_string()),
        num_points: points.len(),
    };
    let cameras_json = out_dir.join("cameras.json");
    let text = serde_json::to_string_pretty(&file).map_err(|e| PosesError::Io {
        path: cameras_json.clone(),
        source: std::io::Error::other(e),
    })?;
    crate::colmap::write_atomically(&cameras_json, text.as_bytes()).map_err(|source| {
        PosesError::Io {
            path: cameras_json.clone(),
            source,
        }
    })?;
    Ok(PosesOutput {
        file,
        points,
        cameras_json,
        points_ply,
    })
}

/// Binary little-endian PLY: `x y z` (float) and `red green blue` (uchar) per vertex.
pub fn points_to_ply(points: &[SparsePoint]) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment 4C4D sparse points, normalised frame\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    );
    let mut out = header.into_bytes();
    for p in points {
        for v in p.xyz {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
        out.extend_from_slice(&p.rgb);
    }
    out
}

/// The nearest rotation (COLMAP's normalised quaternions are orthonormal to ~1e-16 already;
/// this guards imported matrices too).
pub fn orthonormalise(r: DMat3) -> DMat3 {
    let m = nalgebra::Matrix3::from_fn(|i, j| r.col(j)[i]);
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return r;
    };
    let mut q = u * vt;
    if q.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        q = u2 * vt;
    }
    crate::similarity::to_dmat3(&q)
}

/// Checks the inputs; returns the distinct sizes of the video frames.
fn check_inputs(inputs: &PosesInputs) -> Result<BTreeSet<(u32, u32)>, PosesError> {
    if inputs.video_frames.is_empty() {
        return Err(PosesError::NoVideoFrames);
    }
    let mut seen = BTreeSet::new();
    for (name, _) in &inputs.video_frames {
        if !seen.insert(name.as_str()) {
            return Err(PosesError::DuplicateCamera(name.clone()));
        }
    }
    if inputs.stills.len() < inputs.config.min_stills {
        return Err(PosesError::TooFewStills {
            got: inputs.stills.len(),
            min: inputs.config.min_stills,
        });
    }
    let mut still_sizes = BTreeSet::new();
    let mut video_sizes = BTreeSet::new();
    let all = inputs
        .video_frames
        .iter()
        .map(|(_, p)| (p, false))
        .chain(inputs.stills.iter().map(|p| (p, true)));
    for (path, still) in all {
        let img = image::open(path)
            .map_err(|e| PosesError::ImageUnreadable {
                path: path.clone(),
                reason: e.to_string(),
            })?
            .into_luma8();
        let n = img.as_raw().len().max(1) as f64;
        let mean = img.as_raw().iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = img
            .as_raw()
            .iter()
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / n;
        if var.sqrt() < BLANK_STD_DEV {
            return Err(PosesError::BlankImage {
                path: path.clone(),
                std_dev: var.sqrt(),
            });
        }
        if still {
            still_sizes.insert(img.dimensions());
        } else {
            video_sizes.insert(img.dimensions());
        }
    }
    if inputs.config.colmap.video_cameras == VideoCameras::Shared && video_sizes.len() > 1 {
        let sizes: Vec<String> = video_sizes
            .iter()
            .map(|(w, h)| format!("{w}×{h}"))
            .collect();
        return Err(PosesError::VideoSizesDiffer {
            sizes: sizes.join(", "),
        });
    }
    if inputs.config.colmap.stills_cameras == StillsCameras::Shared && still_sizes.len() > 1 {
        let sizes: Vec<String> = still_sizes
            .iter()
            .map(|(w, h)| format!("{w}×{h}"))
            .collect();
        return Err(PosesError::StillSizesDiffer {
            sizes: sizes.join(", "),
        });
    }
    Ok(video_sizes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colmap::ColmapImage;

    fn model_with(names: &[&str]) -> (PathBuf, ColmapModel) {
        let mut m = ColmapModel::default();
        for (i, n) in names.iter().enumerate() {
            m.images.insert(
                i as u32 + 1,
                ColmapImage {
                    id: i as u32 + 1,
                    qvec: [1.0, 0.0, 0.0, 0.0],
                    tvec: [0.0; 3],
                    camera_id: 1,
                    name: n.to_string(),
                    points2d: Vec::new(),
                },
            );
        }
        (PathBuf::from("sparse/x"), m)
    }

    #[test]
    fn points_ply_has_a_header_and_15_bytes_per_point() {
        let pts = [
            SparsePoint {
                xyz: [1.0, -2.0, 0.5],
                rgb: [255, 0, 7],
            },
            SparsePoint {
                xyz: [0.0, 0.0, 0.0],
                rgb: [1, 2, 3],
            },
        ];
        let ply = points_to_ply(&pts);
        let text = String::from_utf8_lossy(&ply);
        let end = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert!(text.starts_with("ply\nformat binary_little_endian 1.0\n"));
        assert!(text[..end].contains("element vertex 2\n"));
        assert_eq!(ply.len() - end, 2 * 15);
        assert_eq!(
            f32::from_le_bytes(ply[end + 4..end + 8].try_into().unwrap()),
            -2.0
        );
        assert_eq!(&ply[end + 12..end + 15], &[255, 0, 7]);
    }

    #[test]
    fn poses_file_round_trips_and_reads_as_a_camera_set() {
        let dir = std::env::temp_dir().join(format!("calib_poses_file_{}", std::process::id()));
        let cam = Camera {
            name: "cam0".into(),
            intrinsics: shared_types::Intrinsics::from_hfov(64, 48, 60.0),
            distortion: Default::default(),
            world_to_camera: WorldToCamera::IDENTITY,
        };
        let other = Camera {
            name: "cam1".into(),
            world_to_camera: WorldToCamera::from_parts(
                glam::DMat3::IDENTITY,
                glam::DVec3::new(-2.0, 0.0, 0.0),
            ),
            ..cam.clone()
        };
        let out = write_outputs(
            &dir,
            vec![cam, other],
            vec![SparsePoint {
                xyz: [1.0, 0.0, 3.0],
                rgb: [9, 9, 9],
            }],
            PoseSource::Import {
                path: "x.json".into(),
            },
            1.0,
        )
        .unwrap();
        let back = PosesFile::read(&out.cameras_json).unwrap();
        assert_eq!(back.normalisation, out.file.normalisation);
        assert_eq!(back.num_points, 1);
        let set: CameraSet =
            serde_json::from_str(&std::fs::read_to_string(&out.cameras_json).unwrap()).unwrap();
        assert_eq!(set.cameras.len(), 2);
        assert!(PosesFile::read(&dir.join("missing.json")).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn config_reads_from_toml_with_defaults() {
        let text = "min_stills = 6\n[colmap]\ncamera_model = \"OPENCV_FISHEYE\"\nvideo_cameras = \"shared\"\n";
        let c: PosesConfig = toml::from_str(text).unwrap();
        assert_eq!(c.min_stills, 6);
        assert_eq!(c.radius, 1.0);
        assert_eq!(
            c.colmap.camera_model,
            crate::colmap::CameraModel::OpencvFisheye
        );
        assert_eq!(c.colmap.video_cameras, VideoCameras::Shared);
        assert_eq!(c.colmap.stills_cameras, StillsCameras::Shared);
        assert!(toml::from_str::<PosesConfig>("min_still = 3").is_err());
        assert!(toml::from_str::<PosesConfig>("[colmap]\ncamera_model = \"BROWN\"").is_err());
    }

    #[test]
    fn picks_the_model_with_all_video_cameras_or_explains_why_none() {
        let video = [
            ("cam0", "v/0.png"),
            ("cam1", "v/1.png"),
            ("cam2", "v/2.png"),
        ];
        let diag = || Diagnosis {
            images: Vec::new(),
            num_models: 2,
        };
        let models = [
            model_with(&["s/a.png", "v/0.png"]),
            model_with(&["v/0.png", "v/1.png", "v/2.png"]),
        ];
        assert_eq!(pick_model(&models, &video, diag()).unwrap(), 1);

        let split = [
            model_with(&["v/0.png", "v/1.png", "s/a.png"]),
            model_with(&["v/2.png", "s/b.png"]),
        ];
        match pick_model(&split, &video, diag()).unwrap_err() {
            PosesError::SplitModels { groups, .. } => {
                assert_eq!(groups, [vec!["cam0", "cam1"], vec!["cam2"]]);
            }
            e => panic!("{e}"),
        }
        let e = pick_model(&split, &video, diag()).unwrap_err().to_string();
        assert!(e.contains("model 0: cam0, cam1; model 1: cam2"), "{e}");

        let missing = [model_with(&["v/0.png", "v/2.png"])];
        match pick_model(&missing, &video, diag()).unwrap_err() {
            PosesError::VideoNotRegistered { missing, .. } => assert_eq!(missing, ["cam1"]),
            e => panic!("{e}"),
        }
        match pick_model(&[], &video, diag()).unwrap_err() {
            PosesError::VideoNotRegistered { missing, .. } => assert_eq!(missing.len(), 3),
            e => panic!("{e}"),
        }
    }

    #[test]
    fn normalisation_puts_cameras_at_the_radius_and_keeps_projections() {
        use glam::DVec3;
        let intr = shared_types::Intrinsics::from_hfov(64, 48, 60.0);
        let cams: Vec<Camera> = [
            DVec3::new(5.0, 1.0, 2.0),
            DVec3::new(1.0, 6.0, 2.0),
            DVec3::new(-3.0, 2.0, 3.0),
        ]
        .iter()
        .enumerate()
        .map(|(i, &e)| Camera {
            name: format!("c{i}"),
            intrinsics: intr,
            distortion: Default::default(),
            world_to_camera: WorldToCamera::look_at(e, DVec3::new(1.0, 2.0, 0.0), DVec3::Z)
                .unwrap(),
        })
        .collect();
        let norm = normalisation_for(&cams, &[], 1.0);
        let p = DVec3::new(1.2, 2.1, 0.3);
        for c in &cams {
            let moved = Camera {
                world_to_camera: norm.apply_to_pose(&c.world_to_camera),
                ..c.clone()
            };
            assert!(
                (moved.world_to_camera.centre() - norm.apply(c.world_to_camera.centre())).length()
                    < 1e-12
            );
            let (a, da) = c.project(p).unwrap();
            let (b, db) = moved.project(norm.apply(p)).unwrap();
            assert!((a - b).length() < 1e-9 && (db - da * norm.scale).abs() < 1e-9);
        }
        let mean: f64 = cams
            .iter()
            .map(|c| norm.apply(c.world_to_camera.centre()).length())
            .sum::<f64>()
            / 3.0;
        assert!((mean - 1.0).abs() < 1e-12);
    }
}
