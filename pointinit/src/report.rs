//! What the init stage did (`init.json`, `stage.json`): the source used, the fallbacks
//! taken, each point-map pair, moment and sweep, and the point counts.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::moments::MomentReport;
use crate::statics::StaticCounts;
use crate::sweep;

/// Which source produced `points.ply`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UsedSource {
    Onnx,
    Npy,
    Triangulated,
    Swept,
    Sparse,
    Random,
}

/// The outcome of one image pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairReport {
    pub first: String,
    pub second: String,
    /// Aligned frame of the pair's images, when point maps of several moments were used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<usize>,
    pub accepted: bool,
    /// Why it was rejected (`None` when accepted).
    pub reason: Option<String>,
    /// Scale applied to the pair's maps (`None` when no scale was found).
    pub scale: Option<f64>,
    /// Scale from the second view's rays.
    pub ray_scale: Option<f64>,
    /// Scale from the sparse points, and how many points gave it.
    pub sparse_scale: Option<f64>,
    pub sparse_matches: usize,
    /// Median reprojection error in the second camera (fraction of the map width).
    pub residual: Option<f64>,
    /// Pixels of both maps, non-finite pixels, confident finite pixels, points kept.
    pub pixels: usize,
    pub non_finite: usize,
    pub confident: usize,
    pub points: usize,
}

/// What [`run_init`](crate::run_init) did, for the log and `stage.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InitReport {
    pub source: UsedSource,
    /// Each fallback taken, with its reason, in order.
    pub fallbacks: Vec<String>,
    pub pairs: Vec<PairReport>,
    /// Each triangulated moment (empty when triangulation did not run).
    #[serde(default)]
    pub moments: Vec<MomentReport>,
    /// Each swept moment (empty when the sweep did not run).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sweeps: Vec<sweep::SweepReport>,
    /// The sweep of the static scene in the static plates and the stills (`None`: no
    /// stills, or `[init] sweep_stills` off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub still_sweep: Option<sweep::SweepReport>,
    /// Static/moving split of the triangulated points (zero unless triangulated).
    #[serde(default)]
    pub statics: StaticCounts,
    /// The static plates that told swept or triangulated points static or moving (`None`:
    /// no plates, the repetition test decided).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plates: Option<PlatesReport>,
    /// Swept points dropped for having fewer than `min_neighbours` neighbours.
    #[serde(default)]
    pub isolated: usize,
    /// Points before downsampling (from the source), after voxel downsampling, written.
    pub points_before: usize,
    pub points_after_voxel: usize,
    pub points_written: usize,
    /// Voxel edge used, in world units.
    pub voxel: f64,
    /// The written cloud (the pipeline records it relative to `work/init/`).
    pub output: PathBuf,
    pub seconds: f64,
}

/// What the static plates did ([`crate::plates`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PlatesReport {
    /// Cameras with a plate, and frames per camera behind each.
    pub cameras: usize,
    pub frames_per_camera: usize,
    /// Per moment: the fraction of the frames' pixels that moved (mean over cameras).
    pub moving_fraction: Vec<f64>,
}
