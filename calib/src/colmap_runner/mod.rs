//! Driving the `colmap` program: find the binary, lay out a workspace, run
//! `feature_extractor` → `exhaustive_matcher` → `mapper` with COLMAP's output streamed to a
//! [`Progress`] and to log files, time each step, and read back the models and the match
//! graph. Deciding what a result means for the rig (which images must register, how to
//! explain a failure) is [`crate::poses`]'s job, with help from [`diagnose`].
//!
//! Workspace layout (`<root>` is `work/poses/colmap/`):
//! ```text
//! <root>/images/video/<cam>/<cam>.<ext>   one folder, so one COLMAP camera, per video camera
//! <root>/images/stills/<file>             stills: one shared camera (or one folder each)
//! <root>/lists/<group>.txt                image lists, one feature_extractor run per model
//! <root>/database.db                      COLMAP's SQLite database
//! <root>/sparse/0, 1, …                   the models the mapper found
//! <root>/logs/<step>.log                  everything COLMAP printed
//! ```

pub mod database;
pub mod diagnose;
mod known_lenses;
pub mod known_poses;
pub mod quality;

use std::ffi::OsString;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use shared_types::Progress;

use crate::colmap::{CameraModel, ColmapModel, ModelError};
pub use database::{DatabaseError, MatchGraph};

/// Environment variable naming the COLMAP binary (checked after the configured path).
pub const COLMAP_ENV: &str = "COLMAP_BIN";

/// How COLMAP is run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ColmapConfig {
    /// Path to the `colmap` binary; `None` → `$COLMAP_BIN`, then `colmap` on `PATH`.
    pub binary: Option<PathBuf>,
    /// Camera model of the video cameras. The default `RADIAL` (one focal length, two radial
    /// terms) suits webcams and phones; `OPENCV_FISHEYE` for GoPro wide modes, `OPENCV`
    /// only for lenses with real tangential distortion. A few views cannot pin `OPENCV`'s
    /// separate fx, fy and tangential terms: on the synthetic rigs its aspect drifted 1–2 %
    /// and the cameras 0.11–0.47° (max), against 0.04–0.09° with `RADIAL` (docs/poses.md).
    pub camera_model: CameraModel,
    /// Camera model of the stills (`RADIAL` by default, for the same reason).
    pub stills_camera_model: CameraModel,
    /// Whether all stills share one camera (same phone/lens and size) or get one each.
    pub stills_cameras: StillsCameras,
    /// Whether the video cameras share one lens (`auto`, the default: shared when their
    /// frames have one size; 4 images then constrain the lens, not 1) or get one each.
    pub video_cameras: VideoCameras,
    /// A prior focal length of the video cameras, in pixels of the frames given to COLMAP
    /// (e.g. from the lens datasheet): COLMAP starts from it and verifies matches with the
    /// essential matrix instead of the fundamental one. `None`: COLMAP guesses
    /// 1.2 × the longest side and solves.
    pub video_focal_px: Option<f64>,
    /// Seed of COLMAP's random number generator (RANSAC samples); retries add 1, 2, ….
    pub random_seed: u32,
    /// Extraction, matching and mapping in one thread each, so that runs differ little
    /// (the matcher's approximate search still varies a few matches per pair):
    /// threaded extraction numbers the images in the order they finish, and the image IDs
    /// steer the matcher's RANSAC and the mapper; threaded RANSAC and bundle adjustment
    /// vary too. Costs up to 2× in extraction and matching time on a 2-core machine.
    pub deterministic: bool,
    /// Mapper runs (each with the next seed and stricter settings) before a degenerate or
    /// incomplete solve is reported as an error; matches are computed once.
    pub max_attempts: u32,
    /// Longest image side SIFT works on (COLMAP downsamples internally, poses stay exact).
    pub max_image_size: u32,
    /// Most SIFT features kept per image (COLMAP's default 8192; fewer is faster to match).
    pub max_num_features: u32,
    /// Threads for extraction, matching and mapping (`-1`: all cores).
    pub num_threads: i32,
    /// `Mapper.init_min_num_inliers` (COLMAP's default 100; lower helps small images).
    pub init_min_num_inliers: u32,
    /// `Mapper.ba_refine_principal_point` (COLMAP's default off: the principal point stays
    /// at the image centre; turn on for well-textured scenes with many matches).
    pub refine_principal_point: bool,
}

