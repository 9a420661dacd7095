//! Command-line interface of the `pipeline` binary.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, builder::PossibleValuesParser};

use crate::engine_inputs::BackendChoice;
use crate::stages::pipeline;

/// Turn four cameras' recordings into a 4D Gaussian model you can render from any
/// viewpoint at any moment (4C4D: 4 Camera 4D Gaussian Splatting).
#[derive(Debug, Parser)]
#[command(
    name = "pipeline",
    version,
    propagate_version = true,
    after_long_help = stages_help()
)]
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
    /// Serve the captures' exported browser viewers (work/export/viewer/) on 127.0.0.1
    /// and open the first in the system's browser; Ctrl-C stops. Several captures are
    /// listed on one index page.
    ///
    /// Example: pipeline view my_capture/
    View {
        /// The capture directories (their export stage has run).
        #[arg(required = true)]
        capture_dirs: Vec<PathBuf>,
        /// Port on 127.0.0.1 (default 8765, or any free one when it is taken; 0: any).
        #[arg(long)]
        port: Option<u16>,
        /// Print the URL without opening a browser (servers, SSH sessions).
        #[arg(long)]
        no_open: bool,
    },
    /// Make a capture directory from a dataset folder laid out the way another tool lays
    /// it out: links to its videos or images in `raw/`, its calibration as
    /// `calibration.json`, and `capture.toml` with the dataset's held-out cameras and
    /// `timestamps` sync. Then `pipeline run DIR`.
    ///
    /// Example: pipeline import n3v coffee_martini/ cm4/ --train farthest:4 --frames 0..300
    Import {
        /// The dataset's layout.
        #[arg(value_enum)]
        format: crate::import::Format,
        /// The dataset's folder.
        source: PathBuf,
        /// The capture directory to make (new or empty).
        capture_dir: PathBuf,
        /// Training cameras: the dataset's names separated by commas, or `farthest:N` (the
        /// N cameras farthest apart: the 4C4D paper's sparse protocol). The others are held
        /// out. Default: the dataset's own protocol.
        #[arg(long)]
        train: Option<crate::import::TrainChoice>,
        /// Frames FIRST..END of the footage (END excluded).
        #[arg(long, value_parser = parse_frame_range)]
        frames: Option<(usize, usize)>,
        /// Working size: the long side of the frames, pixels (`[frames] long_side`).
        #[arg(long)]
        long_side: Option<u32>,
        /// Copy the footage instead of linking to it.
        #[arg(long)]
        copy: bool,
    },
    /// Show each stage's state: done, stale (and why), missing, or failed.
    ///
    /// Example: pipeline status my_capture/
    Status {
        /// The capture directory.
        capture_dir: PathBuf,
    },
    /// Run captures on a Slurm cluster: each stale stage of each capture becomes one
    /// batch job, waiting for the capture's previous job (`afterok`). Up-to-date stages
    /// are not submitted. Settings: `[cluster]` in capture.toml or
    /// ~/.config/4c4d/cluster.toml (docs/cluster.md).
    ///
    /// Example: pipeline submit take01/ take02/ --to train
    Submit(SubmitArgs),
    /// Cancel the Slurm jobs that `pipeline submit` queued for a capture and that have not
    /// finished.
    ///
    /// Example: pipeline cancel my_capture/
    Cancel {
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
        /// Backend of the `train`, `render` and `eval` stages (overrides `[engine] backend`).
        #[arg(long, value_enum)]
        backend: Option<BackendChoice>,
        /// Training preset (overrides the demo's schedule; README "Presets").
        #[arg(long, value_enum)]
        preset: Option<crate::presets::Preset>,
        /// Stop after this stage: `--to init` prepares what training reads, to train
        /// elsewhere (a GPU node, `scripts/gpu-check.sh --bundle-demo`).
        #[arg(long, value_parser = PossibleValuesParser::new(pipeline().stage_names()))]
        to: Option<String>,
    },
    /// Record up to four webcams at once into a new capture directory (raw/camN/capture.mov
    /// and each frame's capture time). Stop with Ctrl-C or --seconds. Cameras come through
    /// V4L2 (Linux) or nokhwa (Linux, macOS, Windows; a build with `--features nokhwa`).
    ///
    /// Examples: pipeline record --device /dev/video0 --device /dev/video2 --seconds 20 my_capture/
    ///           pipeline record --backend nokhwa --device 0 --device "C920" my_capture/
    ///           pipeline record --backend nokhwa --list
    Record(RecordArgs),
    /// Render the trained model of a capture along a camera path, outside the stage graph
    /// (the `render` stage does the same with the [render] settings).
    ///
    /// Example: pipeline render my_capture/ --path spiral --time fixed:1.0 --out spiral.mp4
    Render(RenderArgs),
    /// PSNR, SSIM, DSSIM1, DSSIM2 and LPIPS between two images, or between the
    /// same-named images of two folders (paired by name without extension, so 0001.png
    /// pairs with 0001.jpg) — e.g. renders against ground truth, or against another
    /// tool's renders. LPIPS is LPIPS-alex from the weights scripts/setup.sh installs.
    ///
    /// Examples: pipeline metrics render.png truth.png
    ///           pipeline metrics my_capture/work/render/rgb/ other_tool/renders/
    Metrics(MetricsArgs),
    /// Benchmarks that train and measure (numbers for BENCHMARKS.md).
    #[command(subcommand)]
    Bench(BenchCommand),
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
        /// Also write the point maps a perfect MASt3R would give, from the true depth, to
        /// pointmaps/ (use them with `[init] pointmaps = "pointmaps"`).
        #[arg(long)]
        truth_pointmaps: bool,
        /// Also write the true video cameras as `calibration.json`, so the poses stage
        /// imports them instead of running COLMAP (isolates later stages from pose errors).
        #[arg(long)]
        truth_calibration: bool,
    },
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// The capture directory (holds raw/, stills/, capture.toml).
    pub capture_dir: PathBuf,
    #[command(flatten)]
    pub stages: StageArgs,
}

