//! The `init` stage: the initial point cloud, from MASt3R-style point maps (an ONNX model
//! run here on pairs of the first aligned frames, or point maps exported beforehand),
//! else points triangulated with COLMAP and the known cameras at `[init] moments` aligned
//! frames spread over the clip, else the poses stage's sparse points, else a random cloud
//! (`pointinit`, docs/init.md), into `points.ply` and `init.json`.

use std::path::PathBuf;

use anyhow::Context;
use calib::poses::PosesFile;
use pointinit::{InitConfig, InitInputs, Moment, StillImage, ViewImage};
use rig::frames::FramesIndex;
use shared_types::Camera;
use shared_types::atomic::write_json;

use crate::engine_inputs::time_mapping;
use crate::layout::Capture;
use crate::stage_context::StageContext;

/// `[init]` settings: the initialiser's own. `model` (the ONNX point-map model) and
/// `pointmaps` (a folder of exported point maps) are relative to the capture directory.
pub type InitSettings = InitConfig;

/// The capture files the stage reads: the `model` file and the `pointmaps` folder, when set.
pub fn inputs(capture: &Capture, settings: &InitSettings) -> Vec<PathBuf> {
    [&settings.model, &settings.pointmaps]
        .into_iter()
        .flatten()
        .map(|path| capture.resolve(path))
        .collect()
}

/// The `init` stage.
pub fn run(
    ctx: &StageContext,
    settings: &InitSettings,
    chunks: &crate::chunks::ChunkSettings,
) -> anyhow::Result<()> {
    let frames_dir = ctx.stage_dir("frames");
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let poses_dir = ctx.stage_dir("poses");
    let poses = PosesFile::read(&poses_dir.join("cameras.json"))?;
    let first = index
        .frames
        .first()
        .context("the frames stage wrote no frames; rerun it")?;
    let mapping = time_mapping(&index);
    let views_of = |frame: &rig::frames::AlignedFrame| -> Vec<ViewImage> {
        index
            .cameras
            .iter()
            .zip(&frame.views)
            .map(|(camera, view)| ViewImage {
                camera: camera.name.clone(),
                path: frames_dir.join(&view.file),
                time: mapping.model_time(view.timestamp_s),
            })
            .collect()
    };
    let images = views_of(first);
    let pointmaps = settings.pointmaps.as_ref().map(|p| ctx.capture.resolve(p));
    let moments = moments_of(&index, settings, chunks, pointmaps.as_deref())?
        .into_iter()
        .map(|i| {
            let frame = &index.frames[i];
            let views = views_of(frame);
            let time = views.iter().map(|v| v.time).sum::<f64>() / views.len().max(1) as f64;
            Moment {
                frame: frame.index,
                time,
                views,
            }
        })
        .collect::<Vec<_>>();
    let sparse = poses
        .points_file
        .as_ref()
        .map(|f| poses_dir.join(f))
        .filter(|p| p.exists());
    let mut config = settings.clone();
    // A clip in time chunks has `[init] moments` in each chunk: every one is swept.
    config.moments = config.moments.max(moments.len());
    config.model = config.model.map(|p| ctx.capture.resolve(&p));
    config.pointmaps = pointmaps;
    // The static plates' frames: `[init] plates` per camera, spread over the clip.
    let plate_frames = moment_frames(index.frames.len(), settings.plates)
        .into_iter()
        .flat_map(|i| views_of(&index.frames[i]))
        .collect();
    let stills = stills_of(&poses.stills, &ctx.capture.stills);
    let inputs = InitInputs {
        cameras: poses.set,
        images,
        sparse,
        moments,
        plate_frames,
        stills,
    };
    let mut report = pointinit::run_init(&inputs, &config, &ctx.out_dir, ctx.progress)?;
    // Recorded relative to work/init/: the stage is built in a temporary folder.
    if let Ok(relative) = report.output.strip_prefix(&ctx.out_dir) {
        report.output = relative.to_path_buf();
    }
    write_json(&ctx.output("init.json"), &report).context("cannot write init.json")?;
    Ok(())
}