impl Default for ColmapConfig {
    fn default() -> Self {
        Self {
            binary: None,
            camera_model: CameraModel::Radial,
            stills_camera_model: CameraModel::Radial,
            stills_cameras: StillsCameras::Shared,
            video_cameras: VideoCameras::Auto,
            video_focal_px: None,
            random_seed: 0,
            deterministic: true,
            max_attempts: 5,
            max_image_size: 3200,
            max_num_features: 8192,
            num_threads: -1,
            init_min_num_inliers: 100,
            refine_principal_point: false,
        }
    }
}

/// Whether the stills share one COLMAP camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StillsCameras {
    /// One camera for all stills (they must all have the same size).
    Shared,
    /// One camera per still (different phones, zoom levels or sizes).
    PerImage,
}

/// Whether the video cameras share one COLMAP camera (intrinsics and distortion).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VideoCameras {
    /// Shared when all video frames have the same size, else separate.
    Auto,
    /// One camera per video camera.
    Separate,
    /// One camera for all video cameras (same model, lens mode and resolution).
    Shared,
}

impl VideoCameras {
    /// `Auto` decided: shared when the video frames all have one size.
    pub fn resolve(self, one_size: bool) -> Self {
        match self {
            Self::Auto if one_size => Self::Shared,
            Self::Auto => Self::Separate,
            other => other,
        }
    }
}

/// Seconds spent in each COLMAP step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ColmapTimings {
    pub feature_extraction_s: f64,
    pub matching_s: f64,
    /// All mapper attempts together.
    pub mapping_s: f64,
    /// Mapper runs made (1 when the first solve was sound).
    #[serde(default)]
    pub mapper_attempts: u32,
}

/// One image placed in the workspace.
#[derive(Clone, Debug, PartialEq)]
pub struct WorkspaceImage {
    /// Name as COLMAP sees it (relative to `images/`, `/`-separated).
    pub colmap_name: String,
    pub source: PathBuf,
    /// `Some(camera name)` for a video camera's frame, `None` for a still.
    pub video_camera: Option<String>,
}

/// A COLMAP workspace on disk.
#[derive(Clone, Debug)]
pub struct Workspace {
    pub root: PathBuf,
    pub images: Vec<WorkspaceImage>,
    /// Video cameras whose lens is known (`[poses] intrinsics`), by camera name, at the
    /// size of their frame here: extracted with these parameters and held fixed in a final
    /// bundle adjustment (see [`Workspace::fix_known_lenses`]).
    pub known_lenses: std::collections::BTreeMap<String, crate::colmap::ColmapCamera>,
}

/// What a finished COLMAP run left behind.
#[derive(Clone, Debug)]
pub struct ColmapRun {
    /// The models in `sparse/`, largest (most registered images) first.
    pub models: Vec<(PathBuf, ColmapModel)>,
    pub graph: MatchGraph,
    pub timings: ColmapTimings,
}

/// Errors of driving COLMAP.
#[derive(Debug, thiserror::Error)]
pub enum ColmapError {
    #[error(
        "COLMAP was not found ({tried}). Install it (Debian/Ubuntu: `apt-get install colmap`; \
         other systems: https://colmap.github.io/install.html), or give its path in the \
         configuration (`[poses.colmap] binary = \"/path/to/colmap\"`) or in ${COLMAP_ENV}"
    )]
    NotFound { tried: String },
    #[error("cannot start COLMAP ({binary}): {source}")]
    Spawn {
        binary: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "COLMAP {step} {how}. Its output is in {log}; last lines:\n{tail}\n\
         Check that the images open, that the disk is not full, and rerun; if it keeps \
         failing, run the command in the log by hand"
    )]
    StepFailed {
        step: String,
        how: String,
        log: PathBuf,
        tail: String,
        no_model: bool,
    },
    #[error("cannot write the COLMAP workspace at {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Database(#[from] DatabaseError),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ColmapError + '_ {
    move |source| ColmapError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The COLMAP binary: the configured path, else `$COLMAP_BIN`, else `colmap` on `PATH`.