#[derive(Debug, Args)]
pub struct SubmitArgs {
    /// The capture directories (each holds raw/, stills/, capture.toml).
    #[arg(required = true)]
    pub capture_dirs: Vec<PathBuf>,
    #[command(flatten)]
    pub stages: StageArgs,
}

/// Which stages to run and how: shared by `run` and `submit` (whose jobs run `run`).
#[derive(Debug, Args)]
pub struct StageArgs {
    /// Start at this stage (earlier stages must have run).
    #[arg(long, value_parser = PossibleValuesParser::new(pipeline().stage_names()))]
    pub from: Option<String>,
    /// Stop after this stage.
    #[arg(long, value_parser = PossibleValuesParser::new(pipeline().stage_names()))]
    pub to: Option<String>,
    /// Just this stage.
    #[arg(long, value_parser = PossibleValuesParser::new(pipeline().stage_names()), conflicts_with_all = ["from", "to"])]
    pub only: Option<String>,
    /// Rerun the selected stages even if they are up to date.
    #[arg(long)]
    pub force: bool,
    /// With `--only train`, on a clip cut into time chunks (`[chunks]`): train just this
    /// chunk (0 first), leaving the stage for a run that trains the rest and merges them.
    #[arg(long, requires = "only", conflicts_with = "force")]
    pub chunk: Option<usize>,
    /// Backend of the `train`, `render` and `eval` stages (overrides `[engine] backend`;
    /// on Slurm, `cpu` asks for no GPU).
    #[arg(long, value_enum)]
    pub backend: Option<BackendChoice>,
    /// Training preset: preview | balanced | best | full (overrides `[train] preset` and
    /// the iterations, resolution and Gaussian budget of capture.toml; README "Presets").
    #[arg(long, value_enum)]
    pub preset: Option<crate::presets::Preset>,
}

impl StageArgs {
    /// The stages these flags select.
    pub fn selection(&self) -> crate::runner::Selection {
        crate::runner::Selection {
            from: self.from.clone(),
            to: self.to.clone(),
            only: self.only.clone(),
            force: self.force,
            chunk: self.chunk,
        }
    }

    /// `config` with these flags' `--backend` and `--preset` applied.
    pub fn configure(
        &self,
        mut config: crate::config::CaptureConfig,
    ) -> crate::config::CaptureConfig {
        if let Some(b) = self.backend {
            config.engine.backend = b;
        }
        match self.preset {
            Some(p) => config.with_preset(p),
            None => config,
        }
    }

    /// The flags that carry over to a `pipeline run` of one stage (a Slurm job's command
    /// line): `--force`, `--backend`, `--preset`.
    pub fn run_flags(&self) -> Vec<String> {
        use clap::ValueEnum;
        let mut flags = Vec::new();
        if self.force {
            flags.push("--force".to_string());
        }
        if let Some(value) = self.backend.and_then(|b| b.to_possible_value()) {
            flags.extend(["--backend".to_string(), value.get_name().to_string()]);
        }
        if let Some(p) = self.preset {
            flags.extend(["--preset".to_string(), p.name().to_string()]);
        }
        flags
    }
}

/// The library `record` talks to the cameras through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RecordBackend {
    /// V4L2 directly (Linux): kernel timestamps, driver frame counters.
    V4l2,
    /// nokhwa: V4L2 on Linux, AVFoundation on macOS, Media Foundation on Windows (needs a
    /// build with `--features nokhwa`).
    Nokhwa,
}

