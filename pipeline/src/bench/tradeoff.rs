//! `pipeline bench tradeoff`: what accuracy costs in time. Trains a grid of settings
//! (iterations × training resolution × Gaussian budget × decay variant × backend) from the
//! same capture, points and seed, and records for each the training wall time, CPU time,
//! peak memory, Gaussian count and held-out PSNR / SSIM / DSSIM / LPIPS (and the moving
//! region's PSNR when masks exist). Writes `work/bench/tradeoff/tradeoff.{csv,md,png}`:
//! the table, and held-out PSNR against time with the Pareto front marked. Each finished
//! setting is appended to the CSV at once, so an interrupted bench resumes where it
//! stopped; settings already in the CSV are not trained again, and a later grid adds its
//! rows to the same table and plot. With `--stretch FRAMES:WxH` the training views are
//! stretched first ([`crate::bench::stretch`]) and the results go to a folder of their own,
//! `work/bench/tradeoff-FRAMESxWxH/`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use splat4d::RenderBackend;
use splat4d::decay::{DecayHooks, DecayVariant};

use crate::bench::inputs::{self, BenchInputs, BenchSource};
use crate::bench::stretch::Stretch;
use crate::bench::sysinfo;
use crate::bench::table::{self, Table};
use crate::bench::tradeoff_plot::PlotPoint;
use crate::report::Reporter;

/// The backend a setting trains on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum TrainOn {
    Cpu,
    /// A GPU through wgpu (a hardware one; `SPLAT4D_GPU_SOFTWARE=1` allows lavapipe).
    Gpu,
}

impl TrainOn {
    pub fn name(self) -> &'static str {
        match self {
            Self::Cpu => "cpu",
            Self::Gpu => "gpu",
        }
    }
}

/// The axes of the grid; every combination is one setting.
#[derive(Clone, Debug)]
pub struct Grid {
    pub iterations: Vec<u64>,
    /// Training resolution, a fraction of the frames' size (`[train] resolution`).
    pub resolution: Vec<f64>,
    /// Gaussian budgets (`[train.densify] max_gaussians`); empty: the capture's own.
    pub max_gaussians: Vec<usize>,
    /// Decay variants; empty: the capture's own.
    pub decay: Vec<DecayVariant>,
    pub backend: Vec<TrainOn>,
    /// Train on the training views stretched to this many frames per camera and this size
    /// (every setting alike); `None`: as they are.
    pub stretch: Option<Stretch>,
}

/// One point of the grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setting {
    pub iterations: u64,
    pub resolution: f64,
    pub max_gaussians: usize,
    pub decay: DecayVariant,
    pub backend: TrainOn,
}

impl Setting {
    /// A unique, file-name-safe name: `it1000-res0.5-cap80000-neural-cpu`.
    pub fn key(&self) -> String {
        format!(
            "it{}-res{}-cap{}-{}-{}",
            self.iterations,
            self.resolution,
            self.max_gaussians,
            decay_name(self.decay),
            self.backend.name()
        )
    }

    /// Rough relative cost (iterations × pixels), for the progress bar's ETA.
    fn work(&self) -> u64 {
        (self.iterations as f64 * self.resolution * self.resolution).ceil() as u64
    }
}

/// The `[decay] variant` name of `v`.
pub fn decay_name(v: DecayVariant) -> String {
    serde_json::to_value(v)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_else(|| format!("{v:?}"))
}

/// A decay variant from its `[decay] variant` name.
pub fn parse_decay(name: &str) -> Result<DecayVariant, String> {
    serde_json::from_value(serde_json::Value::String(name.trim().to_string()))
        .map_err(|_| format!("'{name}' is not a decay variant (none, constant, pow, exp, neural)"))
}