/// The stills the poses stage registered (`cameras`, named by file name) with their files
/// among the capture's `stills/` (`files`); a still whose file is gone is left out, with a
/// warning.
fn stills_of(cameras: &[Camera], files: &[PathBuf]) -> Vec<StillImage> {
    cameras
        .iter()
        .filter_map(|camera| {
            let file = files
                .iter()
                .find(|f| f.file_name().is_some_and(|n| *n == *camera.name));
            if file.is_none() {
                tracing::warn!(
                    "the still {} was posed but is no longer in stills/; the init sweeps without it",
                    camera.name
                );
            }
            file.map(|path| StillImage {
                camera: camera.clone(),
                path: path.clone(),
            })
        })
        .collect()
}

/// Indices into `index.frames` of the moments: the aligned frames with exported point maps
/// (`pointmaps/NNNNNN/`) when there are such folders, else `[init] moments` frames spread
/// over the clip, or over each time chunk of a clip trained in chunks (`crate::chunks`).
/// A point-map folder of a frame the frames stage did not write is an error.
fn moments_of(
    index: &FramesIndex,
    settings: &InitSettings,
    chunks: &crate::chunks::ChunkSettings,
    pointmaps: Option<&std::path::Path>,
) -> anyhow::Result<Vec<usize>> {
    use pointinit::moment_maps::{exported_frames, frame_dir};
    let exported = pointmaps.map(|root| (root, exported_frames(root)));
    let Some((root, exported)) = exported.filter(|(_, e)| !e.is_empty()) else {
        let plan = crate::chunks::plan::ChunkPlan::of_index(index, chunks);
        return Ok(plan.moments(settings.moments, moment_frames));
    };
    exported
        .iter()
        .map(|&frame| {
            index.frames.iter().position(|f| f.index == frame).with_context(|| {
                format!(
                    "point maps {} belong to aligned frame {frame}, but the frames stage wrote frames 0..{}; remove the folder or export maps of an existing frame",
                    frame_dir(root, frame).display(),
                    index.frames.len()
                )
            })
        })
        .collect()
}

/// `count` aligned-frame indices spread evenly over `frames` frames, first and last
/// included (clamped to the number of frames; one moment is the first frame).
pub fn moment_frames(frames: usize, count: usize) -> Vec<usize> {
    let count = count.min(frames);
    match count {
        0 => Vec::new(),
        1 => vec![0],
        _ => (0..count)
            .map(|k| (k * (frames - 1) + (count - 1) / 2) / (count - 1))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

    use super::{moment_frames, stills_of};

    #[test]
    fn moments_are_spread_over_the_frames_and_clamped() {
        assert_eq!(moment_frames(36, 6), [0, 7, 14, 21, 28, 35]);
        assert_eq!(moment_frames(3, 6), [0, 1, 2]);
        assert_eq!(moment_frames(10, 1), [0]);
        assert!(moment_frames(0, 6).is_empty());
        assert!(moment_frames(10, 0).is_empty());
    }

    #[test]
    fn posed_stills_are_found_by_file_name_and_missing_ones_left_out() {
        let still = |name: &str| Camera {
            name: name.into(),
            intrinsics: Intrinsics::from_hfov(64, 48, 60.0),
            distortion: Distortion::None,
            world_to_camera: WorldToCamera::IDENTITY,
        };
        let files = [
            PathBuf::from("/c/stills/a.jpg"),
            PathBuf::from("/c/stills/b.png"),
        ];
        let found = stills_of(&[still("b.png"), still("gone.jpg"), still("a.jpg")], &files);
        let got: Vec<(&str, &PathBuf)> = found
            .iter()
            .map(|s| (s.camera.name.as_str(), &s.path))
            .collect();
        assert_eq!(got, [("b.png", &files[1]), ("a.jpg", &files[0])]);
    }
}
