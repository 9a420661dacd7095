//! The init stage's settings (`capture.toml [init]`): where the points come from, which
//! image pairs go through a point-map model, and the thresholds of every source, with
//! their defaults.

use std::path::PathBuf;

use calib::undistort::Fit;
use serde::{Deserialize, Serialize};

use crate::npy::OutputNames;
use crate::onnx::ModelConfig;
use crate::sweep;

/// Where the initial points should come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// `model` if set, else `pointmaps` if set, else the plane sweep of `moments` moments
    /// (unless `moments` is 0), else triangulated moments, else sparse points, else random.
    #[default]
    Auto,
    /// Run the ONNX model `model` (falls back when every pair is rejected).
    Onnx,
    /// Read exported point maps from `pointmaps` (falls back when every pair is rejected).
    Npy,
    /// Triangulate the known cameras' frames at `moments` moments with COLMAP (falls back
    /// to the sparse points when COLMAP is missing or no moment gives points).
    Triangulate,
    /// Dense plane-sweep stereo of the known cameras' frames at `moments` moments
    /// ([`sweep`]; falls back to triangulation, then the sparse points, when no depth is
    /// confirmed).
    Sweep,
    /// The sparse COLMAP points (falls back to random when there are none).
    Sparse,
    /// A random cloud in the cameras' common view volume.
    Random,
}

/// Which image pairs go through the model: `"all"` or a list of `[first, second]` names.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Pairs {
    Keyword(PairsKeyword),
    List(Vec<[String; 2]>),
}

/// The keyword form of [`Pairs`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairsKeyword {
    /// Every pair of cameras (ONNX: each unordered pair once, in camera order; exported
    /// maps: every pair present in the directory).
    All,
}

impl Default for Pairs {
    fn default() -> Self {
        Pairs::Keyword(PairsKeyword::All)
    }
}

/// Settings of the init stage (`capture.toml [init]`). Lengths marked "× rig radius" are
/// fractions of the mean distance of the cameras from their centroid, so they do not
/// depend on the scene's units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitConfig {
    pub source: Source,
    /// ONNX point-map model.
    pub model: Option<PathBuf>,
    /// Directory of exported point maps (`a__b.npz` or `a__b/*.npy`).
    pub pointmaps: Option<PathBuf>,
    /// Model input names (first image, second image).
    pub input_names: [String; 2],
    /// Model output names, also the array names in exported files.
    pub output_names: OutputNames,
    /// `[width, height]` the images are resized to for the model.
    pub input_size: [u32; 2],
    pub pairs: Pairs,
    /// Pixels with a lower confidence are dropped (MASt3R confidences are ≥ 1).
    pub min_confidence: f32,
    /// Voxel edge for downsampling, × rig radius (0: no downsampling).
    pub voxel_size: f64,
    /// At most this many points are written (random subset, seeded).
    pub max_points: usize,
    /// Points of the random fallback cloud.
    pub random_points: usize,
    /// A source that gives fewer points than this (a few dozen triangulated across wide
    /// baselines) is topped up with the random cloud (0: never).
    pub min_points: usize,
    pub seed: u64,
    /// A pair is rejected when its ray scale and sparse-point scale differ by more than
    /// this fraction.
    pub scale_tolerance: f64,
    /// A pair is rejected when its median reprojection error in the second camera exceeds
    /// this fraction of the map width; second-view pixels above it are dropped.
    pub max_residual: f64,
    /// Sparse points needed for the sparse scale check of a pair.
    pub min_sparse_matches: usize,
    /// A pair is rejected when more than this fraction of its pixels is not finite.
    pub max_non_finite: f64,
    /// Undistortion field of view for the images fed to the model (and to COLMAP).
    pub fit: Fit,
    /// Moments of the clip to triangulate (evenly spread over the aligned frames; 0: off).
    pub moments: usize,
    /// Triangulated points must be seen by at least this many cameras (≥ 2).
    pub min_track: usize,
    /// A triangulated point with a point of another moment this close is static, × rig
    /// radius; static points this close are merged.
    pub static_radius: f64,
    /// Add the poses stage's sparse points to the triangulated ones, as static points.
    pub merge_sparse: bool,
    /// The `colmap` binary for triangulation; `None`: `$COLMAP_BIN`, then `PATH`.
    pub colmap: Option<PathBuf>,
    /// Plane sweep: long side (pixels) the frames are shrunk to.
    pub sweep_size: u32,
    /// Plane sweep: most depth planes per camera (they are one pixel of motion apart).
    pub sweep_max_planes: usize,
    /// Plane sweep: least NCC of a pixel's best match for it to take a depth.
    pub sweep_min_score: f32,
    /// Plane sweep: cameras whose depth maps must agree on a point (≥ 2).
    pub sweep_min_views: usize,
    /// Plane sweep: a swept point with fewer other points than this within 3 voxels is
    /// dropped as a false match (0, the default: keep all; dense captures gain, sparse
    /// wide-baseline ones lose real points).
    pub min_neighbours: usize,
    /// Plane sweep: also sweep level planes and planes facing each camera's side, for
    /// floors and walls seen at a grazing angle (three times the work).
    pub sweep_slanted: bool,
    /// Plane sweep: also sweep the static scene as the cameras' static plates and the
    /// stills the poses stage registered show it (each view against its best-placed
    /// partners): stills see surfaces that only one video camera frames.
    pub sweep_stills: bool,
    /// Frames per camera, spread over the clip, whose per-pixel median is the camera's
    /// static plate; points of several moments are then told static or moving by where
    /// they land on each moment's moving pixels ([`crate::plates`]). 0: by `static_radius`
    /// alone (cameras that move during the clip).
    pub plates: usize,
    /// Least difference (0..255, in some colour channel) of a frame from its camera's
    /// plate for a pixel to count as moving.
    pub motion_threshold: u8,
}

impl Default for InitConfig {
    fn default() -> Self {
        let m = ModelConfig::default();
        Self {
            source: Source::Auto,
            model: None,
            pointmaps: None,
            input_names: m.input_names,
            output_names: m.output_names,
            input_size: m.input_size,
            pairs: Pairs::default(),
            min_confidence: 1.5,
            voxel_size: 0.004,
            max_points: 300_000,
            random_points: 50_000,
            min_points: 1000,
            seed: 0,
            scale_tolerance: 0.15,
            max_residual: 0.02,
            min_sparse_matches: 20,
            max_non_finite: 0.5,
            fit: Fit::ValidPixels,
            moments: 6,
            min_track: 2,
            static_radius: 0.008,
            merge_sparse: true,
            colmap: None,
            sweep_size: 320,
            sweep_max_planes: 512,
            sweep_min_score: 0.7,
            sweep_min_views: 2,
            sweep_slanted: true,
            sweep_stills: true,
            min_neighbours: 0,
            plates: 48,
            motion_threshold: crate::plates::MOTION_THRESHOLD,
        }
    }
}

impl InitConfig {
    /// The model part of the settings.
    pub fn model_config(&self) -> ModelConfig {
        ModelConfig {
            input_names: self.input_names.clone(),
            output_names: self.output_names.clone(),
            input_size: self.input_size,
        }
    }

    /// The plane-sweep part of the settings.
    pub fn sweep_options(&self) -> sweep::SweepOptions {
        sweep::SweepOptions {
            size: self.sweep_size,
            max_planes: self.sweep_max_planes,
            min_score: self.sweep_min_score,
            min_views: self.sweep_min_views,
            slanted: self.sweep_slanted,
        }
    }
}
