//! The validated scene: a scene file parsed ([`super::schema`]), checked and resolved
//! ([`super::validate`]), and checked to show every camera some geometry
//! ([`super::check_views`]). What [`super::simulate`] and the live sources take.

use std::path::Path;

use super::error::SimError;
use super::schema::{CameraRole, SceneFile, SimCamera};
use super::validate::{exact_fps, validate};

/// A parsed and validated scene, ready for [`super::simulate`].
#[derive(Clone, Debug)]
pub struct Scene {
    pub(crate) file: SceneFile,
    /// Name used in error messages (the file path or the given origin).
    pub origin: String,
    pub cameras: Vec<SimCamera>,
}

impl Scene {
    /// Read and validate a scene file.
    pub fn from_file(path: &Path) -> Result<Scene, SimError> {
        let text = std::fs::read_to_string(path).map_err(|source| SimError::ReadScene {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Parse and validate a scene from TOML text; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Scene, SimError> {
        let mut file: SceneFile = toml::from_str(text).map_err(|e| SimError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })?;
        file.scene.fps = exact_fps(file.scene.fps, origin)?;
        let cameras = validate(&file, origin)?;
        let scene = Scene {
            file,
            origin: origin.to_string(),
            cameras,
        };
        super::check_views(&scene)?;
        Ok(scene)
    }

    pub fn name(&self) -> &str {
        &self.file.scene.name
    }
    pub fn duration(&self) -> f64 {
        self.file.scene.duration
    }
    pub fn fps(&self) -> f64 {
        self.file.scene.fps
    }
    pub fn seed(&self) -> u64 {
        self.file.scene.seed
    }
    /// Frames each video camera records (before drops): `round(duration · fps)`.
    pub fn frames_per_camera(&self) -> u32 {
        (self.duration() * self.fps()).round().max(1.0) as u32
    }
    pub fn video_cameras(&self) -> impl Iterator<Item = &SimCamera> {
        self.cameras.iter().filter(|c| c.role == CameraRole::Video)
    }
    /// Whether the held-out cameras are also filmed as videos (`[cameras] heldout_videos`).
    pub fn films_heldout(&self) -> bool {
        self.file.cameras.heldout_videos
    }
    /// The same scene with its held-out cameras filmed as videos (`raw/heldoutN/`) or not.
    pub fn with_heldout_videos(mut self, on: bool) -> Scene {
        self.file.cameras.heldout_videos = on;
        self
    }
    /// Whether the scene records audio (an `[audio]` table with `enabled = true`).
    pub fn audio_enabled(&self) -> bool {
        self.file.audio.as_ref().is_some_and(|a| a.enabled)
    }
}
