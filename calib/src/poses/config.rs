//! Settings of the poses stage (`capture.toml [poses]`) and what the stage is given.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use shared_types::{Distortion, Intrinsics};

use crate::colmap_runner::ColmapConfig;

/// Settings of the poses stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PosesConfig {
    pub colmap: ColmapConfig,
    /// Fewer stills than this is refused before COLMAP runs.
    pub min_stills: usize,
    /// Mean distance of the video cameras from the scene centre after normalisation.
    pub radius: f64,
    /// Camera folder → its camera's name in an imported calibration, for folders whose
    /// calibration camera has another name (`names = { cam0 = "cam01" }`).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub names: BTreeMap<String, String>,
    /// A calibration file (relative to the capture directory) whose lenses are known:
    /// COLMAP solves only the poses of the video cameras it holds, keeping their
    /// intrinsics and distortion fixed. Extrinsics in it are not needed (and ignored).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub intrinsics: Option<PathBuf>,
    /// Units of an imported calibration's translations (`"m"`, `"cm"`, `"mm"`),
    /// overriding a `units` key in the file (CMU Panoptic's files are in centimetres and
    /// do not say so). Unset: the file's own `units`, else metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<crate::import::Units>,
}

impl Default for PosesConfig {
    fn default() -> Self {
        Self {
            colmap: ColmapConfig::default(),
            min_stills: 4,
            radius: 1.0,
            names: BTreeMap::new(),
            intrinsics: None,
            units: None,
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
    /// Video cameras whose lens is known (`[poses] intrinsics`), by camera name, with
    /// intrinsics for the size of their frame in `video_frames`: COLMAP keeps them exactly
    /// (only poses and points are solved). Empty: every lens is solved.
    pub known_lenses: BTreeMap<String, (Intrinsics, Distortion)>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colmap_runner::{StillsCameras, VideoCameras};

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
        assert!(c.names.is_empty());
        // An empty `names` leaves the stage's parameters (its JSON) as they were.
        assert!(!serde_json::to_string(&c).unwrap().contains("names"));
        let c: PosesConfig = toml::from_str("names = { cam0 = \"cam01\" }").unwrap();
        assert_eq!(c.names["cam0"], "cam01");
        assert!(toml::from_str::<PosesConfig>("min_still = 3").is_err());
        assert!(toml::from_str::<PosesConfig>("[colmap]\ncamera_model = \"BROWN\"").is_err());
    }
}