impl Grid {
    /// Every setting, budgets and decay variants defaulting to the capture's.
    pub fn settings(&self, default_cap: usize, default_decay: DecayVariant) -> Vec<Setting> {
        let caps = if self.max_gaussians.is_empty() {
            vec![default_cap]
        } else {
            self.max_gaussians.clone()
        };
        let decays = if self.decay.is_empty() {
            vec![default_decay]
        } else {
            self.decay.clone()
        };
        let mut out = Vec::new();
        for &backend in &self.backend {
            for &decay in &decays {
                for &max_gaussians in &caps {
                    for &resolution in &self.resolution {
                        for &iterations in &self.iterations {
                            out.push(Setting {
                                iterations,
                                resolution,
                                max_gaussians,
                                decay,
                                backend,
                            });
                        }
                    }
                }
            }
        }
        out
    }

    fn check(&self) -> anyhow::Result<()> {
        if self.iterations.is_empty() || self.iterations.contains(&0) {
            bail!("--iterations needs one or more counts above 0, e.g. 1000,3000");
        }
        if self.resolution.is_empty() || self.resolution.iter().any(|r| !(*r > 0.0 && *r <= 1.0)) {
            bail!("--resolution needs fractions in (0, 1] of the frames' size, e.g. 0.5,1");
        }
        if self.max_gaussians.contains(&0) {
            bail!("--max-gaussians needs budgets above 0");
        }
        if self.backend.is_empty() {
            bail!("--backend needs cpu, gpu or both");
        }
        Ok(())
    }
}

/// What one setting measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub setting: Setting,
    /// Training wall time (seconds).
    pub seconds: f64,
    /// CPU time of the whole process during training (user + system, seconds).
    pub cpu_seconds: Option<f64>,
    /// Peak resident memory during training (MiB).
    pub peak_ram_mib: Option<f64>,
    pub gaussians: usize,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub dssim1: Option<f64>,
    pub dssim2: Option<f64>,
    pub lpips: Option<f64>,
    /// Held-out PSNR, SSIM and LPIPS inside the moving-object masks.
    pub moving_psnr: Option<f64>,
    pub moving_ssim: Option<f64>,
    pub moving_lpips: Option<f64>,
}

/// The CSV's columns: the setting (the key), then what was measured.
const KEY_COLUMNS: [&str; 5] = [
    "iterations",
    "resolution",
    "max_gaussians",
    "decay",
    "backend",
];
const VALUE_COLUMNS: [&str; 12] = [
    "seconds",
    "cpu_seconds",
    "peak_ram_mib",
    "gaussians",
    "psnr",
    "ssim",
    "dssim1",
    "dssim2",
    "lpips",
    "moving_psnr",
    "moving_ssim",
    "moving_lpips",
];

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| format!("{v}"))
}

impl Setting {
    fn key_cells(&self) -> Vec<String> {
        vec![
            self.iterations.to_string(),
            self.resolution.to_string(),
            self.max_gaussians.to_string(),
            decay_name(self.decay),
            self.backend.name().to_string(),
        ]
    }
}

impl Row {
    fn to_table_row(&self) -> table::Row {
        table::Row {
            key: self.setting.key_cells(),
            values: vec![
                self.seconds.to_string(),
                opt(self.cpu_seconds),
                opt(self.peak_ram_mib),
                self.gaussians.to_string(),
                opt(self.psnr),
                opt(self.ssim),
                opt(self.dssim1),
                opt(self.dssim2),
                opt(self.lpips),
                opt(self.moving_psnr),
                opt(self.moving_ssim),
                opt(self.moving_lpips),
            ],
        }
    }

