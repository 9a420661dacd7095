//! The stage graph, capture directory, manifests and the `pipeline` command.
//!
//! - `layout` validates a capture directory (reads only); `config` reads `capture.toml`,
//!   gathering the settings section of each stage.
//! - `stages` lists the pipeline's stages, in order, with one module per stage holding its
//!   work and its settings section; `stage_def` is what a stage declares, `stage_context`
//!   what a running stage sees.
//! - Shared by several stages: `engine_inputs` (earlier stages' outputs loaded for the
//!   engine: frames, pinhole cameras, the trained model), `heldout` (held-out cameras
//!   split off the training ones), `masks` (moving-region masks for eval), `interrupt`
//!   (Ctrl-C stops training cleanly).
//! - `chunks` trains a long clip in time chunks (the plan, the shared static scene, the
//!   runner that trains and merges them), for the `train` stage.
//! - `runner` decides what is stale and runs it, with `manifest` (`stage.json`),
//!   `partial_dir` (outputs appear only when complete) and `lock` (one run per capture).
//! - `cluster` runs captures on Slurm (`submit`, `cancel`, the jobs in `status`): each
//!   stale stage one job, chained by `afterok`.
//! - `report` shows progress, `status` prints the table, `cli` is the command line;
//!   `simulate` and `ablation` are the `simulate`/`demo` and `bench ablation` commands,
//!   `bench` the `bench sync` and `bench poses` commands (and their resumable results table),
//!   `compare` the `metrics` command (image metrics between two images or folders), `view`
//!   the `view` command (the exported viewers served on 127.0.0.1).
#![cfg_attr(not(feature = "ffmpeg"), allow(unused))]

pub mod bench;
pub mod chunks;
pub mod cli;
pub mod cluster;
pub mod compare;
pub mod config;
pub mod disk;
pub mod engine_inputs;
pub mod heldout;
pub mod import;
pub mod interrupt;
pub mod layout;
pub mod lock;
pub mod manifest;
pub mod masks;
pub mod partial_dir;
pub mod presets;
pub mod ranges;
pub mod report;
pub mod runner;
pub mod simulate;
pub mod stage_context;
pub mod stage_def;
pub mod stages;
pub mod status;
pub mod view;

use std::path::Path;

/// The error of a stage or command that reads or writes videos, in a build without FFmpeg
/// (`--no-default-features`: the engine-only binary for GPU nodes, which trains, renders,
/// evaluates and exports a capture prepared by the full build).
#[cfg(not(feature = "ffmpeg"))]
pub fn without_ffmpeg(what: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "{what} reads or writes videos, and this pipeline was built without FFmpeg (the \
         engine-only build: train, render, eval and export); run it with the full build \
         (`cargo build --release -p pipeline`), which can share the capture directory"
    )
}

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
    let capture = layout::validate_rig(dir, config.capture.cameras, &config.capture.heldout)?;
    Ok((capture, config))
}

/// An error with its causes, each cause shown once: library errors often repeat their
/// source in their own message, and anyhow's `{:#}` would print it again.
pub fn error_chain(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&cause);
        }
    }
    text
}

#[cfg(test)]
mod tests {
    #[test]
    fn error_chain_shows_each_cause_once() {
        let io = std::io::Error::other("disk on fire");
        let e = anyhow::Error::new(io)
            .context("cannot write a.txt: disk on fire")
            .context("stage x");
        assert_eq!(
            super::error_chain(&e),
            "stage x: cannot write a.txt: disk on fire"
        );
    }
}
