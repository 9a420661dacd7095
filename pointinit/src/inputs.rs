//! What the init stage is given: the posed cameras, their first frames, the sparse points
//! and the frames at each moment to triangulate or sweep. Plain values: this crate reads no
//! pipeline files (frames index, stage manifests) itself.

use std::path::PathBuf;

use shared_types::{Camera, CameraSet};

/// One image of a training camera: its first frame (distorted, at the cameras' working
/// size) and that frame's time (the model's time axis; written to each point).
#[derive(Clone, Debug, PartialEq)]
pub struct ViewImage {
    pub camera: String,
    pub path: PathBuf,
    pub time: f64,
}

/// What the init stage is given.
#[derive(Clone, Debug)]
pub struct InitInputs {
    /// The training cameras (`work/poses/cameras.json`), with their lens.
    pub cameras: CameraSet,
    /// First frame of each camera (if a camera has several, the earliest is used).
    pub images: Vec<ViewImage>,
    /// `work/poses/points3d.ply`, if the poses stage wrote one.
    pub sparse: Option<PathBuf>,
    /// Frames of every training camera at each moment to triangulate (the first config
    /// `moments` of them are used; empty: no triangulation).
    pub moments: Vec<Moment>,
    /// Frames of every training camera spread over the clip, for the cameras' static
    /// plates (`[init] plates` of them per camera; empty: no plates).
    pub plate_frames: Vec<ViewImage>,
    /// Stills of the static scene with their cameras (lens and size their own), for the
    /// static sweep (`[init] sweep_stills`; empty: none).
    pub stills: Vec<StillImage>,
}

/// A still photo of the scene and its camera (`work/poses/cameras.json` → `stills`).
#[derive(Clone, Debug, PartialEq)]
pub struct StillImage {
    pub camera: Camera,
    pub path: PathBuf,
}

/// The training cameras' frames at one moment.
#[derive(Clone, Debug, PartialEq)]
pub struct Moment {
    /// Aligned frame index (`frames.json`), for the report.
    pub frame: usize,
    /// Model time of the moment (the mean of its views' times).
    pub time: f64,
    /// One frame per camera; each keeps its own time.
    pub views: Vec<ViewImage>,
}