    fn from_table_row(row: &table::Row) -> Result<Self, String> {
        let f: Vec<&str> = row
            .key
            .iter()
            .chain(&row.values)
            .map(String::as_str)
            .collect();
        let num = |i: usize| -> Result<f64, String> {
            f[i].parse::<f64>()
                .map_err(|_| format!("'{}' is not a number", f[i]))
        };
        let maybe = |i: usize| -> Result<Option<f64>, String> {
            if f[i].is_empty() {
                Ok(None)
            } else {
                num(i).map(Some)
            }
        };
        let int = |i: usize| -> Result<u64, String> {
            f[i].parse::<u64>()
                .map_err(|_| format!("'{}' is not a count", f[i]))
        };
        let backend = match f[4] {
            "cpu" => TrainOn::Cpu,
            "gpu" => TrainOn::Gpu,
            other => return Err(format!("'{other}' is not a backend")),
        };
        Ok(Self {
            setting: Setting {
                iterations: int(0)?,
                resolution: num(1)?,
                max_gaussians: int(2)? as usize,
                decay: parse_decay(f[3])?,
                backend,
            },
            seconds: num(5)?,
            cpu_seconds: maybe(6)?,
            peak_ram_mib: maybe(7)?,
            gaussians: int(8)? as usize,
            psnr: maybe(9)?,
            ssim: maybe(10)?,
            dssim1: maybe(11)?,
            dssim2: maybe(12)?,
            lpips: maybe(13)?,
            moving_psnr: maybe(14)?,
            moving_ssim: maybe(15)?,
            moving_lpips: maybe(16)?,
        })
    }
}

/// The tradeoff table kept in `path` (empty when it does not exist).
fn open_table(path: &Path) -> anyhow::Result<Table> {
    Table::open(path, &KEY_COLUMNS, &VALUE_COLUMNS)
}

/// The rows of a tradeoff CSV; an error names the file and the bad row.
pub fn read_csv(path: &Path) -> anyhow::Result<Vec<Row>> {
    rows_of(&open_table(path)?)
}

fn rows_of(table: &Table) -> anyhow::Result<Vec<Row>> {
    table
        .rows()
        .iter()
        .enumerate()
        .map(|(i, r)| {
            Row::from_table_row(r).map_err(|e| {
                anyhow::anyhow!(
                    "{} row {}: {e}; fix or delete that row (it is measured again)",
                    table.path().display(),
                    i + 2
                )
            })
        })
        .collect()
}

/// Indices of the rows on the Pareto front of (less time, more held-out PSNR): no other
/// row is at least as fast and at least as good, and better in one. Rows without a PSNR
/// are never on it.
pub fn pareto_front(rows: &[Row]) -> Vec<usize> {
    let point = |r: &Row| r.psnr.map(|p| (r.seconds, p));
    (0..rows.len())
        .filter(|&i| {
            let Some((t, p)) = point(&rows[i]) else {
                return false;
            };
            !rows.iter().enumerate().any(|(j, o)| {
                j != i
                    && point(o)
                        .is_some_and(|(to, po)| to <= t && po >= p && (to < t || po > p || j < i))
            })
        })
        .collect()
}

/// The rows with a PSNR as plot points, labelled with their iterations and whatever else
/// varies between the rows (decay, budget, backend).
pub fn plot_points(rows: &[Row]) -> Vec<PlotPoint> {
    let varies =
        |f: &dyn Fn(&Setting) -> String| rows.iter().any(|r| f(&r.setting) != f(&rows[0].setting));
    let decay_varies = varies(&|s| decay_name(s.decay));
    let cap_varies = varies(&|s| s.max_gaussians.to_string());
    let backend_varies = varies(&|s| s.backend.name().to_string());
    let front = pareto_front(rows);
    rows.iter()
        .enumerate()
        .filter_map(|(i, r)| {
            let s = &r.setting;
            let mut label = format!("{} it", s.iterations);
            if decay_varies {
                label += &format!(" {}", decay_name(s.decay));
            }
            if cap_varies {
                label += &format!(" {}k", s.max_gaussians / 1000);
            }
            if backend_varies {
                label += &format!(" {}", s.backend.name());
            }
            Some(PlotPoint {
                seconds: r.seconds,
                psnr: r.psnr?,
                resolution: s.resolution,
                label,
                on_front: front.contains(&i),
            })
        })
        .collect()
}

