//! Command-line interface of the `pipeline` binary.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, builder::PossibleValuesParser};

use crate::stages::STAGE_NAMES;

/// Turn four cameras' recordings into a 4D Gaussian model you can render from any
/// viewpoint at any moment (4C4D: 4 Camera 4D Gaussian Splatting).
///
/// Stages, in order: ingest → sync → frames → poses → init → train → render → eval → export.
/// Each writes work/<stage>/ in the capture directory and is skipped when its inputs and
/// settings have not changed.
#[derive(Debug, Parser)]
#[command(name = "pipeline", version, propagate_version = true)]
pub struct Cli {
    /// More log output (-v: debug, -vv: trace).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    /// Print only errors (no progress bars).
    #[arg(short, long, global = true, conflicts_with = "json")]
    pub quiet: bool,
    /// Print machine-readable JSON lines on stdout instead of progress bars.
    #[arg(long, global = true)]
    pub json: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the pipeline (or part of it) on a capture directory.
    ///
    /// A capture directory holds raw/cam0/ … raw/cam3/ (each camera's videos), stills/
    /// (eight extra photos for pose solving) and optionally capture.toml (settings).
    /// Stages whose inputs and settings are unchanged since their last run are skipped.
    ///
    /// Example: pipeline run my_capture/ --from frames --to train
    Run(RunArgs),
    /// Show each stage's state: done, stale (and why), missing, or failed.
    ///
    /// Example: pipeline status my_capture/
    Status {
        /// The capture directory.
        capture_dir: PathBuf,
    },
    /// Simulate a capture of a built-in scene and run every stage on it.
    ///
    /// The capture is simulated once; running the demo again on the same folder reuses it
    /// and reruns only what is not up to date.
    ///
    /// Example: pipeline demo /tmp/4c4d-demo
    Demo {
        /// Where to write the simulated capture and its outputs.
        #[arg(default_value = "4c4d-demo")]
        out_dir: PathBuf,
    },
    /// Record up to four V4L2 webcams at once into a new capture directory
    /// (raw/camN/capture.mov + kernel timestamps per frame). Stop with Ctrl-C or --seconds.
    ///
    /// Example: pipeline record --device /dev/video0 --device /dev/video2 --seconds 20 my_capture/
    Record(RecordArgs),
    /// Render a scene file (TOML) into a new capture directory with simulated cameras:
    /// videos with audio in raw/camN/, stills/, and the ground truth in groundtruth/.
    ///
    /// The scene format is described in docs/simulator.md; examples are in fixtures/.
    ///
    /// Example: pipeline simulate fixtures/tiny.toml /tmp/tiny-capture
    Simulate {
        /// The scene file.
        scene: PathBuf,
        /// The capture directory to create (must not already hold a capture).
        capture_dir: PathBuf,
    },
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// The capture directory (holds raw/, stills/, capture.toml).
    pub capture_dir: PathBuf,
    /// Start at this stage (earlier stages must have run).
    #[arg(long, value_parser = PossibleValuesParser::new(STAGE_NAMES))]
    pub from: Option<String>,
    /// Stop after this stage.
    #[arg(long, value_parser = PossibleValuesParser::new(STAGE_NAMES))]
    pub to: Option<String>,
    /// Run just this stage.
    #[arg(long, value_parser = PossibleValuesParser::new(STAGE_NAMES), conflicts_with_all = ["from", "to"])]
    pub only: Option<String>,
    /// Rerun the selected stages even if they are up to date.
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, Args)]
pub struct RecordArgs {
    /// A V4L2 device to record (repeat for each camera, up to 4).
    #[arg(long = "device", value_name = "DEVICE")]
    pub devices: Vec<PathBuf>,
    /// The capture directory to create (must not already hold a capture).
    pub capture_dir: PathBuf,
    /// Stop after this many seconds (default: when Ctrl-C is pressed).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Wanted frame width, pixels.
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// Wanted frame height, pixels.
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Wanted frames per second.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Do not prompt for a sync flash or clap once all cameras run.
    #[arg(long)]
    pub no_flash_prompt: bool,
}
