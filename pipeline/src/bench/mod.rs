//! `pipeline bench sync` and `pipeline bench poses`: accuracy against time of the sync
//! methods and of COLMAP's settings on simulated scenes, each a grid of settings written
//! to `OUT_DIR/<bench>.csv` and `<bench>.md` (see [`table`], resumable by settings).
//!
//! - `table`: the CSV/Markdown results table keyed by settings (shared by the benches).
//! - `ablation`, `tradeoff` (+ `tradeoff_plot`): training benches on a capture brought up
//!   to `init` by `inputs` (`stretch`: its training views made longer and larger);
//!   `sysinfo`: the machine, CPU time and peak memory.
//! - `sync`: recovered camera offsets against the simulator's true ones.
//! - `poses`: solved camera poses against the true ones, and COLMAP's time per step.

pub mod ablation;
pub mod inputs;
pub mod poses;
pub mod stretch;
pub mod sync;
pub mod sysinfo;
pub mod table;
pub mod tradeoff;
pub mod tradeoff_plot;

use std::path::Path;

use anyhow::{Context, bail};

use crate::report::Reporter;

/// Run the capture in `dir` quietly up to stage `to` and return it; a failed stage is an
/// error naming the folder.
pub fn run_stages_to(dir: &Path, to: &str) -> anyhow::Result<crate::layout::Capture> {
    let (capture, config) = crate::open_capture(dir)?;
    let summary = crate::stages::pipeline().run(
        &capture,
        &config,
        &crate::runner::Selection {
            to: Some(to.into()),
            ..Default::default()
        },
        &crate::report::Reporter::new(crate::report::OutputMode::Quiet),
    )?;
    if let Some((stage, error)) = summary.failed {
        anyhow::bail!("{}: the {stage} stage failed: {error}", dir.display());
    }
    Ok(capture)
}

/// Create the benchmark's output folder (or accept an existing one).
pub fn prepare_out_dir(out_dir: &Path) -> anyhow::Result<()> {
    if out_dir.exists() && !out_dir.is_dir() {
        bail!(
            "{} is a file, not a folder; give a folder for the simulated captures and results \
             (it is created when missing)",
            out_dir.display()
        );
    }
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create the output folder {}", out_dir.display()))
}

/// Simulate `scene` into `dir` once; an existing capture there is reused.
pub fn simulate_once(
    scene_toml: &str,
    origin: &str,
    dir: &Path,
    reporter: &Reporter,
) -> anyhow::Result<()> {
    if dir.join("raw").is_dir() && dir.join("groundtruth").is_dir() {
        return Ok(());
    }
    let scene = rig::sim::Scene::from_toml_str(scene_toml, origin)?;
    reporter.say(&format!("simulating {origin} into {}", dir.display()));
    crate::simulate::simulate_into(&scene, dir, reporter)
}

/// A fixture scene's text with some values changed: `edits` are (`table.key`, value),
/// e.g. `("flash.readout", 0.0)`; a missing table is created.
pub fn edit_scene(text: &str, edits: &[(&str, toml::Value)]) -> anyhow::Result<String> {
    let mut doc: toml::Table = toml::from_str(text).context("a built-in scene is not TOML")?;
    for (path, value) in edits {
        let (table, key) = path
            .split_once('.')
            .with_context(|| format!("scene edit {path} is not table.key"))?;
        let entry = doc
            .entry(table.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        let toml::Value::Table(t) = entry else {
            bail!("scene edit {path}: [{table}] is not a table");
        };
        t.insert(key.to_string(), value.clone());
    }
    Ok(toml::to_string(&doc)?)
}

/// Now, for the `computed_at` column (UTC, to the millisecond).
pub fn now() -> String {
    chrono::Utc::now()
        .format("%Y-%m-%dT%H:%M:%S%.3fZ")
        .to_string()
}

/// `x` with `digits` decimals.
pub fn fixed(x: f64, digits: usize) -> String {
    format!("{x:.digits$}")
}

#[cfg(test)]
mod tests {
    #[test]
    fn scene_edits_change_and_add_values() {
        let text = "[flash]\ntime = 0.5\nreadout = 0.0266\n";
        let out = super::edit_scene(
            text,
            &[
                ("flash.readout", 0.0.into()),
                ("audio.clap_time", 0.7.into()),
            ],
        )
        .unwrap();
        let doc: toml::Table = toml::from_str(&out).unwrap();
        assert_eq!(doc["flash"]["readout"].as_float(), Some(0.0));
        assert_eq!(doc["flash"]["time"].as_float(), Some(0.5));
        assert_eq!(doc["audio"]["clap_time"].as_float(), Some(0.7));
        assert!(super::edit_scene("flash = 1\n", &[("flash.time", 1.into())]).is_err());
        assert!(super::edit_scene(text, &[("flash", 1.into())]).is_err());
    }
}