/// The rows as a Markdown table sorted by time, Pareto rows marked ★.
pub fn markdown(header: &str, rows: &[Row]) -> String {
    let front = pareto_front(rows);
    let mut order: Vec<usize> = (0..rows.len()).collect();
    order.sort_by(|&a, &b| rows[a].seconds.total_cmp(&rows[b].seconds));
    let cell = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
    let mut s = format!(
        "# Accuracy against training time\n\n{header}\n\n![held-out PSNR against training time](tradeoff.png)\n\n★: on the Pareto front (no other setting is both faster and better).\n\n| | iterations | resolution | max Gaussians | decay | backend | train time | CPU s | peak RAM MiB | Gaussians | PSNR ↑ | SSIM ↑ | DSSIM₁ ↓ | LPIPS ↓ | moving PSNR ↑ |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    );
    for i in order {
        let r = &rows[i];
        let st = &r.setting;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            if front.contains(&i) { "★" } else { "" },
            st.iterations,
            st.resolution,
            st.max_gaussians,
            decay_name(st.decay),
            st.backend.name(),
            crate::report::format_duration(r.seconds),
            cell(r.cpu_seconds, 0),
            cell(r.peak_ram_mib, 0),
            r.gaussians,
            cell(r.psnr, 2),
            cell(r.ssim, 3),
            cell(r.dssim1, 4),
            r.lpips.map_or("skipped".into(), |v| format!("{v:.4}")),
            cell(r.moving_psnr, 2),
        );
    }
    s
}

/// Where the tradeoff bench writes: `work/bench/tradeoff/` of the capture, or
/// `tradeoff-FRAMESxWxH/` with the training views stretched.
pub fn out_dir(bench_dir: &Path, stretch: Option<Stretch>) -> PathBuf {
    match stretch {
        None => bench_dir.join("tradeoff"),
        Some(s) => bench_dir.join(format!("tradeoff-{}x{}x{}", s.frames, s.width, s.height)),
    }
}

/// Run the bench; returns the path of `tradeoff.md`.
pub fn run(source: &BenchSource, grid: &Grid, reporter: &Reporter) -> anyhow::Result<PathBuf> {
    grid.check()?;
    let mut inputs = inputs::prepare(source, reporter)?;
    if let Some(stretch) = grid.stretch {
        reporter.say(&format!(
            "tradeoff: {} training views stretched to {} frames per camera at {}×{}",
            inputs.dataset.views.len(),
            stretch.frames,
            stretch.width,
            stretch.height
        ));
        inputs.dataset = stretch.apply(&inputs.dataset);
    }
    let out = out_dir(&inputs.bench_dir, grid.stretch);
    let settings = grid.settings(
        inputs.config.train.densify.max_gaussians,
        inputs.config.decay.variant,
    );
    let rows = measure_missing(&inputs, &settings, &out.join("tradeoff.csv"), reporter)?;
    // The table and plot show every setting measured on this capture (this grid's and
    // earlier ones'); delete tradeoff.csv to start afresh.
    let shown = rows;
    let header = format!(
        "{}, seed {}. {} Machine: {}. Last command: `pipeline bench tradeoff {}`.",
        inputs.describe(source),
        inputs.config.train.seed,
        crate::bench::inputs::lpips_note(inputs.lpips.as_ref()),
        sysinfo::describe_machine(),
        grid.describe(source)
    );
    crate::bench::tradeoff_plot::plot(&plot_points(&shown), &out.join("tradeoff.png"))?;
    let md = out.join("tradeoff.md");
    shared_types::atomic::write_atomic(&md, markdown(&header, &shown).as_bytes())?;
    Ok(md)
}

