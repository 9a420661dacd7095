//! `rig`: cameras and time. Camera sources (video files, V4L2 devices, simulated
//! cameras), audio and flash synchronisation, frame re-alignment and extraction.
//!
//! Depends on `shared-types` (cameras, progress, atomic writes), not on the engine.
//!
//! Feature `ffmpeg` (default) reads and writes videos; without it only what training and
//! rendering read is built (the frames index, sync results, the simulator's scenes and
//! renders), and the helpers only video work uses are unused.
#![cfg_attr(not(feature = "ffmpeg"), allow(unused, dead_code))]

pub mod frames;
pub mod ingest;
pub mod media;
#[cfg(feature = "ffmpeg")]
pub mod record;
pub mod rotation;
pub mod sim;
#[cfg(feature = "ffmpeg")]
pub mod source;
pub mod sync;
#[cfg(feature = "ffmpeg")]
pub mod video;
