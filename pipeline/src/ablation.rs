//! `pipeline bench ablation SCENE`: the 4C4D opacity-decay ablation (how much each decay
//! variant, against none, changes novel-view quality) on a simulated 4-camera scene with
//! held-out cameras. The scene is simulated once, its true video cameras are imported as
//! the calibration (so pose errors do not blur the comparison), the capture stages and the
//! point initialisation run once, then every decay variant
//! (`DecayConfig::variants_for_ablation`) trains from the same points with the same
//! settings and seed and is measured on the held-out views. Writes
//! `work/bench/ablation.md` and `ablation.csv` in the capture directory.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use splat4d::decay::{DecayConfig, DecayHooks};

use crate::report::Reporter;
use crate::runner::Selection;
use crate::{open_capture, simulate, stages};

/// One row of the table.
#[derive(Clone, Debug)]
pub struct AblationRow {
    pub label: String,
    pub psnr: Option<f64>,
    pub dssim1: Option<f64>,
    pub dssim2: Option<f64>,
    pub lpips: Option<f64>,
    pub gaussians: usize,
    pub seconds: f64,
}

/// Run the ablation; returns the path of `ablation.md`.
pub fn run(
    scene: &Path,
    capture_dir: &Path,
    iterations: u64,
    reporter: &Reporter,
) -> anyhow::Result<PathBuf> {
    if !capture_dir.join("raw").exists() {
        let parsed = rig::sim::Scene::from_file(scene)?;
        simulate::simulate_into(&parsed, capture_dir, reporter)?;
        simulate::write_truth_calibration(capture_dir)?;
    }
    if !capture_dir.join("groundtruth/heldout").is_dir() {
        bail!(
            "{} has no held-out cameras (groundtruth/heldout/); add [[cameras.heldout]] to the scene",
            capture_dir.display()
        );
    }
    let (capture, config) = open_capture(capture_dir)?;
    let summary = stages::pipeline().run(
        &capture,
        &config,
        &Selection {
            to: Some("init".into()),
            ..Default::default()
        },
        reporter,
    )?;
    if let Some((stage, error)) = summary.failed {
        bail!("the {stage} stage failed: {error}");
    }
    let work = capture.work_dir();
    let cameras_file = work.join("poses/cameras.json");
    let progress = reporter.progress("ablation");
    let dataset =
        crate::engine_inputs::load_dataset(&work.join("frames"), &cameras_file, &progress)?;
    let points = shared_types::points::read_points_ply(&work.join("init/points.ply"))?;
    let index = FramesIndex::read_json(&work.join("frames/frames.json"))?;
    let poses = PosesFile::read(&cameras_file)?;
    let bench = work.join("bench");
    let heldout = crate::stages::eval::heldout_views(
        &capture,
        &config.eval,
        &poses.set,
        &crate::engine_inputs::time_mapping(&index),
        &bench.join("heldout-groundtruth"),
        None,
    )?;
    let train_config = config.train.with_iterations(iterations);
    let scale = iterations as f64 / config.train.iterations.max(1) as f64;
    let mut rows = Vec::new();
    let backend = crate::engine_inputs::training_backend();
    for (label, mut decay) in DecayConfig::variants_for_ablation() {
        decay.warmup = (decay.warmup as f64 * scale).round() as u64;
        reporter.say(&format!(
            "ablation: training `{label}` ({iterations} iterations)"
        ));
        let dir = bench.join("ablation").join(label.replace([' ', '/'], "_"));
        let mut hooks = DecayHooks::new(&decay).map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
        let summary = splat4d::train::train(
            backend.as_ref(),
            &train_config,
            &dataset,
            &points,
            &dir,
            false,
            &mut hooks,
            &progress,
        )
        .with_context(|| format!("training `{label}`"))?;
        let model = splat4d::load_model(&summary.model_path)?;
        let report = splat4d::eval::evaluate(
            backend.as_ref(),
            &model,
            &heldout,
            &[],
            &dir.join("eval"),
            None,
            &progress,
        )?;
        let m = &report.heldout;
        rows.push(AblationRow {
            label,
            psnr: m.psnr,
            dssim1: m.dssim1,
            dssim2: m.dssim2,
            lpips: m.lpips,
            gaussians: model.len(),
            seconds: summary.seconds,
        });
    }
    shared_types::Progress::finish(&progress);
    let md = bench.join("ablation.md");
    let header = format!(
        "scene {}, {} training views, {} held-out views, {iterations} iterations, seed {}",
        scene.display(),
        dataset.views.len(),
        heldout.len(),
        train_config.seed
    );
    shared_types::atomic::write_atomic(&md, markdown(&header, &rows).as_bytes())?;
    shared_types::atomic::write_atomic(&bench.join("ablation.csv"), csv(&rows).as_bytes())?;
    Ok(md)
}

fn cell(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.digits$}"))
}

/// The results as a Markdown table: one row per variant with held-out PSNR, DSSIM₁,
/// DSSIM₂, LPIPS, Gaussian count and training seconds.
pub fn markdown(header: &str, rows: &[AblationRow]) -> String {
    let mut s = format!(
        "# Decay ablation\n\n{header}\n\n| variant | PSNR ↑ | DSSIM₁ ↓ | DSSIM₂ ↓ | LPIPS ↓ | Gaussians | train s |\n|---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {:.0} |",
            r.label,
            cell(r.psnr, 2),
            cell(r.dssim1, 4),
            cell(r.dssim2, 4),
            r.lpips
                .map_or("skipped: no weights".into(), |v| format!("{v:.4}")),
            r.gaussians,
            r.seconds
        );
    }
    s
}

/// The same rows as CSV.
pub fn csv(rows: &[AblationRow]) -> String {
    let mut s = String::from("variant,psnr,dssim1,dssim2,lpips,gaussians,seconds\n");
    let f = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{}",
            r.label,
            f(r.psnr),
            f(r.dssim1),
            f(r.dssim2),
            f(r.lpips),
            r.gaussians,
            r.seconds
        );
    }
    s
}