/// Train and measure the `settings` not yet in the table `csv_path` (each row written as
/// soon as it is measured, each run in `runs/KEY/` beside the table); returns every row of
/// the table, those measured before included.
pub fn measure_missing(
    inputs: &BenchInputs,
    settings: &[Setting],
    csv_path: &Path,
    reporter: &Reporter,
) -> anyhow::Result<Vec<Row>> {
    let out = csv_path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut table = open_table(csv_path)?;
    let mut rows = rows_of(&table)?;
    let todo: Vec<Setting> = settings
        .iter()
        .filter(|s| !rows.iter().any(|r| r.setting.key() == s.key()))
        .copied()
        .collect();
    reporter.say(&format!(
        "{} settings, {} already measured in {}, {} to train",
        settings.len(),
        settings.len() - todo.len(),
        csv_path.display(),
        todo.len()
    ));
    let grid_progress = reporter.progress("settings");
    shared_types::Progress::start(
        &grid_progress,
        todo.iter().map(Setting::work).sum(),
        "full-size steps",
    );
    let evaluator = crate::engine_inputs::render_backend(inputs.config.engine.backend)?;
    // A row measured before the held-out views had moving-region masks is scored again
    // from its saved model, not trained again.
    if inputs.heldout.iter().any(|v| v.mask.is_some()) {
        let background = inputs.config.train.background.resolve(&inputs.dataset);
        for row in rows.iter_mut().filter(|r| r.moving_psnr.is_none()) {
            let dir = out.join("runs").join(row.setting.key());
            if !dir.join(splat4d::train::MODEL_FILE).is_file() {
                continue;
            }
            reporter.say(&format!("{}: scoring its moving region", row.setting.key()));
            let progress = reporter.progress("eval");
            row.set_scores(&score(
                inputs,
                &dir,
                background,
                evaluator.as_ref(),
                &progress,
            )?);
            shared_types::Progress::finish(&progress);
            table.insert(row.to_table_row())?;
            table.write_csv()?;
        }
    }
    for (k, setting) in todo.iter().enumerate() {
        shared_types::Progress::message(
            &grid_progress,
            &format!("{}/{}: {}", k + 1, todo.len(), setting.key()),
        );
        let row = measure(inputs, setting, out, evaluator.as_ref(), reporter)
            .with_context(|| format!("setting {}", setting.key()))?;
        reporter.say(&format!(
            "{} trained in {}, held-out PSNR {}",
            setting.key(),
            crate::report::format_duration(row.seconds),
            row.psnr.map_or("–".into(), |p| format!("{p:.2} dB"))
        ));
        table.insert(row.to_table_row())?;
        table.write_csv()?;
        rows.push(row);
        shared_types::Progress::advance(&grid_progress, setting.work());
    }
    shared_types::Progress::finish(&grid_progress);
    Ok(rows)
}

impl Grid {
    /// The command-line arguments that give this grid.
    pub fn describe(&self, source: &BenchSource) -> String {
        let join = |v: Vec<String>| v.join(",");
        let mut s = match source {
            BenchSource::Scene { scene, capture_dir } => {
                format!("{} {}", scene.display(), capture_dir.display())
            }
            BenchSource::Capture(dir) => dir.display().to_string(),
            BenchSource::Prepared(dir) => format!("{} --as-prepared", dir.display()),
        };
        let _ = write!(
            s,
            " --iterations {} --resolution {}",
            join(self.iterations.iter().map(u64::to_string).collect()),
            join(self.resolution.iter().map(f64::to_string).collect())
        );
        if !self.max_gaussians.is_empty() {
            let _ = write!(
                s,
                " --max-gaussians {}",
                join(self.max_gaussians.iter().map(usize::to_string).collect())
            );
        }
        if !self.decay.is_empty() {
            let _ = write!(
                s,
                " --decay {}",
                join(self.decay.iter().map(|d| decay_name(*d)).collect())
            );
        }
        let _ = write!(
            s,
            " --backend {}",
            join(self.backend.iter().map(|b| b.name().to_string()).collect())
        );
        if let Some(stretch) = self.stretch {
            let _ = write!(s, " --stretch {stretch}");
        }
        s
    }
}

