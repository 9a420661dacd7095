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
use shared_types::{Camera, CameraSet};

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
            file.stills.clear();
        }
        file
    };
    write_json(&path, &part(false))?;
    write_json(&out_dir.join(HELDOUT_FILE), &part(true))
}

/// The held-out cameras of a capture's `work/` folder as the undistorted pinhole cameras
/// that `eval` renders (e.g. for `[render] path = "heldout"`); empty when the capture
/// lists no held-out cameras (no `work/frames/heldout.json`).
pub fn pinhole_heldout_cameras(work_dir: &Path) -> anyhow::Result<Vec<Camera>> {
    let index_path = work_dir.join("frames").join(HELDOUT_FILE);
    if !index_path.exists() {
        return Ok(Vec::new());
    }
    let index = FramesIndex::read_json(&index_path)?;
    let poses_path = work_dir.join("poses").join(HELDOUT_FILE);
    let poses = PosesFile::read(&poses_path)?;
    Ok(
        crate::engine_inputs::pinhole_cameras(&index, &poses.set, &poses_path)?
            .into_iter()
            .map(|(camera, _)| camera)
            .collect(),
    )
}

fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    shared_types::atomic::write_json(path, value)
        .with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib::poses::{Normalisation, PoseSource};
    use glam::{DMat3, DVec3};
    use rig::frames::{AlignedFrame, CameraImages, View};
    use shared_types::{Distortion, Intrinsics, WorldToCamera};

    fn names(n: &[&str]) -> Vec<String> {
        n.iter().map(|s| s.to_string()).collect()
    }

    fn index(cameras: &[&str]) -> FramesIndex {
        FramesIndex {
            fps: 10.0,
            start_s: 0.25,
            cameras: cameras
                .iter()
                .map(|name| CameraImages {
                    name: name.to_string(),
                    width: 16,
                    height: 12,
                })
                .collect(),
            frames: (0..3)
                .map(|f| AlignedFrame {
                    index: f,
                    time_s: 0.25 + f as f64 / 10.0,
                    views: cameras
                        .iter()
                        .enumerate()
                        .map(|(c, name)| View {
                            source_frame: f + c,
                            timestamp_s: 0.25 + f as f64 / 10.0 + 0.01 * c as f64,
                            residual_s: 0.01 * c as f64,
                            file: format!("{name}/{f:06}.png"),
                        })
                        .collect(),
                })
                .collect(),
            warnings: Vec::new(),
        }
    }

    #[test]
    fn frames_split_keeps_the_timeline_and_each_cameras_views() {
        let all = index(&["cam0", "cam1", "cam4", "cam2"]);
        let (train, held) = split_frames(&all, &names(&["cam4"])).unwrap();
        let cams = |i: &FramesIndex| i.cameras.iter().map(|c| c.name.clone()).collect::<Vec<_>>();
        assert_eq!(cams(&train), ["cam0", "cam1", "cam2"]);
        assert_eq!(cams(&held), ["cam4"]);
        for part in [&train, &held] {
            assert_eq!((part.fps, part.start_s), (all.fps, all.start_s));
            assert_eq!(part.frames.len(), all.frames.len());
        }
        for (f, frame) in all.frames.iter().enumerate() {
            assert_eq!(held.frames[f].views, [frame.views[2].clone()]);
            assert_eq!(train.frames[f].views[2], frame.views[3]);
            assert_eq!(train.frames[f].time_s, frame.time_s);
        }
        let err = split_frames(&all, &names(&["cam5"]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("cam5") && err.contains("frames"), "{err}");
    }

    fn camera(name: &str, x: f64) -> Camera {
        Camera {
            name: name.into(),
            intrinsics: Intrinsics::from_hfov(16, 12, 60.0),
            distortion: Distortion::None,
            world_to_camera: WorldToCamera::from_parts(DMat3::IDENTITY, DVec3::new(x, 0.0, 4.0)),
        }
    }

    fn write_poses(dir: &Path, cameras: &[&str]) {
        let file = PosesFile {
            set: CameraSet::new(
                cameras
                    .iter()
                    .enumerate()
                    .map(|(i, n)| camera(n, i as f64))
                    .collect(),
            ),
            normalisation: Normalisation {
                centre: [1.0, 2.0, 3.0],
                scale: 0.5,
            },
            source: PoseSource::Import {
                path: "calibration.json".into(),
            },
            points_file: Some("points3d.ply".into()),
            num_points: 7,
            stills: Vec::new(),
        };
        write_json(&dir.join("cameras.json"), &file).unwrap();
    }

    #[test]
    fn poses_split_into_training_and_heldout_files() {
        let tmp = tempfile::tempdir().unwrap();
        write_poses(tmp.path(), &["cam0", "cam1", "cam4", "cam5"]);
        split_poses(
            tmp.path(),
            &names(&["cam5", "cam4"]),
            "the calibration c.json",
        )
        .unwrap();
        let train = PosesFile::read(&tmp.path().join("cameras.json")).unwrap();
        let held = PosesFile::read(&tmp.path().join(HELDOUT_FILE)).unwrap();
        let cams = |f: &PosesFile| {
            f.set
                .cameras
                .iter()
                .map(|c| c.name.clone())
                .collect::<Vec<_>>()
        };
        assert_eq!(cams(&train), ["cam0", "cam1"]);
        assert_eq!(cams(&held), ["cam4", "cam5"]);
        assert_eq!(held.normalisation, train.normalisation);
        assert_eq!(held.set.get("cam4"), Some(&camera("cam4", 2.0)));
        assert_eq!(
            (train.points_file.as_deref(), train.num_points),
            (Some("points3d.ply"), 7)
        );
        assert_eq!((held.points_file, held.num_points), (None, 0));
    }

    #[test]
    fn a_calibration_without_a_heldout_camera_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        write_poses(tmp.path(), &["cam0", "cam1", "cam4"]);
        let err = split_poses(
            tmp.path(),
            &names(&["cam4", "cam5"]),
            "the calibration c.json",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("the calibration c.json")
                && err.contains("cam5")
                && err.contains("heldout"),
            "{err}"
        );
        assert!(!err.contains("cam4,"), "{err}");
        assert!(!tmp.path().join(HELDOUT_FILE).exists());
        // Without held-out cameras nothing changes.
        let before = std::fs::read(tmp.path().join("cameras.json")).unwrap();
        split_poses(tmp.path(), &[], "x").unwrap();
        assert_eq!(
            std::fs::read(tmp.path().join("cameras.json")).unwrap(),
            before
        );
    }
}
