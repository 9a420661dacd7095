//! Solving the rig with COLMAP: check the inputs, build the workspace, run the mapper
//! (retrying with stricter settings when a solve looks degenerate), pick the model holding
//! every video camera, and take its cameras and points.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use shared_types::{Camera, Progress};

use super::config::PosesInputs;
use super::error::PosesError;
use super::file::PoseSource;
use super::write::{PosesOutput, SparsePoint, scale_intrinsics, write_outputs};
use crate::colmap::{ColmapCamera, ColmapModel};
use crate::colmap_runner::diagnose::Diagnosis;
use crate::colmap_runner::quality::{self, Degeneracy, QualityLimits};
use crate::colmap_runner::{
    ColmapError, MatchGraph, StillsCameras, VideoCameras, Workspace, WorkspaceImage, find_colmap,
};
use crate::convert;

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
    let known_lenses = known_lenses(inputs)?;
    // A known lens is per camera: each video camera gets its own COLMAP camera.
    let video_cameras = if known_lenses.is_empty() {
        config.colmap.video_cameras.resolve(video_sizes.len() <= 1)
    } else {
        VideoCameras::Separate
    };
    let mut ws = Workspace::create(
        &ws_root,
        &inputs.video_frames,
        &inputs.stills,
        config.colmap.stills_cameras,
        video_cameras,
    )?;
    ws.known_lenses = known_lenses;
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
    // The lenses the mapper's model is judged on: a known lens is put back (held fixed) after
    // mapping, and judged then by how well the camera fits it (`known_lens_misfits`).
    let judged_lenses: Vec<&str> = ws
        .images
        .iter()
        .filter(|i| {
            i.video_camera
                .as_ref()
                .is_none_or(|c| !ws.known_lenses.contains_key(c))
        })
        .map(|i| i.colmap_name.as_str())
        .collect();
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
        let mut found = quality::assess(model, &judged_lenses, prior, &QualityLimits::default());
        let adjusted;
        let (model_dir, model) = if ws.known_lenses.is_empty() || !found.is_empty() {
            (model_dir, model)
        } else {
            adjusted = ws.fix_known_lenses(&binary, model, &video, progress)?;
            found = quality::known_lens_misfits(
                &adjusted.1,
                model,
                &video_names,
                &QualityLimits::default(),
            );
            (&adjusted.0, &adjusted.1)
        };
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
        let stills = still_cameras(model, &ws.images)?;
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
        return write_outputs(out_dir, cameras, points, stills, source, config.radius);
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

/// The registered stills among the workspace's `images` as cameras of `model` (COLMAP's
/// frame), each named by its file name, at its own size and lens.
fn still_cameras(
    model: &ColmapModel,
    images: &[WorkspaceImage],
) -> Result<Vec<Camera>, PosesError> {
    images
        .iter()
        .filter(|i| i.video_camera.is_none())
        .filter_map(|i| {
            let name = i.source.file_name()?.to_string_lossy().into_owned();
            let image = model.image_by_name(&i.colmap_name)?;
            Some(convert::camera_from_image(model, image, &name).map_err(PosesError::from))
        })
        .collect()
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
        let camera = convert::camera_from_image(model, image, cam)?;
        cameras.push(Camera {
            intrinsics: scale_intrinsics(cam, &camera.intrinsics, working_size)?,
            ..camera
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

/// The known lenses of [`PosesInputs::known_lenses`] as COLMAP cameras, each checked
/// against its video camera's frame size.
fn known_lenses(inputs: &PosesInputs) -> Result<BTreeMap<String, ColmapCamera>, PosesError> {
    let mut out = BTreeMap::new();
    for (camera, (intrinsics, distortion)) in &inputs.known_lenses {
        let Some((_, frame)) = inputs.video_frames.iter().find(|(c, _)| c == camera) else {
            return Err(PosesError::KnownLensWithoutCamera {
                camera: camera.clone(),
            });
        };
        let size = image::image_dimensions(frame).map_err(|e| PosesError::ImageUnreadable {
            path: frame.clone(),
            reason: e.to_string(),
        })?;
        if size != (intrinsics.width, intrinsics.height) {
            return Err(PosesError::AspectMismatch {
                camera: camera.clone(),
                calibrated: (intrinsics.width, intrinsics.height),
                working: size,
            });
        }
        out.insert(
            camera.clone(),
            convert::from_engine(0, intrinsics, distortion)?,
        );
    }
    Ok(out)
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
    let list = |sizes: &BTreeSet<(u32, u32)>| {
        let sizes: Vec<String> = sizes.iter().map(|(w, h)| format!("{w}×{h}")).collect();
        sizes.join(", ")
    };
    if inputs.config.colmap.video_cameras == VideoCameras::Shared && video_sizes.len() > 1 {
        return Err(PosesError::VideoSizesDiffer {
            sizes: list(&video_sizes),
        });
    }
    if inputs.config.colmap.stills_cameras == StillsCameras::Shared && still_sizes.len() > 1 {
        return Err(PosesError::StillSizesDiffer {
            sizes: list(&still_sizes),
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
}
