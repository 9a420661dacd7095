//! The `pipeline` command. See `pipeline --help`.
#![cfg_attr(not(feature = "ffmpeg"), allow(unused))]

use std::io::{IsTerminal, Write};
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use indicatif::MultiProgress;
use pipeline::cli::{
    BenchCommand, Cli, Command, MetricsArgs, RecordArgs, RenderArgs, RunArgs, SubmitArgs,
};
use pipeline::partial_dir::{build_fresh, partial_path, swap_in};
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::{RunSummary, Selection};
use pipeline::{open_capture, simulate, stages, status};

/// Mesa's Vulkan device-select layer connects to a Wayland display to rank GPUs and, on a
/// headless machine, prints `error: XDG_RUNTIME_DIR is invalid…` to the terminal whenever
/// the GPU backend looks for an adapter. The engine picks its adapter itself, so the layer
/// is switched off (`NODEVICE_SELECT=1`) unless the user set that variable.
fn quiet_vulkan_device_select() {
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called first thing in `main`, before any other thread exists.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

fn main() -> ExitCode {
    quiet_vulkan_device_select();
    let cli = Cli::parse();
    let mode = if cli.json {
        OutputMode::Json
    } else if cli.quiet {
        OutputMode::Quiet
    } else {
        OutputMode::Human
    };
    let reporter = Reporter::new(mode);
    init_logging(cli.verbose, mode, reporter.multi().clone());
    match dispatch(cli.command, &reporter) {
        Ok(code) => code,
        Err(e) => {
            if mode == OutputMode::Json {
                reporter.json(
                    &serde_json::json!({"event": "error", "error": pipeline::error_chain(&e)}),
                );
            }
            eprintln!("error: {}", pipeline::error_chain(&e));
            ExitCode::FAILURE
        }
    }
}

fn dispatch(command: Command, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    if matches!(command, Command::Run(_) | Command::Demo { .. }) {
        ctrlc::set_handler(pipeline::interrupt::on_interrupt)
            .context("cannot install the Ctrl-C handler")?;
    }
    match command {
        Command::Run(args) => run(args, reporter),
        Command::Submit(args) => submit(args, reporter),
        Command::Cancel { capture_dir } => cancel(&capture_dir, reporter),
        Command::View {
            capture_dirs,
            port,
            no_open,
        } => view(&capture_dirs, port, no_open, reporter),
        Command::Import {
            format,
            source,
            capture_dir,
            train,
            frames,
            long_side,
            copy,
        } => {
            let request = pipeline::import::Request {
                format,
                source,
                dest: capture_dir.clone(),
                train: train.unwrap_or(pipeline::import::TrainChoice::Protocol),
                frames,
                long_side,
                copy,
            };
            let summary = pipeline::import::import(&request)?;
            let names = |range: std::ops::Range<usize>| {
                summary.cameras[range]
                    .iter()
                    .map(|(c, d)| format!("{c} ({d})"))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            reporter.say(&format!("training cameras: {}", names(0..summary.training)));
            if !summary.heldout.is_empty() {
                reporter.say(&format!(
                    "held out: {}",
                    names(summary.training..summary.cameras.len())
                ));
            }
            reporter.say(&format!("next: pipeline run {}", capture_dir.display()));
            Ok(ExitCode::SUCCESS)
        }
        Command::Status { capture_dir } => {
            let (capture, config) = open_capture(&capture_dir)?;
            let mut rows = stages::pipeline().status(&capture, &config)?;
            if let Err(e) = pipeline::cluster::annotate_status(&mut rows, &capture) {
                reporter.say(&format!(
                    "the Slurm jobs of this capture are not shown: {e}"
                ));
            }
            if reporter.mode() == OutputMode::Json {
                reporter.json(&rows);
            } else {
                println!("{}\n", capture_summary(&capture));
                print!("{}", status::format_table(&rows));
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Demo {
            out_dir,
            backend,
            preset,
            to,
        } => demo(&out_dir, backend, preset, to.as_deref(), reporter),
        Command::Render(args) => render(args, reporter),
        Command::Metrics(args) => metrics(args, reporter),
        Command::Bench(BenchCommand::Ablation {
            source,
            capture_dir,
            preset,
            iterations,
            decay,
            backend,
            as_prepared,
        }) => {
            let mut source =
                pipeline::bench::inputs::BenchSource::from_args(&source, capture_dir.as_deref())?;
            if as_prepared {
                source = source.as_prepared();
            }
            let ablation = pipeline::bench::ablation::Ablation {
                preset,
                iterations,
                decay,
                backend,
            };
            let table = pipeline::bench::ablation::run(&source, &ablation, reporter)?;
            reporter.say(&format!("ablation table written to {}", table.display()));
            if reporter.mode() == OutputMode::Human {
                print!("{}", std::fs::read_to_string(&table).unwrap_or_default());
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Bench(BenchCommand::Tradeoff {
            source,
            capture_dir,
            iterations,
            resolution,
            max_gaussians,
            decay,
            backend,
            stretch,
            as_prepared,
        }) => {
            let mut source =
                pipeline::bench::inputs::BenchSource::from_args(&source, capture_dir.as_deref())?;
            if as_prepared {
                source = source.as_prepared();
            }
            let grid = pipeline::bench::tradeoff::Grid {
                iterations,
                resolution,
                max_gaussians,
                decay,
                backend,
                stretch,
            };
            let table = pipeline::bench::tradeoff::run(&source, &grid, reporter)?;
            reporter.say(&format!(
                "tradeoff table and plot written to {}",
                table.parent().unwrap_or(&table).display()
            ));
            if reporter.mode() == OutputMode::Human {
                print!("{}", std::fs::read_to_string(&table).unwrap_or_default());
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Bench(BenchCommand::Sync { out_dir, quick }) => {
            let bench = pipeline::bench::sync::run(&out_dir, quick, reporter)?;
            bench_done(&bench.markdown, &bench.csv, bench.summary, reporter)
        }
        Command::Bench(BenchCommand::Poses { out_dir, quick }) => {
            let bench = pipeline::bench::poses::run(&out_dir, quick, reporter)?;
            bench_done(&bench.markdown, &bench.csv, bench.summary, reporter)
        }
        Command::Record(args) => record(args, reporter),
        Command::Simulate {
            scene,
            capture_dir,
            truth_pointmaps,
            truth_calibration,
        } => {
            let scene = rig::sim::Scene::from_file(&scene)?;
            simulate::simulate_into(&scene, &capture_dir, reporter)?;
            if truth_pointmaps {
                let dir = simulate::write_truth_pointmaps(&capture_dir)?;
                reporter.say(&format!(
                    "true point maps written to {} (set [init] pointmaps = \"pointmaps\" to use them)",
                    dir.display()
                ));
            }
            if truth_calibration {
                simulate::write_truth_calibration(&capture_dir)?;
                reporter.say(
                    "true video cameras written to calibration.json (the poses stage imports them)",
                );
            }
            reporter.say(&format!(
                "simulated capture written to {}",
                capture_dir.display()
            ));
            reporter.json(&serde_json::json!({"event": "simulated", "capture_dir": capture_dir}));
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// Say where a bench wrote its table and how many rows it computed; print the table.
fn bench_done(
    markdown: &std::path::Path,
    csv: &std::path::Path,
    summary: pipeline::bench::table::FillSummary,
    reporter: &Reporter,
) -> anyhow::Result<ExitCode> {
    reporter.say(&format!(
        "{} settings computed, {} already in {}; table written to {}",
        summary.computed,
        summary.reused,
        csv.display(),
        markdown.display()
    ));
    reporter.json(&serde_json::json!({
        "event": "bench_finished",
        "markdown": markdown,
        "csv": csv,
        "computed": summary.computed,
        "reused": summary.reused,
    }));
    if reporter.mode() == OutputMode::Human {
        print!("{}", std::fs::read_to_string(markdown).unwrap_or_default());
    }
    Ok(ExitCode::SUCCESS)
}

fn run(args: RunArgs, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    let (capture, config) = open_capture(&args.capture_dir)?;
    pipeline::cluster::check_local_run(&capture)?;
    say_preset(args.stages.preset, reporter);
    let config = args.stages.configure(config);
    let selection = args.stages.selection();
    let summary = stages::pipeline()
        .run(&capture, &config, &selection, reporter)
        .with_context(|| format!("run on {}", capture.root.display()))?;
    report_summary(&summary, reporter);
    if summary.ran.iter().any(|s| s == "export") {
        say_view(&capture.root, reporter);
    }
    Ok(if summary.complete() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// The command that shows a capture's exported viewer, when it has one.
fn say_view(capture_dir: &std::path::Path, reporter: &Reporter) {
    if pipeline::view::viewer_dir(capture_dir).is_ok() {
        let program = std::env::current_exe()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|_| "pipeline".into());
        reporter.say(&format!(
            "see the 4D scene in a browser: {program} view {}",
            capture_dir.display()
        ));
    }
}

/// Submit each capture's stale stages to Slurm, one job per stage, chained by `afterok`.
/// Every capture is tried; the command fails when one of them could not be submitted.
/// `pipeline view`: serve the exported viewers until Ctrl-C.
fn view(
    capture_dirs: &[std::path::PathBuf],
    port: Option<u16>,
    no_open: bool,
    reporter: &Reporter,
) -> anyhow::Result<ExitCode> {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let site = pipeline::view::Site::of(capture_dirs)?;
    let server = pipeline::view::Server::bind(site.clone(), port)?;
    let url = server.url()?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("cannot install the Ctrl-C handler")?;
    for viewer in &site.viewers {
        reporter.say(&format!("{}: {}", viewer.name, viewer.dir.display()));
    }
    // The URL on stdout, whatever the output mode: scripts read it there.
    println!("viewer at {url}");
    if !no_open && !pipeline::view::open_browser(&url) {
        reporter.say("open that address in a browser (no browser to open here); Ctrl-C stops");
    } else {
        reporter.say("Ctrl-C stops");
    }
    server.serve_until(|| stop.load(Ordering::SeqCst))?;
    reporter.say("stopped");
    Ok(ExitCode::SUCCESS)
}

fn submit(args: SubmitArgs, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    if args.stages.chunk.is_some() {
        anyhow::bail!(
            "--chunk trains one time chunk in `pipeline run`; `pipeline submit` makes one job per chunk itself (docs/cluster.md)"
        );
    }
    let pipeline = stages::pipeline();
    let names = pipeline.stage_names();
    let options = pipeline::cluster::SubmitOptions {
        selection: args.stages.selection(),
        run_args: args.stages.run_flags(),
    };
    let mut failed = 0;
    for dir in &args.capture_dirs {
        let outcome = open_capture(dir).and_then(|(capture, config)| {
            let config = args.stages.configure(config);
            let settings =
                pipeline::cluster::settings_for(&config, &capture.config_path(), &names)?;
            Ok(pipeline::cluster::submit(
                &pipeline, &capture, &config, &settings, &options,
            )?)
        });
        match outcome {
            Ok(done) => {
                reporter.json(&serde_json::json!({"event": "submitted", "submission": done}));
                let jobs: Vec<String> = done
                    .jobs
                    .iter()
                    .map(|j| {
                        let gpus = if j.gpus > 0 {
                            format!(" ({} GPU)", j.gpus)
                        } else {
                            String::new()
                        };
                        format!("{} → job {}{gpus}", j.stage, j.job_id)
                    })
                    .collect();
                let mut line = format!("{}: ", dir.display());
                if jobs.is_empty() {
                    line += "up to date, nothing submitted";
                } else {
                    line += &jobs.join(", ");
                    if !done.up_to_date.is_empty() {
                        line += &format!("; up to date: {}", done.up_to_date.join(", "));
                    }
                }
                reporter.say(&line);
                for note in &done.notes {
                    reporter.say(&format!("  note: {note}"));
                }
            }
            Err(e) => {
                failed += 1;
                let error = pipeline::error_chain(&e);
                reporter
                    .json(&serde_json::json!({"event": "error", "capture": dir, "error": error}));
                eprintln!("error: {}: {error}", dir.display());
            }
        }
    }
    if failed == 0 && args.capture_dirs.len() == 1 {
        reporter.say(&format!(
            "`pipeline status {}` shows the jobs",
            args.capture_dirs[0].display()
        ));
    }
    Ok(if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// Cancel a capture's Slurm jobs that have not finished.
fn cancel(dir: &std::path::Path, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    let (capture, _) = open_capture(dir)?;
    let cancelled = pipeline::cluster::cancel(&capture, std::time::Duration::from_secs(30))?;
    reporter.json(&serde_json::json!({"event": "cancelled", "jobs": cancelled}));
    if cancelled.is_empty() {
        reporter.say(&format!(
            "{}: no job of this capture is in Slurm",
            dir.display()
        ));
    } else {
        let jobs: Vec<String> = cancelled
            .iter()
            .map(|j| format!("{} (job {})", j.stage, j.job_id))
            .collect();
        reporter.say(&format!("{}: cancelled {}", dir.display(), jobs.join(", ")));
    }
    Ok(ExitCode::SUCCESS)
}

/// Render the trained model along a path into an MP4 file or a folder of PNGs; the
/// output appears only when complete.
fn render(args: RenderArgs, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    let (capture, config) = open_capture(&args.capture_dir)?;
    let backend =
        pipeline::engine_inputs::render_backend(args.backend.unwrap_or(config.engine.backend))?;
    let work = capture.work_dir();
    let model = pipeline::engine_inputs::load_trained_model(&work)?;
    let trained = pipeline::engine_inputs::trained_record(&work, config.train.background)?;
    let backdrop = trained.load_backdrop(&work)?;
    let (index, cameras, heldout) = pipeline::stages::render::path_cameras(&work)?;
    let video = args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mp4"));
    let settings = pipeline::stages::render::RenderSettings {
        path: args.path,
        time: args.time,
        frames: args.frames,
        fps: args.fps,
        size: args.size,
        video,
        png: !video,
    };
    // The partial folder is a sibling named after --out.
    args.out
        .file_name()
        .context("--out needs a file or folder name")?;
    let staging = partial_path(&args.out);
    let frames = build_fresh(&staging, |staging| {
        let progress = reporter.progress("render");
        let frames = pipeline::stages::render::render(
            backend.as_ref(),
            &model,
            trained.background,
            backdrop.as_ref(),
            &cameras,
            &heldout,
            &settings,
            index.frames.len(),
            index.fps,
            staging,
            &progress,
        );
        shared_types::Progress::finish(&progress);
        frames
    })?;
    if video {
        std::fs::rename(staging.join("render.mp4"), &args.out)
            .with_context(|| format!("cannot write {}", args.out.display()))?;
        std::fs::remove_dir_all(&staging).ok();
    } else {
        if args.out.exists() {
            anyhow::bail!("{} already exists; choose a new folder", args.out.display());
        }
        swap_in(&staging, &args.out)?;
    }
    reporter.say(&format!(
        "{frames} frames written to {}",
        args.out.display()
    ));
    Ok(ExitCode::SUCCESS)
}

#[cfg(not(feature = "ffmpeg"))]
fn record(_: RecordArgs, _: &Reporter) -> anyhow::Result<ExitCode> {
    Err(pipeline::without_ffmpeg("recording"))
}

/// Record webcams (V4L2 or nokhwa) into a new capture directory until Ctrl-C or
/// `--seconds`; or, with `--list`, list the cameras.
#[cfg(feature = "ffmpeg")]
fn record(args: RecordArgs, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    let backend = args
        .backend
        .map(rig::record::CaptureBackend::from)
        .unwrap_or_else(rig::record::CaptureBackend::native);
    if args.list {
        let cameras = rig::record::list_cameras(backend)?;
        if reporter.mode() == OutputMode::Json {
            reporter.json(&serde_json::json!({ "event": "cameras", "cameras": cameras }));
        } else if cameras.is_empty() {
            reporter.say(&format!("no camera found through {backend:?}"));
        } else {
            // The list is the command's output: stdout, one camera a line.
            for camera in cameras {
                println!("{camera}");
            }
        }
        return Ok(ExitCode::SUCCESS);
    }
    let Some(capture_dir) = args.capture_dir else {
        anyhow::bail!("give the capture directory to record into (pipeline record --help)");
    };
    if capture_dir.join("raw").exists() {
        anyhow::bail!(
            "{} already holds a capture (raw/); choose another folder or delete it first",
            capture_dir.display()
        );
    }
    let config = rig::record::RecordConfig {
        width: args.width,
        height: args.height,
        fps: args.fps,
        duration_s: args.seconds,
        flash_prompt: !args.no_flash_prompt,
    };
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;
    let progress = reporter.progress("record");
    let cameras = rig::record::record_with(
        backend,
        &args.devices,
        &capture_dir,
        &config,
        &stop,
        &progress,
    )?;
    shared_types::Progress::finish(&progress);
    for cam in &cameras {
        reporter.say(&format!(
            "{}: {} frames in {}",
            cam.name,
            cam.frames,
            cam.dir.display()
        ));
    }
    reporter.say(&format!(
        "recorded; next: pipeline run {}",
        capture_dir.display()
    ));
    Ok(ExitCode::SUCCESS)
}

/// `DIR (4 cameras, 2 held-out: cam4, cam5, 8 stills, calibration.json)` for `status`.
fn capture_summary(capture: &pipeline::layout::Capture) -> String {
    let mut parts = vec![format!("{} cameras", capture.cameras.len())];
    if !capture.heldout.is_empty() {
        let names: Vec<&str> = capture.heldout.iter().map(|c| c.name.as_str()).collect();
        parts.push(format!("{} held-out: {}", names.len(), names.join(", ")));
    }
    parts.push(format!("{} stills", capture.stills.len()));
    if let Some(calibration) = &capture.calibration {
        let name = calibration.file_name().unwrap_or(calibration.as_os_str());
        parts.push(format!("calibration {}", name.to_string_lossy()));
    }
    format!("{} ({})", capture.root.display(), parts.join(", "))
}

/// `--preset` over the capture's settings, said to the user.
/// Say which preset a run uses, when one was chosen.
fn say_preset(preset: Option<pipeline::presets::Preset>, reporter: &Reporter) {
    if let Some(p) = preset {
        reporter.say(&format!("preset {}: {}", p.name(), p.describe()));
    }
}

/// Simulate the built-in scene (once) and run every stage on it. Stages that are not
/// implemented yet are reported but do not make the demo fail; a failing stage does.
/// On a hardware GPU the demo trains at the paper's schedule (preset `full`) unless a
/// preset was chosen; it says which backend and schedule it uses. `to` stops it after
/// that stage.
fn demo(
    out_dir: &std::path::Path,
    backend: Option<pipeline::engine_inputs::BackendChoice>,
    preset: Option<pipeline::presets::Preset>,
    to: Option<&str>,
    reporter: &Reporter,
) -> anyhow::Result<ExitCode> {
    let names = stages::pipeline().stage_names();
    let position = |stage: &str| names.iter().position(|n| *n == stage);
    // Whether the run goes as far as `stage`.
    let reaches = |stage: &str| to.is_none_or(|t| position(t) >= position(stage));
    if out_dir.join("raw").exists() {
        reporter.say(&format!(
            "reusing the simulated capture in {} (delete it to simulate again)",
            out_dir.display()
        ));
    } else {
        reporter.say(&format!(
            "simulating the demo capture into {} …",
            out_dir.display()
        ));
        let scene = simulate::demo_scene()?;
        simulate::simulate_into(&scene, out_dir, reporter)?;
        let settings = out_dir.join(pipeline::layout::CONFIG_FILE);
        shared_types::atomic::write_atomic(&settings, simulate::demo_settings(&scene).as_bytes())
            .with_context(|| format!("cannot write {}", settings.display()))?;
    }
    let (capture, mut config) = open_capture(out_dir)?;
    if let Some(b) = backend {
        config.engine.backend = b;
    }
    let trainer = pipeline::engine_inputs::training_backend_for(config.engine.backend)?;
    let hardware_gpu = trainer.as_gpu().is_some_and(|g| !g.is_software());
    let schedule = pipeline::presets::demo_preset(preset.or(config.preset), hardware_gpu);
    if schedule != config.preset
        && let Some(p) = schedule
    {
        say_preset(schedule, reporter);
        config = config.with_preset(p);
    }
    reporter.say(&format!(
        "training on {}: {}",
        trainer.describe(),
        match config.preset {
            Some(p) => format!(
                "preset {}, {} iterations",
                p.name(),
                config.train.iterations
            ),
            None => format!(
                "the demo's CPU schedule, {} iterations (on a hardware GPU it takes preset full)",
                config.train.iterations
            ),
        }
    ));
    drop(trainer);
    if reaches("init") && !out_dir.join("pointmaps").exists() {
        // No MASt3R weights ship with the tool: the demo stands in for the point-map model
        // with the simulator's true depth at the init moments (docs/init.md), which are
        // aligned frames: the stages up to `frames` run first.
        let to_frames = Selection {
            to: Some("frames".into()),
            ..Selection::default()
        };
        let summary = stages::pipeline().run(&capture, &config, &to_frames, reporter)?;
        if summary.failed.is_some() {
            report_summary(&summary, reporter);
            return Ok(ExitCode::FAILURE);
        }
        let index = rig::frames::FramesIndex::read_json(
            &capture.work_dir().join("frames").join("frames.json"),
        )?;
        let moments = stages::init::moment_frames(index.frames.len(), config.init.moments.max(1));
        let frames: Vec<usize> = moments.iter().map(|&i| index.frames[i].index).collect();
        let maps = simulate::write_truth_moment_pointmaps(
            out_dir,
            &simulate::demo_scene()?,
            &index,
            &frames,
        )?;
        reporter.say(&format!(
            "point maps of the simulated scene at aligned frames {frames:?} written to {} (they stand in for a MASt3R export)",
            maps.display()
        ));
    }
    let selection = Selection {
        to: to.map(str::to_owned),
        ..Selection::default()
    };
    let summary = stages::pipeline().run(&capture, &config, &selection, reporter)?;
    report_summary(&summary, reporter);
    reporter.say(&format!(
        "outputs are in {}; `pipeline status {}` shows each stage",
        capture.work_dir().display(),
        out_dir.display()
    ));
    say_view(out_dir, reporter);
    Ok(if summary.failed.is_none() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

fn report_summary(summary: &RunSummary, reporter: &Reporter) {
    reporter.json(&serde_json::json!({"event": "run_finished", "summary": summary}));
    let mut line = format!(
        "{} ran, {} up to date",
        summary.ran.len(),
        summary.skipped.len()
    );
    if !summary.not_implemented.is_empty() {
        line += &format!(
            ", not implemented yet: {}",
            summary.not_implemented.join(", ")
        );
    }
    if !summary.blocked.is_empty() {
        line += &format!(", not run: {}", summary.blocked.join(", "));
    }
    if let Some((stage, _)) = &summary.failed {
        line += &format!(", FAILED: {stage} (see `pipeline status`)");
    }
    reporter.say(&line);
}

/// Logs go to stderr through the progress bars' container so they never tear a bar.
fn init_logging(verbose: u8, mode: OutputMode, multi: MultiProgress) {
    let default = match (verbose, mode) {
        (0, OutputMode::Human) => "info",
        (0, _) => "warn",
        (1, _) => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("PIPELINE_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let writer = move || BarSafeWriter(multi.clone());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(writer)
        .with_target(false)
        .with_ansi(std::io::stderr().is_terminal())
        .try_init();
}

struct BarSafeWriter(MultiProgress);

impl Write for BarSafeWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.suspend(|| std::io::stderr().write_all(buf))?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// `pipeline metrics A B`: the table on stdout (JSON lines with `--json`), notes on stderr.
fn metrics(args: MetricsArgs, reporter: &Reporter) -> anyhow::Result<ExitCode> {
    use splat4d::metrics::lpips::{INSTALL_HINT, Lpips};
    let lpips = match &args.lpips {
        Some(path) => Some(
            Lpips::load(path)
                .with_context(|| format!("--lpips {}: cannot load it", path.display()))?,
        ),
        None => Lpips::installed().context("cannot load the installed LPIPS weights")?,
    };
    match &lpips {
        Some(net) => reporter.say(&format!(
            "LPIPS: {} from {}",
            net.kind(),
            net.path().display()
        )),
        None => reporter.say(&format!(
            "LPIPS skipped: no weights installed; {INSTALL_HINT}"
        )),
    }
    let progress = reporter.progress("metrics");
    let comparison = pipeline::compare::compare(&args.a, &args.b, lpips.as_ref(), &progress)?;
    for (folder, names) in [
        (&args.a, &comparison.only_in_a),
        (&args.b, &comparison.only_in_b),
    ] {
        if !names.is_empty() {
            let shown: Vec<&str> = names.iter().take(5).map(String::as_str).collect();
            let more = if names.len() > shown.len() {
                ", …"
            } else {
                ""
            };
            reporter.say(&format!(
                "{} image(s) only in {}, left out: {}{more}",
                names.len(),
                folder.display(),
                shown.join(", ")
            ));
        }
    }
    if reporter.mode() == OutputMode::Json {
        let finite = |v: f64| v.is_finite().then_some(v);
        for p in &comparison.pairs {
            reporter.json(&serde_json::json!({
                "event": "metrics",
                "image": p.name,
                "a": p.a,
                "b": p.b,
                "width": p.width,
                "height": p.height,
                "psnr": finite(p.metrics.psnr),
                "ssim": p.metrics.ssim,
                "dssim1": p.metrics.dssim1,
                "dssim2": p.metrics.dssim2,
                "lpips": p.lpips,
            }));
        }
        let mean = comparison.mean();
        reporter.json(&serde_json::json!({
            "event": "metrics_mean",
            "images": comparison.pairs.len(),
            "only_in_a": comparison.only_in_a,
            "only_in_b": comparison.only_in_b,
            "psnr": mean.psnr.and_then(finite),
            "ssim": mean.ssim,
            "dssim1": mean.dssim1,
            "dssim2": mean.dssim2,
            "lpips": mean.lpips,
            "lpips_network": lpips.as_ref().map(|l| l.kind()),
        }));
    } else {
        print!(
            "{}",
            pipeline::compare::format_table(&comparison, lpips.is_some())
        );
    }
    Ok(ExitCode::SUCCESS)
}