pub fn find_colmap(configured: Option<&Path>) -> Result<PathBuf, ColmapError> {
    if let Some(p) = configured {
        return if p.is_file() {
            Ok(p.to_path_buf())
        } else {
            Err(ColmapError::NotFound {
                tried: format!("configured path {} does not exist", p.display()),
            })
        };
    }
    if let Some(p) = std::env::var_os(COLMAP_ENV).filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(ColmapError::NotFound {
                tried: format!("${COLMAP_ENV}={} does not exist", p.display()),
            })
        };
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .map(|d| d.join("colmap"))
        .find(|p| p.is_file())
        .ok_or_else(|| ColmapError::NotFound {
            tried: "no `colmap` on PATH".into(),
        })
}

impl Workspace {
    /// Lay out a fresh workspace at `root` (anything there before is removed, so a rerun
    /// never mixes old features or matches in): one folder per video camera, stills in
    /// `stills/` (shared camera) or one folder each; with [`VideoCameras::Shared`] all video
    /// frames in `video/` (`Auto` is taken as shared: resolve it first with
    /// [`VideoCameras::resolve`]). Images are copied.
    pub fn create(
        root: &Path,
        video_frames: &[(String, PathBuf)],
        stills: &[PathBuf],
        stills_cameras: StillsCameras,
        video_cameras: VideoCameras,
    ) -> Result<Self, ColmapError> {
        if root.exists() {
            std::fs::remove_dir_all(root).map_err(io_err(root))?;
        }
        let mut images = Vec::new();
        for (cam, src) in video_frames {
            let ext = extension(src);
            images.push(WorkspaceImage {
                colmap_name: match video_cameras {
                    VideoCameras::Separate => format!("video/{cam}/{cam}.{ext}"),
                    VideoCameras::Shared | VideoCameras::Auto => format!("video/{cam}.{ext}"),
                },
                source: src.clone(),
                video_camera: Some(cam.clone()),
            });
        }
        for (i, src) in stills.iter().enumerate() {
            let file = src
                .file_name()
                .map(|f| f.to_string_lossy().replace(' ', "_"))
                .unwrap_or_default();
            let file = format!("{i:03}_{file}"); // unique even when two folders hold the same name
            let colmap_name = match stills_cameras {
                StillsCameras::Shared => format!("stills/{file}"),
                StillsCameras::PerImage => format!("stills/{i:03}/{file}"),
            };
            images.push(WorkspaceImage {
                colmap_name,
                source: src.clone(),
                video_camera: None,
            });
        }
        for img in &images {
            let dst = root.join("images").join(&img.colmap_name);
            let parent = dst.parent().unwrap_or(root);
            std::fs::create_dir_all(parent).map_err(io_err(parent))?;
            std::fs::copy(&img.source, &dst).map_err(io_err(&img.source))?;
        }
        for dir in ["sparse", "logs", "lists"] {
            let d = root.join(dir);
            std::fs::create_dir_all(&d).map_err(io_err(&d))?;
        }
        Ok(Self {
            root: root.to_path_buf(),
            images,
            known_lenses: Default::default(),
        })
    }

    pub fn image_dir(&self) -> PathBuf {
        self.root.join("images")
    }
    pub fn database(&self) -> PathBuf {
        self.root.join("database.db")
    }
    pub fn sparse_dir(&self) -> PathBuf {
        self.root.join("sparse")
    }

    /// Run extraction, matching and one mapping (attempt 0); stream COLMAP's output to
    /// `progress`. A mapper that finds no model is reported as
    /// `StepFailed { no_model: true, .. }`.
    pub fn run(
        &self,
        binary: &Path,
        config: &ColmapConfig,
        progress: &dyn Progress,
    ) -> Result<ColmapRun, ColmapError> {
        progress.start(3, "COLMAP steps");
        let mut timings = self.extract_and_match(binary, config, progress)?;
        let t0 = Instant::now();
        let models = self.map(binary, config, 0, progress);
        timings.mapping_s = t0.elapsed().as_secs_f64();
        timings.mapper_attempts = 1;
        progress.advance(1);
        let models = models?;
        let graph = MatchGraph::read(&self.database())?;
        progress.finish();
        Ok(ColmapRun {
            models,
            graph,
            timings,
        })
    }