/// Train and measure one setting (its run folder is started afresh).
fn measure(
    inputs: &BenchInputs,
    setting: &Setting,
    out: &Path,
    evaluator: &dyn RenderBackend,
    reporter: &Reporter,
) -> anyhow::Result<Row> {
    let config = &inputs.config;
    let (mut train, mut decay) =
        crate::presets::schedule_for(&config.train, &config.decay, setting.iterations);
    train.resolution = setting.resolution;
    train.densify.max_gaussians = setting.max_gaussians;
    decay.variant = setting.decay;
    let backend: Box<dyn RenderBackend> = match setting.backend {
        TrainOn::Cpu => Box::new(splat4d::CpuBackend),
        TrainOn::Gpu => Box::new(
            splat4d::render::gpu::GpuBackend::new(splat4d::gpu::AdapterPolicy::from_env())
                .context("--backend gpu")?,
        ),
    };
    let dir = out.join("runs").join(setting.key());
    if dir.exists() {
        std::fs::remove_dir_all(&dir)
            .with_context(|| format!("cannot clear the unfinished run {}", dir.display()))?;
    }
    let mut hooks = DecayHooks::new(&decay).map_err(|e| anyhow::anyhow!("decay: {e}"))?;
    let progress = reporter.progress("train");
    let memory = sysinfo::PeakMemory::reset();
    let cpu0 = sysinfo::cpu_seconds();
    let started = Instant::now();
    let summary = splat4d::train::train(
        backend.as_ref(),
        &train,
        &inputs.dataset,
        &inputs.points,
        &dir,
        false,
        &mut hooks,
        &progress,
    )?;
    let seconds = started.elapsed().as_secs_f64();
    let cpu_seconds = cpu0.zip(sysinfo::cpu_seconds()).map(|(a, b)| b - a);
    let peak_ram_mib = memory.peak_mib();
    let report = score(inputs, &dir, summary.background, evaluator, &progress)?;
    shared_types::Progress::finish(&progress);
    let mut row = Row {
        setting: *setting,
        seconds,
        cpu_seconds,
        peak_ram_mib,
        gaussians: 0,
        psnr: None,
        ssim: None,
        dssim1: None,
        dssim2: None,
        lpips: None,
        moving_psnr: None,
        moving_ssim: None,
        moving_lpips: None,
    };
    row.set_scores(&report);
    Ok(row)
}

/// Measure the model trained into `dir` (`model.bin`, and `backdrop.bin` when it has one)
/// on the held-out views, drawn on `background`; its files go to `dir/eval/`.
fn score(
    inputs: &BenchInputs,
    dir: &Path,
    background: [f32; 3],
    evaluator: &dyn RenderBackend,
    progress: &dyn shared_types::Progress,
) -> anyhow::Result<(usize, splat4d::eval::EvalReport)> {
    let model = splat4d::load_model(&dir.join(splat4d::train::MODEL_FILE))?;
    let backdrop_path = dir.join(splat4d::train::BACKDROP_FILE);
    let backdrop = backdrop_path
        .is_file()
        .then(|| splat4d::render::backdrop::load_backdrop(&backdrop_path))
        .transpose()?;
    let report = splat4d::eval::evaluate(
        evaluator,
        &model,
        &inputs.heldout,
        &[],
        &dir.join("eval"),
        inputs.lpips.as_ref(),
        background,
        backdrop.as_ref(),
        progress,
    )?;
    Ok((model.len(), report))
}

