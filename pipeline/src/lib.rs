//! The stage graph, capture directory, manifests and the `pipeline` command.
//!
//! `layout` validates a capture directory, `config` reads `capture.toml`, `stages`
//! declares the pipeline, `runner` decides what is stale and runs it with atomic
//! outputs (`manifest`, `atomic`, `lock`), `report` shows progress, `cli` is the
//! command line.

pub mod atomic;
pub mod cli;
pub mod config;
pub mod layout;
pub mod lock;
pub mod manifest;
pub mod report;
pub mod runner;
pub mod simulate;
pub mod stage;
pub mod stages;
pub mod status;

use std::path::Path;

pub use config::CaptureConfig;
pub use layout::Capture;

/// Read the settings and validate the layout of a capture directory, writing nothing.
pub fn open_capture(dir: &Path) -> anyhow::Result<(Capture, CaptureConfig)> {
    if !dir.exists() {
        return Err(layout::LayoutError::NoCaptureDir(dir.to_path_buf()).into());
    }
    if !dir.is_dir() {
        return Err(layout::LayoutError::NotADirectory(dir.to_path_buf()).into());
    }
    let config = CaptureConfig::load(dir)?;
    let capture = layout::validate(dir, config.capture.cameras)?;
    Ok((capture, config))
}
