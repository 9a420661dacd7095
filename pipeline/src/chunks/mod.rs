//! Long captures in time chunks: a clip longer than `[chunks] seconds` is trained as
//! consecutive chunks, each its own model over its frames plus an overlap on both sides,
//! so train's memory and each model's detail per second do not depend on the clip's
//! length. The static scene is trained once, with the first chunk, frozen as static
//! Gaussians and shared by every later chunk (walls do not flicker from chunk to chunk,
//! and no chunk pays for them again). The chunks' moving Gaussians are merged into one
//! `model.bin`, each chunk keeping those whose time centre lies in its own part of the
//! clip, so render, eval, export and the viewer see one model of the whole clip.
//!
//! - `plan`: which aligned frames each chunk trains on and which part of the clip it owns.
//! - `static_scene`: the first chunk's model split into what stands still and what moves;
//!   the still part frozen into static Gaussians.
//! - `plates`: the static scene refined on each camera's static plate of the whole clip.
//! - `runner`: trains the chunks one after another (each resumable on its own), and merges.

pub mod plan;
pub mod plates;
pub mod runner;
pub mod static_scene;

use serde::{Deserialize, Serialize};

/// `[chunks]`: how a long clip is cut for training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChunkSettings {
    /// Target length of a chunk in seconds; the clip is cut into `round(length / seconds)`
    /// equal chunks (a clip up to 1.5 × this long stays one model). 0: one model for the
    /// whole clip, however long.
    pub seconds: f64,
    /// Seconds of the neighbouring chunks each chunk also trains on, on both sides, so
    /// that what crosses a boundary is learnt by both.
    pub overlap_seconds: f64,
    /// Steps that refine the first chunk's static scene on every camera's static plate of
    /// the whole clip (`plates`), so that it also holds what the first chunk never saw. 0:
    /// the first chunk's static scene as it is.
    pub static_steps: u64,
}

impl Default for ChunkSettings {
    fn default() -> Self {
        Self {
            seconds: 5.0,
            overlap_seconds: 0.5,
            static_steps: 300,
        }
    }
}
