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

use anyhow::Context;
use splat4d::decay::{DecayConfig, DecayHooks};

use crate::bench::inputs::{self, BenchInputs, BenchSource};
use crate::report::Reporter;

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
    let source = BenchSource::Scene {
        scene: scene.to_path_buf(),
        capture_dir: capture_dir.to_path_buf(),
    };
    let BenchInputs {
        config,
        dataset,
        points,
        heldout,
        lpips,
        bench_dir: bench,
        ..
    } = inputs::prepare(&source, reporter)?;
    let progress = reporter.progress("ablation");
    let train_config = config.train.with_iterations(iterations);
    let mut rows = Vec::new();
    let backend = crate::engine_inputs::training_backend();
    for (label, decay) in DecayConfig::variants_for_ablation() {
        let (_, decay) = crate::presets::schedule_for(&config.train, &decay, iterations);
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
        let backdrop = summary
            .backdrop
            .as_deref()
            .map(splat4d::render::backdrop::load_backdrop)
            .transpose()?;

        let report = splat4d::eval::evaluate(
            backend.as_ref(),
            &model,
            &heldout,
            &[],
            &dir.join("eval"),
            lpips.as_ref(),
            summary.background,
            backdrop.as_ref(),
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
        "scene {}, {} training views, {} held-out views, {iterations} iterations, seed {}. {}",
        scene.display(),
        dataset.views.len(),
        heldout.len(),
        train_config.seed,
        crate::bench::inputs::lpips_note(lpips.as_ref()),
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
            r.lpips.map_or("skipped".into(), |v| format!("{v:.4}")),
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
