//! `rig`: cameras and time. Camera sources (video files, V4L2 devices, simulated
//! cameras), audio and flash synchronisation, frame re-alignment and extraction.
//!
//! Depends on `shared-types` (cameras, progress, atomic writes), not on the engine.

pub mod frames;
pub mod ingest;
pub mod media;
pub mod record;
pub mod rotation;
pub mod sim;
pub mod source;
pub mod sync;
pub mod video;
