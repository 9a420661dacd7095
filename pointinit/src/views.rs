//! The training cameras' frames made ready for point maps, triangulation or the sweep:
//! read, checked against the calibrated size and undistorted to each camera's pinhole twin.

use std::path::Path;

use calib::undistort::{Fit, UndistortMap};
use image::RgbImage;
use shared_types::{Camera, CameraSet};

use crate::error::InitError;
use crate::inputs::ViewImage;

/// A training camera ready for point maps or the sweep: pinhole twin, its undistorted
/// frame, that frame's time.
pub struct View {
    pub camera: Camera,
    pub image: RgbImage,
    pub time: f64,
}

/// Read and undistort each training camera's frame among `images` (the earliest, if a
/// camera has several).
pub(crate) fn load_views(
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

/// A frame of `cam` read from `path` (checked against the calibrated size), undistorted
/// to the camera's pinhole twin when it has a lens; with that pinhole camera.
/// Reads the image of `camera` at `path`, refusing one whose size is not the camera's.
pub(crate) fn read_frame(camera: &Camera, path: &Path) -> Result<RgbImage, InitError> {
    let rgb = image::open(path)
        .map_err(|source| InitError::Image {
            path: path.into(),
            source,
        })?
        .to_rgb8();
    let want = (camera.intrinsics.width, camera.intrinsics.height);
    if rgb.dimensions() != want {
        return Err(InitError::ImageSize {
            path: path.into(),
            camera: camera.name.clone(),
            got: rgb.dimensions(),
            want,
        });
    }
    Ok(rgb)
}

pub(crate) fn pinhole_view(
    cam: &Camera,
    path: &Path,
    fit: Fit,
) -> Result<(Camera, RgbImage), InitError> {
    let rgb = read_frame(cam, path)?;
    undistorted(cam, rgb, fit, &path.display().to_string())
}

/// `image` of `cam` undistorted to the camera's pinhole twin when it has a lens, with
/// that pinhole camera; `what` names the image in an error.
pub(crate) fn undistorted(
    cam: &Camera,
    image: RgbImage,
    fit: Fit,
    what: &str,
) -> Result<(Camera, RgbImage), InitError> {
    if cam.distortion.is_none() {
        return Ok((cam.clone(), image));
    }
    let map = UndistortMap::new(cam, fit);
    let out = map
        .apply(&image)
        .map_err(|e| InitError::Config(format!("undistorting {what}: {e}")))?;
    Ok((map.pinhole().clone(), out))
}