    /// Feature extraction (one run per camera model, or for the video cameras apart when
    /// they have a prior focal length) and exhaustive matching; advances `progress` by 2.
    pub fn extract_and_match(
        &self,
        binary: &Path,
        config: &ColmapConfig,
        progress: &dyn Progress,
    ) -> Result<ColmapTimings, ColmapError> {
        let threads = config.num_threads.to_string();
        let match_threads = if config.deterministic {
            "1".to_string()
        } else {
            threads.clone()
        };
        let db = self.database();
        let images = self.image_dir();
        let mut timings = ColmapTimings::default();

        // One extraction per camera model, each from its own image list.
        let t0 = Instant::now();
        let groups = [
            (true, config.camera_model),
            (false, config.stills_camera_model),
        ];
        let same_model = config.camera_model == config.stills_camera_model
            && config.video_focal_px.is_none()
            && self.known_lenses.is_empty();
        let known = |i: &WorkspaceImage| {
            i.video_camera
                .as_ref()
                .is_some_and(|c| self.known_lenses.contains_key(c))
        };
        for (video, model) in groups {
            let names: Vec<&str> = self
                .images
                .iter()
                .filter(|i| same_model || i.video_camera.is_some() == video)
                .filter(|i| !known(i))
                .map(|i| i.colmap_name.as_str())
                .collect();
            if names.is_empty() {
                continue;
            }
            let group = if same_model {
                "all"
            } else if video {
                "video"
            } else {
                "stills"
            };
            let list = self.root.join("lists").join(format!("{group}.txt"));
            std::fs::write(&list, names.join("\n") + "\n").map_err(io_err(&list))?;
            let mut step_args = args(&[
                ("--database_path", db.as_os_str()),
                ("--image_path", images.as_os_str()),
                ("--image_list_path", list.as_os_str()),
                ("--ImageReader.camera_model", model.name().as_ref()),
                ("--ImageReader.single_camera_per_folder", "1".as_ref()),
                ("--SiftExtraction.use_gpu", "0".as_ref()),
                ("--SiftExtraction.num_threads", match_threads.as_ref()),
                (
                    "--SiftExtraction.max_image_size",
                    config.max_image_size.to_string().as_ref(),
                ),
                (
                    "--SiftExtraction.max_num_features",
                    config.max_num_features.to_string().as_ref(),
                ),
            ]);
            if let (true, Some(f)) = (video, config.video_focal_px) {
                let (w, h) = self.video_size().unwrap_or((0, 0));
                let params = prior_params(model, f, w as f64 / 2.0, h as f64 / 2.0);
                step_args.extend(args(&[("--ImageReader.camera_params", params.as_ref())]));
            }
            self.run_step(
                binary,
                "feature_extractor",
                &format!("feature_extractor_{group}"),
                step_args,
                progress,
            )?;
            if same_model {
                break;
            }
        }
        self.extract_known_lenses(binary, &match_threads, config, progress)?;
        timings.feature_extraction_s = t0.elapsed().as_secs_f64();
        progress.advance(1);

        let t0 = Instant::now();
        let seed = config.random_seed.to_string();
        let step_args = args(&[
            ("--database_path", db.as_os_str()),
            ("--random_seed", seed.as_ref()),
            ("--SiftMatching.use_gpu", "0".as_ref()),
            ("--SiftMatching.num_threads", match_threads.as_ref()),
        ]);
        self.run_step(
            binary,
            "exhaustive_matcher",
            "exhaustive_matcher",
            step_args,
            progress,
        )?;
        timings.matching_s = t0.elapsed().as_secs_f64();
        progress.advance(1);
        Ok(timings)
    }