impl Row {
    /// Take the Gaussian count and held-out scores of a [`score`].
    fn set_scores(&mut self, (gaussians, report): &(usize, splat4d::eval::EvalReport)) {
        let m = &report.heldout;
        let moving = m.moving.as_ref();
        self.gaussians = *gaussians;
        self.psnr = m.psnr;
        self.ssim = m.ssim;
        self.dssim1 = m.dssim1;
        self.dssim2 = m.dssim2;
        self.lpips = m.lpips;
        self.moving_psnr = moving.and_then(|mv| mv.psnr);
        self.moving_ssim = moving.and_then(|mv| mv.ssim);
        self.moving_lpips = moving.and_then(|mv| mv.lpips);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(it: u64, seconds: f64, psnr: Option<f64>) -> Row {
        Row {
            setting: Setting {
                iterations: it,
                resolution: 0.5,
                max_gaussians: 1000,
                decay: DecayVariant::Neural,
                backend: TrainOn::Cpu,
            },
            seconds,
            cpu_seconds: Some(seconds * 1.9),
            peak_ram_mib: None,
            gaussians: 10,
            psnr,
            ssim: Some(0.5),
            dssim1: Some(0.25),
            dssim2: Some(0.2),
            lpips: None,
            moving_psnr: Some(18.5),
            moving_ssim: Some(0.4),
            moving_lpips: None,
        }
    }

    #[test]
    fn the_pareto_front_keeps_only_undominated_points() {
        let rows = vec![
            row(100, 10.0, Some(18.0)),
            row(200, 20.0, Some(17.0)), // slower and worse than the first
            row(300, 30.0, Some(21.0)),
            row(400, 30.0, Some(20.0)), // as slow as the third, worse
            row(500, 5.0, None),        // no PSNR: never on the front
            row(600, 40.0, Some(21.0)), // slower, not better
            row(700, 10.0, Some(18.0)), // a tie with the first: one of the two
        ];
        assert_eq!(pareto_front(&rows), vec![0, 2]);
    }

    #[test]
    fn plot_points_label_what_varies_and_mark_the_front() {
        let mut rows = vec![row(100, 10.0, Some(18.0)), row(200, 20.0, Some(17.0))];
        let points = plot_points(&rows);
        assert_eq!(points[0].label, "100 it");
        assert!(points[0].on_front && !points[1].on_front);
        rows[1].setting.decay = DecayVariant::None;
        rows.push(row(300, 5.0, None));
        let points = plot_points(&rows);
        assert_eq!(points.len(), 2, "a row without PSNR is not drawn");
        assert_eq!(points[1].label, "200 it none");
    }

    #[test]
    fn rows_survive_the_csv_and_bad_lines_name_the_file() {
        let rows = vec![row(100, 10.5, Some(18.25)), row(200, 20.0, None)];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tradeoff.csv");
        let mut table = open_table(&path).unwrap();
        for r in &rows {
            table.insert(r.to_table_row()).unwrap();
        }
        table.write_csv().unwrap();
        assert_eq!(read_csv(&path).unwrap(), rows);
        let good = std::fs::read_to_string(&path).unwrap();
        std::fs::write(&path, good.clone() + "1,2,3\n").unwrap();
        let e = read_csv(&path).unwrap_err().to_string();
        assert!(e.contains("tradeoff.csv: row 4"), "{e}");
        std::fs::write(&path, good.replace(",neural,", ",nerual,")).unwrap();
        let e = read_csv(&path).unwrap_err().to_string();
        assert!(
            e.contains("tradeoff.csv row 2") && e.contains("nerual"),
            "{e}"
        );
        std::fs::write(&path, "a,b\n").unwrap();
        let e = read_csv(&path).unwrap_err().to_string();
        assert!(e.contains("columns"), "{e}");
    }

    #[test]
    fn the_grid_is_every_combination_with_the_capture_defaults() {
        let grid = Grid {
            iterations: vec![100, 200],
            resolution: vec![0.5, 1.0],
            max_gaussians: vec![],
            decay: vec![DecayVariant::None, DecayVariant::Neural],
            backend: vec![TrainOn::Cpu],
            stretch: None,
        };
        let s = grid.settings(5000, DecayVariant::Exp);
        assert_eq!(s.len(), 8);
        assert!(s.iter().all(|s| s.max_gaussians == 5000));
        let keys: std::collections::BTreeSet<String> = s.iter().map(Setting::key).collect();
        assert_eq!(keys.len(), 8);
        assert!(keys.contains("it200-res0.5-cap5000-none-cpu"), "{keys:?}");
        for bad in [
            Grid {
                iterations: vec![0],
                ..grid.clone()
            },
            Grid {
                resolution: vec![1.5],
                ..grid.clone()
            },
            Grid {
                backend: vec![],
                ..grid.clone()
            },
        ] {
            assert!(bad.check().is_err());
        }
        assert_eq!(parse_decay("neural"), Ok(DecayVariant::Neural));
        assert!(parse_decay("nerual").unwrap_err().contains("nerual"));
    }
}