#[cfg(feature = "ffmpeg")]
impl From<RecordBackend> for rig::record::CaptureBackend {
    fn from(b: RecordBackend) -> Self {
        match b {
            RecordBackend::V4l2 => rig::record::CaptureBackend::V4l2,
            RecordBackend::Nokhwa => rig::record::CaptureBackend::Nokhwa,
        }
    }
}

#[derive(Debug, Args)]
pub struct RecordArgs {
    /// A camera to record (repeat for each camera, up to 4): a device path for v4l2
    /// (/dev/video0); for nokhwa an index (0), /dev/videoN, or (part of) a camera's name.
    #[arg(long = "device", value_name = "DEVICE")]
    pub devices: Vec<String>,
    /// The capture directory to create (must not already hold a capture).
    #[arg(required_unless_present = "list")]
    pub capture_dir: Option<PathBuf>,
    /// Camera library: v4l2 or nokhwa (default: v4l2 on Linux, nokhwa elsewhere).
    #[arg(long, value_enum)]
    pub backend: Option<RecordBackend>,
    /// List the cameras the backend finds, then exit.
    #[arg(long)]
    pub list: bool,
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

#[derive(Debug, Args)]
pub struct MetricsArgs {
    /// An image, or a folder of images (the first of each pair: e.g. the renders).
    pub a: PathBuf,
    /// An image, or a folder of images (the second of each pair: e.g. the ground truth).
    pub b: PathBuf,
    /// LPIPS network: LPIPS-alex weights (.safetensors) or an ONNX model (default: the
    /// installed weights, see docs/render-eval.md "LPIPS").
    #[arg(long, value_name = "FILE")]
    pub lpips: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// The capture directory (its `train` stage must have run).
    pub capture_dir: PathBuf,
    /// Camera path: orbit, spiral, interpolate, train or heldout.
    #[arg(long, default_value = "orbit")]
    pub path: String,
    /// Time: fixed:SECONDS (e.g. fixed:1.5), sweep or real.
    #[arg(long, default_value = "sweep")]
    pub time: String,
    /// Number of frames (default: one per aligned frame, at least 60).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Frames per second of the video (default: the capture's).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Output size WIDTHxHEIGHT (default: the first camera's working size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<[u32; 2]>,
    /// Output: a `.mp4` file (H.264), or a folder for PNG frames (rgb/, depth/, alpha/).
    #[arg(long)]
    pub out: PathBuf,
    /// Renderer: auto (a hardware GPU if there is one), cpu or gpu (default: `[engine]
    /// backend` of capture.toml).
    #[arg(long, value_enum)]
    pub backend: Option<BackendChoice>,
}

/// The stages in order, from the one list of them (`stages::pipeline`).
fn stages_help() -> String {
    format!(
        "Stages, in order: {}.\nEach writes work/<stage>/ in the capture directory and is skipped when its inputs and\nsettings have not changed.",
        pipeline().stage_names().join(" → ")
    )
}

fn parse_size(s: &str) -> Result<[u32; 2], String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT (e.g. 960x540)"))?;
    let n = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT (e.g. 960x540)"))
    };
    Ok([n(w)?, n(h)?])
}

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// The 4C4D decay ablation: train each decay variant (none, constant, pow, exp, neural)
    /// from the same points, settings and seed, and write held-out PSNR, SSIM and LPIPS,
    /// over the whole image and inside the moving-region masks, per variant to
    /// work/bench/ablation/ablation.{md,csv}. An interrupted ablation resumes: variants
    /// already in ablation.csv are not trained again.
    ///
    /// Examples: pipeline bench ablation my_capture/ --preset best
    ///           pipeline bench ablation fixtures/demo.toml /tmp/ablation --iterations 600
    Ablation {
        /// A capture directory with held-out cameras (real or made by `pipeline demo`), or
        /// a scene file with held-out cameras to simulate into CAPTURE_DIR.
        source: PathBuf,
        /// Where a scene file is simulated (reused when it exists); only with a scene file.
        capture_dir: Option<PathBuf>,
        /// Train with this preset's schedule instead of the capture's.
        #[arg(long, value_enum)]
        preset: Option<crate::presets::Preset>,
        /// Train this many iterations instead of the capture's (its schedules scaled).
        #[arg(long, conflicts_with = "preset")]
        iterations: Option<u64>,
        /// Decay variants to train (default: none, constant, pow, exp, neural); the rest of
        /// the capture's [decay] table applies to each.
        #[arg(long, value_delimiter = ',', value_parser = crate::bench::tradeoff::parse_decay)]
        decay: Vec<splat4d::decay::DecayVariant>,
        /// The training backend (gpu: a hardware GPU; SPLAT4D_GPU_SOFTWARE=1 allows lavapipe).
        #[arg(long, value_enum, default_value_t = crate::bench::tradeoff::TrainOn::Cpu)]
        backend: crate::bench::tradeoff::TrainOn,
        /// Use the capture as its stages left it up to `init`, without bringing them up to
        /// date (a capture prepared elsewhere).
        #[arg(long)]
        as_prepared: bool,
    },
    /// What accuracy costs in time: train a grid of settings (iterations × training
    /// resolution × Gaussian budget × decay × backend) and write held-out PSNR / SSIM /
    /// DSSIM / LPIPS, wall and CPU time, peak memory and Gaussian count per setting to
    /// work/bench/tradeoff/tradeoff.{csv,md,png} (the plot marks the Pareto front). An
    /// interrupted bench resumes: settings already in tradeoff.csv are not trained again.
    ///
    /// Examples: pipeline bench tradeoff my_demo/ --iterations 300,1000 --resolution 0.5,1
    ///           pipeline bench tradeoff fixtures/demo.toml /tmp/bench
    Tradeoff {
        /// A capture directory with held-out cameras (e.g. one made by `pipeline demo`), or
        /// a scene file to simulate into CAPTURE_DIR.
        source: PathBuf,
        /// Where a scene file is simulated (reused when it exists); only with a scene file.
        capture_dir: Option<PathBuf>,
        /// Training iterations (schedules are scaled to each).
        #[arg(long, value_delimiter = ',', default_values_t = [1000u64, 3000, 10000, 30000])]
        iterations: Vec<u64>,
        /// Training resolutions, fractions of the frames' size (`[train] resolution`).
        #[arg(long, value_delimiter = ',', default_values_t = [0.25f64, 0.5, 1.0])]
        resolution: Vec<f64>,
        /// Gaussian budgets (`[train.densify] max_gaussians`; default: the capture's).
        #[arg(long, value_delimiter = ',')]
        max_gaussians: Vec<usize>,
        /// Decay variants: none, constant, pow, exp, neural (default: the capture's).
        #[arg(long, value_delimiter = ',', value_parser = crate::bench::tradeoff::parse_decay)]
        decay: Vec<splat4d::decay::DecayVariant>,
        /// Training backends (gpu: a hardware GPU; SPLAT4D_GPU_SOFTWARE=1 allows lavapipe).
        #[arg(long, value_delimiter = ',', value_enum, default_values_t = [crate::bench::tradeoff::TrainOn::Cpu])]
        backend: Vec<crate::bench::tradeoff::TrainOn>,
        /// Train on the training views stretched to FRAMES frames per camera at W×H (each a
        /// resized copy of the camera's frame nearest in time), e.g. `300:1352x1014`: what a
        /// long, large capture costs to train, from a short one. Results go to
        /// work/bench/tradeoff-FRAMESxWxH/.
        #[arg(long, value_name = "FRAMES:WxH")]
        stretch: Option<crate::bench::stretch::Stretch>,
        /// Use the capture as its stages left it up to `init`, without bringing them up to
        /// date (a capture prepared elsewhere, e.g. on a GPU node with the engine-only build).
        #[arg(long)]
        as_prepared: bool,
    },
    /// Sync error against time: every sync method and setting (audio with/without the clap
    /// window and acoustic correction, flash with/without the rolling-shutter readout and
    /// exposure declared) on simulated scenes, against their true offsets. Writes
    /// OUT_DIR/sync.csv + sync.md; rows already in sync.csv are not recomputed.
    ///
    /// Example: pipeline bench sync /tmp/bench
    Sync {
        /// Where the simulated captures and the results go (reused when it exists).
        out_dir: PathBuf,
        /// A small grid (4 settings on 2 scenes), for tests.
        #[arg(long)]
        quick: bool,
    },
    /// Pose error against time: COLMAP with each max_num_features and max_image_size on a
    /// simulated static scene, against the true cameras, with COLMAP's time per step.
    /// Writes OUT_DIR/poses.csv + poses.md; rows already in poses.csv are not recomputed.
    ///
    /// Example: pipeline bench poses /tmp/bench
    Poses {
        /// Where the simulated capture, the COLMAP runs and the results go (reused).
        out_dir: PathBuf,
        /// One setting only (1024 features, 320 px), for tests.
        #[arg(long)]
        quick: bool,
    },
}

/// `FIRST..END` → (first, end), END after FIRST.
fn parse_frame_range(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("{s}: write FIRST..END, e.g. 0..300");
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let (a, b) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if b <= a {
        return Err(format!("{s}: END must be after FIRST"));
    }
    Ok((a, b))
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    #[test]
    fn help_lists_the_stages_of_the_pipeline_in_order() {
        let help = super::Cli::command().render_long_help().to_string();
        let names = crate::stages::pipeline().stage_names();
        assert!(help.contains(&names.join(" → ")), "{help}");
    }
}
