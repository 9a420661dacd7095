//! `work/poses/cameras.json`: the stage's output file, a camera set plus the
//! normalisation, where the poses came from and the sparse points file.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shared_types::{Camera, CameraSet};

use super::error::PosesError;
use super::normalise::Normalisation;
use crate::colmap_runner::ColmapTimings;

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
    /// The stills the solve registered, each named by its file name in `stills/`, with
    /// its own lens and size (normalised frame): more views of the static scene for the
    /// init's sweep. Empty for an imported calibration.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stills: Vec<Camera>,
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
