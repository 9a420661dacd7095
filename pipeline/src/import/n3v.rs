//! Neural 3D Video (and any LLFF-style video dataset): `camNN.mp4` beside
//! `poses_bounds.npy`, an `N × 17` array of `float64` with one row per video in name
//! order. A row is a 3×5 matrix, row-major, then two depth bounds: columns 0–2 are the
//! camera-to-world rotation in LLFF's axes `[down, right, back]`, column 3 the camera's
//! centre, column 4 `[height, width, focal]`; the principal point is the image centre.
//! The dataset's protocol holds out `cam00`.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DMat3, DVec3};
use shared_types::camera::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::{Dataset, Footage, ImportError};

pub const POSES_FILE: &str = "poses_bounds.npy";
/// N3V's videos are 30 fps.
const FPS: f64 = 30.0;

pub fn read(source: &Path) -> Result<Dataset, ImportError> {
    let poses_path = source.join(POSES_FILE);
    let array = pointinit::npy::read_npy(&poses_path)
        .map_err(|e| ImportError::bad(&poses_path, e.to_string()))?;
    let rows = match array.shape[..] {
        [n, 17] => n,
        _ => {
            return Err(ImportError::bad(
                &poses_path,
                format!("shape {:?}, expected (cameras, 17)", array.shape),
            ));
        }
    };
    let mut videos: Vec<_> = std::fs::read_dir(source)
        .map_err(ImportError::io(source))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| rig::media::has_video_name(p))
        .collect();
    videos.sort();
    if videos.len() != rows {
        return Err(ImportError::bad(
            &poses_path,
            format!(
                "{rows} cameras, but {} holds {} videos; each row belongs to one video in name order",
                source.display(),
                videos.len()
            ),
        ));
    }
    let mut cameras = Vec::new();
    let mut footage = BTreeMap::new();
    for (row, video) in array.data.chunks_exact(17).zip(&videos) {
        let name = video
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if row.iter().any(|v| !v.is_finite()) {
            return Err(ImportError::bad(
                &poses_path,
                format!("camera {name}: its row holds NaN or infinite values"),
            ));
        }
        let at = |r: usize, c: usize| f64::from(row[r * 5 + c]);
        let col = |c: usize| DVec3::new(at(0, c), at(1, c), at(2, c));
        let (height, width, focal) = (at(0, 4), at(1, 4), at(2, 4));
        if !(height >= 1.0 && width >= 1.0) {
            return Err(ImportError::bad(
                &poses_path,
                format!("camera {name}: image size {width} × {height} is not a size"),
            ));
        }
        // LLFF's columns are the camera's down, right and back axes: OpenCV's x is right,
        // y down, z forward.
        let camera_to_world = DMat3::from_cols(col(1), col(0), -col(2));
        let rotation = camera_to_world.transpose();
        let (width, height) = (width.round() as u32, height.round() as u32);
        cameras.push(Camera {
            name: name.clone(),
            intrinsics: Intrinsics {
                width,
                height,
                fx: focal,
                fy: focal,
                cx: width as f64 / 2.0,
                cy: height as f64 / 2.0,
            },
            distortion: Distortion::None,
            world_to_camera: WorldToCamera::from_parts(rotation, -(rotation * col(3))),
        });
        footage.insert(name, Footage::Video(video.clone()));
    }
    let heldout = cameras
        .iter()
        .filter(|c| c.name == "cam00")
        .map(|c| c.name.clone())
        .collect();
    Ok(Dataset {
        cameras,
        footage,
        heldout,
        fps: Some(FPS),
    })
}