    /// One mapper run into a fresh `sparse/`, log `logs/mapper.log` (attempt 0) or
    /// `logs/mapper_retry<attempt>.log`. Attempt `k` uses seed `random_seed + k`; retries
    /// (`k > 0`) also reject implausible lenses during mapping (focal length 0.25–4× the
    /// longest image side, distortion coefficients below 0.5) and outliers harder.
    /// Returns the models, most registered images first; a mapper that finds none is
    /// `StepFailed { no_model: true, .. }`.
    pub fn map(
        &self,
        binary: &Path,
        config: &ColmapConfig,
        attempt: u32,
        progress: &dyn Progress,
    ) -> Result<Vec<(PathBuf, ColmapModel)>, ColmapError> {
        let sparse = self.sparse_dir();
        if sparse.exists() {
            std::fs::remove_dir_all(&sparse).map_err(io_err(&sparse))?;
        }
        std::fs::create_dir_all(&sparse).map_err(io_err(&sparse))?;
        let db = self.database();
        let images = self.image_dir();
        let threads = if config.deterministic {
            "1".to_string()
        } else {
            config.num_threads.to_string()
        };
        let seed = config.random_seed.wrapping_add(attempt).to_string();
        let mut step_args = args(&[
            ("--database_path", db.as_os_str()),
            ("--image_path", images.as_os_str()),
            ("--output_path", sparse.as_os_str()),
            ("--random_seed", seed.as_ref()),
            ("--Mapper.num_threads", threads.as_ref()),
            (
                "--Mapper.init_min_num_inliers",
                config.init_min_num_inliers.to_string().as_ref(),
            ),
            (
                "--Mapper.ba_refine_principal_point",
                if config.refine_principal_point {
                    "1"
                } else {
                    "0"
                }
                .as_ref(),
            ),
        ]);
        if attempt > 0 {
            step_args.extend(args(&[
                ("--Mapper.min_focal_length_ratio", "0.25".as_ref()),
                ("--Mapper.max_focal_length_ratio", "4".as_ref()),
                ("--Mapper.max_extra_param", "0.5".as_ref()),
                ("--Mapper.abs_pose_min_inlier_ratio", "0.4".as_ref()),
                ("--Mapper.filter_max_reproj_error", "2".as_ref()),
                ("--Mapper.init_min_tri_angle", "20".as_ref()),
            ]));
        }
        let log_name = if attempt == 0 {
            "mapper".to_string()
        } else {
            format!("mapper_retry{attempt}")
        };
        let mapped = self.run_step(binary, "mapper", &log_name, step_args, progress);
        let models = self.read_models()?;
        match mapped {
            Err(ColmapError::StepFailed {
                step,
                how,
                log,
                tail,
                ..
            }) if models.is_empty() && !how.contains("signal") => Err(ColmapError::StepFailed {
                step,
                how,
                log,
                tail,
                no_model: true,
            }),
            Err(e) => Err(e),
            Ok(()) => Ok(models),
        }
    }

    /// The size of the first video frame (for the prior focal length's principal point).
    fn video_size(&self) -> Option<(u32, u32)> {
        let img = self.images.iter().find(|i| i.video_camera.is_some())?;
        image::image_dimensions(self.image_dir().join(&img.colmap_name)).ok()
    }

    /// The models in `sparse/<n>/`, most registered images first.
    pub fn read_models(&self) -> Result<Vec<(PathBuf, ColmapModel)>, ColmapError> {
        let sparse = self.sparse_dir();
        let mut dirs: Vec<PathBuf> = match std::fs::read_dir(&sparse) {
            Ok(rd) => rd
                .filter_map(|e| e.ok())
                .map(|e| e.path())
                .filter(|p| p.is_dir())
                .collect(),
            Err(_) => Vec::new(),
        };
        dirs.sort();
        let mut models = Vec::new();
        for d in dirs {
            if ColmapModel::detect_format(&d).is_some() {
                let m = ColmapModel::read(&d)?;
                models.push((d, m));
            }
        }
        models.sort_by_key(|(_, m)| std::cmp::Reverse(m.images.len()));
        Ok(models)
    }

