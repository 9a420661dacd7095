//! `pipeline bench ablation SOURCE`: the 4C4D opacity-decay ablation, how much each decay
//! variant changes novel-view quality against none. SOURCE is a capture directory with
//! held-out cameras (real or simulated) or a scene file simulated into a capture directory
//! (its true cameras as the calibration). The stages run up to `init` once; then every
//! variant (none, constant, pow, exp, neural by default) trains from the same points with
//! the capture's settings (a `--preset` over them) and seed, each with the capture's
//! `[decay]` table but its own `variant`, and is measured on the held-out views: PSNR,
//! SSIM and LPIPS over the whole image and inside the moving-region masks. Each variant is
//! a setting of [`crate::bench::tradeoff`], measured the same way and kept the same way:
//! `work/bench/ablation/ablation.csv` (the tradeoff's columns) keeps every variant as soon
//! as it is measured, so an interrupted ablation resumes, and `ablation.md` is the table.

use std::fmt::Write as _;
use std::path::PathBuf;

use splat4d::decay::DecayVariant;

use crate::bench::inputs::{self, BenchSource};
use crate::bench::sysinfo;
use crate::bench::tradeoff::{self, Row, Setting, TrainOn};
use crate::presets::Preset;
use crate::report::Reporter;

/// The variants an ablation trains unless told otherwise: the paper's table.
pub const VARIANTS: [DecayVariant; 5] = [
    DecayVariant::None,
    DecayVariant::Constant,
    DecayVariant::Pow,
    DecayVariant::Exp,
    DecayVariant::Neural,
];

/// What to train: the capture's schedule, or a preset's, or its iterations.
#[derive(Clone, Debug)]
pub struct Ablation {
    pub preset: Option<Preset>,
    /// Iterations instead of the capture's (its schedules scaled to them).
    pub iterations: Option<u64>,
    /// Variants to train; empty: [`VARIANTS`].
    pub decay: Vec<DecayVariant>,
    pub backend: TrainOn,
}

/// Run the ablation; returns the path of `ablation.md`.
pub fn run(
    source: &BenchSource,
    ablation: &Ablation,
    reporter: &Reporter,
) -> anyhow::Result<PathBuf> {
    if ablation.iterations == Some(0) {
        anyhow::bail!("--iterations needs a count above 0, e.g. 2000");
    }
    let mut inputs = inputs::prepare(source, reporter)?;
    if let Some(preset) = ablation.preset {
        inputs.config = inputs.config.clone().with_preset(preset);
    }
    let train = &inputs.config.train;
    let iterations = ablation.iterations.unwrap_or(train.iterations);
    let variants = if ablation.decay.is_empty() {
        VARIANTS.to_vec()
    } else {
        ablation.decay.clone()
    };
    let settings: Vec<Setting> = variants
        .iter()
        .map(|&decay| Setting {
            iterations,
            resolution: train.resolution,
            max_gaussians: train.densify.max_gaussians,
            decay,
            backend: ablation.backend,
        })
        .collect();
    let out = inputs.bench_dir.join("ablation");
    let measured =
        tradeoff::measure_missing(&inputs, &settings, &out.join("ablation.csv"), reporter)?;
    let rows: Vec<&Row> = settings
        .iter()
        .filter_map(|s| measured.iter().find(|r| r.setting.key() == s.key()))
        .collect();
    let d = &inputs.config.decay;
    let header = format!(
        "{}, {iterations} iterations at resolution {}, at most {} Gaussians, seed {}, {} backend. `[decay]`: warm-up {} steps, visibility {:?}, invisible β {}, constant {}, range [{}, {}] (pow γ {}, exp κ {}), f_θ inputs {:?}, lr {}. Moving region: inside the held-out views' masks. {} Machine: {}.",
        inputs.describe(source),
        train.resolution,
        train.densify.max_gaussians,
        train.seed,
        ablation.backend.name(),
        crate::presets::schedule_for(train, d, iterations).1.warmup,
        d.visibility,
        d.beta,
        d.constant,
        d.f_min,
        d.f_max,
        d.pow_gamma,
        d.exp_kappa,
        d.inputs,
        d.lr,
        inputs::lpips_note(inputs.lpips.as_ref()),
        sysinfo::describe_machine(),
    );
    let md = out.join("ablation.md");
    shared_types::atomic::write_atomic(&md, markdown(&header, &rows).as_bytes())?;
    Ok(md)
}

/// The ablation table: one row per variant, whole image and moving region, with the
/// difference in held-out PSNR from `none` where it was trained.
pub fn markdown(header: &str, rows: &[&Row]) -> String {
    let cell = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
    let none = rows
        .iter()
        .find(|r| r.setting.decay == DecayVariant::None)
        .and_then(|r| r.psnr);
    let mut s = format!(
        "# Decay ablation\n\n{header}\n\n| decay | PSNR ↑ | Δ none | SSIM ↑ | LPIPS ↓ | moving PSNR ↑ | moving SSIM ↑ | moving LPIPS ↓ | Gaussians | train time |\n|---|---|---|---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        let delta = r.psnr.zip(none).map(|(p, n)| p - n);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            tradeoff::decay_name(r.setting.decay),
            cell(r.psnr, 2),
            delta.map_or("–".into(), |d| format!("{d:+.2}")),
            cell(r.ssim, 3),
            cell(r.lpips, 3),
            cell(r.moving_psnr, 2),
            cell(r.moving_ssim, 3),
            cell(r.moving_lpips, 3),
            r.gaussians,
            crate::report::format_duration(r.seconds),
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(decay: DecayVariant, psnr: f64) -> Row {
        Row {
            setting: Setting {
                iterations: 2000,
                resolution: 1.0,
                max_gaussians: 80_000,
                decay,
                backend: TrainOn::Cpu,
            },
            seconds: 600.0,
            cpu_seconds: None,
            peak_ram_mib: None,
            gaussians: 70_000,
            psnr: Some(psnr),
            ssim: Some(0.83),
            dssim1: None,
            dssim2: None,
            lpips: Some(0.29),
            moving_psnr: Some(20.0),
            moving_ssim: None,
            moving_lpips: Some(0.31),
        }
    }

    #[test]
    fn the_table_shows_each_variant_against_none() {
        let rows = [
            row(DecayVariant::None, 22.0),
            row(DecayVariant::Neural, 21.5),
        ];
        let md = markdown("h", &rows.iter().collect::<Vec<_>>());
        assert!(
            md.contains("| none | 22.00 | +0.00 | 0.830 | 0.290 | 20.00 | – | 0.310 | 70000 |"),
            "{md}"
        );
        assert!(md.contains("| neural | 21.50 | -0.50 |"), "{md}");
        // Without a `none` row there is nothing to subtract.
        let md = markdown("h", &[&rows[1]]);
        assert!(md.contains("| neural | 21.50 | – |"), "{md}");
    }
}
