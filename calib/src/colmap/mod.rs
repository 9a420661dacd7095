//! COLMAP sparse models: cameras, images and 3D points, read and written in both of
//! COLMAP's formats (`.bin` little-endian and `.txt`), one reader/writer per file kind
//! ([`binary`], [`text`]). IDs are kept as COLMAP wrote them (they need not be contiguous).
//!
//! Conventions are COLMAP's: world-to-camera pose `x_cam = R(q)·x_world + t`, Hamilton
//! quaternion `(qw, qx, qy, qz)`, pixel centres at integer + 0.5.
//! This module does file IO only; turning a model's images into engine cameras is
//! [`crate::convert::camera_from_image`].

pub mod binary;
mod camera_model;
pub mod text;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use shared_types::atomic::write_atomic;

pub use camera_model::CameraModel;

/// COLMAP's "no 3D point" marker in an image's 2D point list.
pub const INVALID_POINT3D_ID: u64 = u64::MAX;

/// One COLMAP camera (intrinsics shared by the images that use it).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: CameraModel,
    pub width: u64,
    pub height: u64,
    /// Parameters in COLMAP's order for `model` (see [`CameraModel::param_names`]).
    pub params: Vec<f64>,
}

/// One 2D feature of an image, possibly the observation of a 3D point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point2D {
    pub xy: [f64; 2],
    /// [`INVALID_POINT3D_ID`] when the feature has no 3D point.
    pub point3d_id: u64,
}

/// One registered image: its pose and its 2D features.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation, Hamilton `(qw, qx, qy, qz)`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    pub camera_id: u32,
    /// File name relative to the image folder COLMAP was given (may contain `/`).
    pub name: String,
    pub points2d: Vec<Point2D>,
}

/// One element of a 3D point's track: which image saw it, and which of its 2D points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TrackElement {
    pub image_id: u32,
    pub point2d_idx: u32,
}

/// One triangulated 3D point.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint3D {
    pub id: u64,
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
    /// Mean reprojection error in pixels.
    pub error: f64,
    pub track: Vec<TrackElement>,
}

/// A whole sparse model (`cameras`, `images`, `points3D`), keyed by COLMAP ID.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    pub cameras: BTreeMap<u32, ColmapCamera>,
    pub images: BTreeMap<u32, ColmapImage>,
    pub points3d: BTreeMap<u64, ColmapPoint3D>,
}

/// Which of COLMAP's two model formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelFormat {
    Binary,
    Text,
}

impl ModelFormat {
    pub fn extension(self) -> &'static str {
        match self {
            ModelFormat::Binary => "bin",
            ModelFormat::Text => "txt",
        }
    }

    /// The path of model file `name` (`cameras`, `images`, `points3D`) in `dir`.
    fn file(self, dir: &Path, name: &str) -> PathBuf {
        dir.join(format!("{name}.{}", self.extension()))
    }
}

/// Errors reading or writing a COLMAP model. Each names the file and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("cannot read or write COLMAP model file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{dir} holds no COLMAP model: expected cameras, images and points3D as .bin or .txt \
         (COLMAP writes them to sparse/0/; `colmap model_converter` converts between formats)"
    )]
    NotAModel { dir: PathBuf },
    #[error("{path}: {what} (is this file complete and written by COLMAP?)")]
    Malformed { path: PathBuf, what: String },
    #[error("{path}: unknown COLMAP camera model {model}")]
    UnknownCameraModel { path: PathBuf, model: String },
    #[error(
        "{path}: camera {camera_id} of model {model} has {got} parameters, expected {expected}"
    )]
    ParamCount {
        path: PathBuf,
        camera_id: u32,
        model: &'static str,
        got: usize,
        expected: usize,
    },
}

impl ColmapCamera {
    /// A camera, checking the parameter count against the model.
    pub fn new(
        id: u32,
        model: CameraModel,
        width: u64,
        height: u64,
        params: Vec<f64>,
    ) -> Option<Self> {
        (params.len() == model.num_params()).then_some(Self {
            id,
            model,
            width,
            height,
            params,
        })
    }
}

impl ColmapImage {
    /// World-to-camera rotation matrix.
    pub fn rotation(&self) -> DMat3 {
        let [w, x, y, z] = self.qvec;
        DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize())
    }

    pub fn translation(&self) -> DVec3 {
        DVec3::from_array(self.tvec)
    }

    /// Camera centre in world coordinates, `−Rᵀ t`.
    pub fn centre(&self) -> DVec3 {
        -(self.rotation().transpose() * self.translation())
    }

    /// Number of 2D points with a 3D point.
    pub fn num_observations(&self) -> usize {
        self.points2d
            .iter()
            .filter(|p| p.point3d_id != INVALID_POINT3D_ID)
            .count()
    }
}

impl ColmapModel {
    /// Read the model in `dir`, in whichever format is there (binary preferred when both).
    pub fn read(dir: &Path) -> Result<Self, ModelError> {
        let format = Self::detect_format(dir).ok_or_else(|| ModelError::NotAModel {
            dir: dir.to_path_buf(),
        })?;
        let file = |name: &str| format.file(dir, name);
        let (cameras, images, points3d) = match format {
            ModelFormat::Binary => (
                binary::read_cameras(&file("cameras"))?,
                binary::read_images(&file("images"))?,
                binary::read_points3d(&file("points3D"))?,
            ),
            ModelFormat::Text => (
                text::read_cameras(&file("cameras"))?,
                text::read_images(&file("images"))?,
                text::read_points3d(&file("points3D"))?,
            ),
        };
        Ok(ColmapModel {
            cameras: cameras.into_iter().map(|c| (c.id, c)).collect(),
            images: images.into_iter().map(|i| (i.id, i)).collect(),
            points3d: points3d.into_iter().map(|p| (p.id, p)).collect(),
        })
    }

    /// The format of the model in `dir`, if a complete one is there.
    pub fn detect_format(dir: &Path) -> Option<ModelFormat> {
        [ModelFormat::Binary, ModelFormat::Text]
            .into_iter()
            .find(|f| {
                ["cameras", "images", "points3D"]
                    .iter()
                    .all(|n| f.file(dir, n).is_file())
            })
    }

    /// Write the model to `dir` (created if needed) in `format`. Each file is written
    /// under a temporary name and renamed, so a reader never sees a half-written file.
    pub fn write(&self, dir: &Path, format: ModelFormat) -> Result<(), ModelError> {
        std::fs::create_dir_all(dir).map_err(|source| ModelError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let files = match format {
            ModelFormat::Binary => [
                ("cameras", binary::cameras_to_bytes(self.cameras.values())),
                ("images", binary::images_to_bytes(self.images.values())),
                (
                    "points3D",
                    binary::points3d_to_bytes(self.points3d.values()),
                ),
            ],
            ModelFormat::Text => [
                (
                    "cameras",
                    text::cameras_to_text(self.cameras.values()).into_bytes(),
                ),
                (
                    "images",
                    text::images_to_text(self.images.values()).into_bytes(),
                ),
                (
                    "points3D",
                    text::points3d_to_text(self.points3d.values()).into_bytes(),
                ),
            ],
        };
        for (name, bytes) in files {
            let path = format.file(dir, name);
            write_atomic(&path, &bytes).map_err(|source| ModelError::Io { path, source })?;
        }
        Ok(())
    }

    /// The image with this file name (as COLMAP stores it, e.g. `video/cam0.png`).
    pub fn image_by_name(&self, name: &str) -> Option<&ColmapImage> {
        self.images.values().find(|i| i.name == name)
    }
}