    /// Run one COLMAP command; its output goes line by line to `logs/<log_name>.log` and,
    /// for the lines that tell progress, to `progress.message`.
    fn run_step(
        &self,
        binary: &Path,
        step: &str,
        log_name: &str,
        args: Vec<OsString>,
        progress: &dyn Progress,
    ) -> Result<(), ColmapError> {
        let log_path = self.root.join("logs").join(format!("{log_name}.log"));
        let mut log = std::fs::File::create(&log_path).map_err(io_err(&log_path))?;
        let mut cmdline = format!("{} {step}", binary.display());
        for a in &args {
            cmdline.push(' ');
            cmdline.push_str(&a.to_string_lossy());
        }
        let _ = writeln!(log, "$ {cmdline}");
        progress.message(&format!("colmap {step}"));
        let mut child = Command::new(binary)
            .arg(step)
            .args(&args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|source| ColmapError::Spawn {
                binary: binary.to_path_buf(),
                source,
            })?;
        let (tx, rx) = mpsc::channel::<String>();
        let mut readers = Vec::new();
        if let Some(out) = child.stdout.take() {
            let tx = tx.clone();
            readers.push(std::thread::spawn(move || forward_lines(out, tx)));
        }
        if let Some(err) = child.stderr.take() {
            let tx = tx.clone();
            readers.push(std::thread::spawn(move || forward_lines(err, tx)));
        }
        drop(tx);
        let mut tail: std::collections::VecDeque<String> = std::collections::VecDeque::new();
        for line in rx {
            let _ = writeln!(log, "{line}");
            if let Some(msg) = progress_line(&line) {
                progress.message(&format!("{step}: {msg}"));
            }
            if !line.trim().is_empty() {
                tail.push_back(line);
                if tail.len() > 15 {
                    tail.pop_front();
                }
            }
        }
        readers.into_iter().for_each(|h| {
            let _ = h.join();
        });
        let status = child.wait().map_err(|source| ColmapError::Spawn {
            binary: binary.to_path_buf(),
            source,
        })?;
        let _ = writeln!(log, "# exit: {status}");
        if status.success() {
            return Ok(());
        }
        Err(ColmapError::StepFailed {
            step: step.to_string(),
            how: describe_status(status),
            log: log_path,
            tail: tail
                .into_iter()
                .map(|l| format!("  | {l}"))
                .collect::<Vec<_>>()
                .join("\n"),
            no_model: false,
        })
    }
}

/// `--ImageReader.camera_params` for `model` with focal length `f`, principal point
/// `(cx, cy)` and no distortion.
pub fn prior_params(model: CameraModel, f: f64, cx: f64, cy: f64) -> String {
    let mut p = vec![0.0; model.num_params()];
    if model.has_single_focal() {
        (p[0], p[1], p[2]) = (f, cx, cy);
    } else {
        (p[0], p[1], p[2], p[3]) = (f, f, cx, cy);
    }
    p.iter()
        .map(|v| v.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

fn args(pairs: &[(&str, &std::ffi::OsStr)]) -> Vec<OsString> {
    pairs
        .iter()
        .flat_map(|(k, v)| [OsString::from(k), v.to_os_string()])
        .collect()
}

fn extension(p: &Path) -> String {
    p.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_else(|| "png".into())
}

fn forward_lines(r: impl std::io::Read, tx: mpsc::Sender<String>) {
    for line in BufReader::new(r).split(b'\n') {
        let Ok(line) = line else { break };
        let line = String::from_utf8_lossy(&line)
            .trim_end_matches('\r')
            .to_string();
        if tx.send(line).is_err() {
            break;
        }
    }
}

/// The lines of COLMAP's output worth showing beside a progress bar.
fn progress_line(line: &str) -> Option<&str> {
    let l = line.trim();
    const KEYS: [&str; 7] = [
        "Processed file",
        "Matching block",
        "Initializing with image pair",
        "Registering image",
        "No good initial image pair",
        "Elapsed time",
        "ERROR",
    ];
    KEYS.iter().any(|k| l.contains(k)).then_some(l)
}

fn describe_status(status: ExitStatus) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(sig) = status.signal() {
            return format!("crashed (killed by signal {sig})");
        }
    }
    match status.code() {
        Some(c) => format!("failed (exit code {c})"),
        None => "failed".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_video_cameras_share_one_lens_only_at_one_size() {
        assert_eq!(VideoCameras::Auto.resolve(true), VideoCameras::Shared);
        assert_eq!(VideoCameras::Auto.resolve(false), VideoCameras::Separate);
        assert_eq!(VideoCameras::Separate.resolve(true), VideoCameras::Separate);
        assert_eq!(VideoCameras::Shared.resolve(false), VideoCameras::Shared);
        assert_eq!(ColmapConfig::default().video_cameras, VideoCameras::Auto);
        assert!(ColmapConfig::default().deterministic);
    }

    #[test]
    fn prior_parameters_follow_the_model_layout() {
        assert_eq!(
            prior_params(CameraModel::Opencv, 502.5, 320.0, 240.0),
            "502.5,502.5,320,240,0,0,0,0"
        );
        assert_eq!(
            prior_params(CameraModel::SimpleRadial, 400.0, 160.0, 120.0),
            "400,160,120,0"
        );
        assert_eq!(
            prior_params(CameraModel::OpencvFisheye, 300.0, 1.5, 2.5),
            "300,300,1.5,2.5,0,0,0,0"
        );
    }
}
