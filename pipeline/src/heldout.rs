//! Held-out cameras of a real capture (`[capture] heldout`, docs/render-eval.md): they go
//! through ingest, sync, frames and poses with the training cameras, and are then split
//! off so that init, train, render and export never see them:
//!
//! - `work/frames/frames.json`: the training cameras; `work/frames/heldout.json`: the
//!   held-out cameras on the same timeline (same `fps`, `start_s` and frame times; each
//!   view keeps its exact timestamp). Both are [`FramesIndex`] files.
//! - `work/poses/cameras.json`: the training cameras; `work/poses/heldout.json`: the
//!   held-out cameras in the same normalised frame. Both are [`PosesFile`] files.
//!
//! Without held-out cameras neither `heldout.json` is written.

use std::path::Path;

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use splat4d::CameraSet;

/// File name of the held-out cameras' index in `work/frames/` and of their poses in
/// `work/poses/`.
pub const HELDOUT_FILE: &str = "heldout.json";

/// Split a frames index into the training cameras and the `heldout` ones, on the same
/// timeline (frame times and view timestamps unchanged). Fails when a held-out camera has
/// no images in `index`.
pub fn split_frames(
    index: &FramesIndex,
    heldout: &[String],
) -> anyhow::Result<(FramesIndex, FramesIndex)> {
    for name in heldout {
        if !index.cameras.iter().any(|c| &c.name == name) {
            bail!(
                "the frames stage has no images of the held-out camera {name}; rerun it (`pipeline run CAPTURE --from frames --force`)"
            );
        }
    }
    let keep = |held: bool| {
        let columns: Vec<usize> = (0..index.cameras.len())
            .filter(|&c| heldout.contains(&index.cameras[c].name) == held)
            .collect();
        let mut part = index.clone();
        part.cameras = columns.iter().map(|&c| index.cameras[c].clone()).collect();
        for (frame, source) in part.frames.iter_mut().zip(&index.frames) {
            frame.views = columns.iter().map(|&c| source.views[c].clone()).collect();
        }
        part
    };
    Ok((keep(false), keep(true)))
}

/// Split the poses stage's `out_dir/cameras.json` (every camera, as solved or imported)
/// into `cameras.json` (training cameras) and `heldout.json` (the `heldout` cameras, same
/// normalisation). `origin` names where the poses came from, for the error when a
/// held-out camera is missing.
pub fn split_poses(out_dir: &Path, heldout: &[String], origin: &str) -> anyhow::Result<()> {
    if heldout.is_empty() {
        return Ok(());
    }
    let path = out_dir.join("cameras.json");
    let all = PosesFile::read(&path)?;
    let missing: Vec<&str> = heldout
        .iter()
        .filter(|name| all.set.get(name).is_none())
        .map(String::as_str)
        .collect();
    if !missing.is_empty() {
        bail!(
            "{origin} has no camera {} listed in [capture] heldout of capture.toml; add its pose to the calibration, or remove it from `heldout`",
            missing.join(", ")
        );
    }
    let part = |held: bool| {
        let mut file = all.clone();
        file.set = CameraSet {
            cameras: all
                .set
                .cameras
                .iter()
                .filter(|c| heldout.contains(&c.name) == held)
                .cloned()
                .collect(),
            ..all.set.clone()
        };
        if held {
            file.points_file = None;
            file.num_points = 0;
        }
        file
    };
    write_json(&path, &part(false))?;
    write_json(&out_dir.join(HELDOUT_FILE), &part(true))
}

/// The held-out cameras of a capture's `work/` folder as the undistorted pinhole cameras
/// that `eval` renders (e.g. for `[render] path = "heldout"`); empty when the capture
/// lists no held-out cameras (no `work/frames/heldout.json`).
pub fn pinhole_heldout_cameras(work_dir: &Path) -> anyhow::Result<Vec<splat4d::Camera>> {
    let index_path = work_dir.join("frames").join(HELDOUT_FILE);
    if !index_path.exists() {
        return Ok(Vec::new());
    }
    let index = FramesIndex::read_json(&index_path)?;
    let poses_path = work_dir.join("poses").join(HELDOUT_FILE);
    let poses = PosesFile::read(&poses_path)?;
    Ok(
        crate::training::pinhole_cameras(&index, &poses.set, &poses_path)?
            .into_iter()
            .map(|(camera, _)| camera)
            .collect(),
    )
}

fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    crate::atomic::write_atomic(path, &serde_json::to_vec_pretty(value)?)
        .with_context(|| format!("cannot write {}", path.display()))
}
