//! Running the stage graph: decide which stages are up to date, run the others in order,
//! and swap each stage's outputs in only when it succeeds.
//!
//! A stage is rerun when its parameters, one of its capture inputs, or the outputs of an
//! upstream stage changed (content hashes, so an upstream rerun that reproduces identical
//! outputs does not force the whole chain to rerun), when one of its outputs went missing,
//! or with `--force`. Outputs are written to `work/.<stage>.partial/` and renamed to
//! `work/<stage>/` on success; a stage that finishes without one of its required outputs
//! has failed. A failure or an interruption leaves the previous outputs untouched and is
//! recorded in `work/.status/<stage>.json` for `status`.

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::fs;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, bail};
use chrono::{DateTime, Utc};
use serde::Serialize;

use crate::config::CaptureConfig;
use crate::layout::Capture;
use crate::lock::CaptureLock;
use crate::manifest::{
    InputRecord, MANIFEST_VERSION, Manifest, RunRecord, RunState, file_stamp, hash_bytes,
    record_input, record_outputs,
};
use crate::partial_dir::{partial_path, recover_interrupted_swap, swap_in};
use crate::report::{Event, Reporter};
use crate::stage_context::StageContext;
use crate::stage_def::{RunFn, StageDef};

/// The stages of a pipeline, in execution order.
pub struct Pipeline {
    pub stages: Vec<StageDef>,
}

/// Which stages a run covers.
#[derive(Clone, Debug, Default)]
pub struct Selection {
    /// First stage to run (default: the first).
    pub from: Option<String>,
    /// Last stage to run (default: the last).
    pub to: Option<String>,
    /// Run just this stage.
    pub only: Option<String>,
    /// Rerun selected stages even when they are up to date.
    pub force: bool,
    /// With `only = "train"`: train just this time chunk of a clip cut into chunks
    /// (`crate::chunks`), leaving the stage unfinished for the run that trains the rest and
    /// merges them (one Slurm job per chunk). Several such runs share the capture's lock.
    pub chunk: Option<usize>,
}

/// What a run did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RunSummary {
    pub ran: Vec<String>,
    pub skipped: Vec<String>,
    pub not_implemented: Vec<String>,
    /// Stages that could not run because a stage they read from failed or is missing.
    pub blocked: Vec<String>,
    /// The stage that failed, with its error.
    pub failed: Option<(String, String)>,
}

impl RunSummary {
    /// True when nothing failed and nothing was left out for lack of an implementation.
    pub fn complete(&self) -> bool {
        self.failed.is_none() && self.not_implemented.is_empty() && self.blocked.is_empty()
    }
}

/// Whether a stage's recorded outputs match its current inputs and parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum Freshness {
    UpToDate,
    /// Out of date, with the reasons (which input or parameter changed).
    Stale(Vec<String>),
    /// Never ran (no manifest).
    Missing,
}

/// The state `status` shows for a stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    Done,
    Stale,
    Missing,
    Failed,
    Running,
    /// Submitted to Slurm, waiting to start (`pipeline submit`).
    Queued,
    /// Its Slurm job was cancelled, or never will start because the job it waited for
    /// failed.
    Cancelled,
}

/// One row of `pipeline status`.
#[derive(Clone, Debug, Serialize)]
pub struct StageStatus {
    pub stage: String,
    pub state: State,
    pub implemented: bool,
    /// When the current outputs were made.
    pub when: Option<DateTime<Utc>>,
    pub duration_s: Option<f64>,
    /// Why stale / failed, or notes.
    pub details: Vec<String>,
    /// The Slurm job of the latest `pipeline submit` that runs (or ran) it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub job: Option<String>,
}

impl Pipeline {
    pub fn stage_names(&self) -> Vec<&'static str> {
        self.stages.iter().map(|s| s.name).collect()
    }

    fn index_of(&self, name: &str) -> anyhow::Result<usize> {
        self.stages
            .iter()
            .position(|s| s.name == name)
            .with_context(|| {
                format!(
                    "unknown stage `{name}`; the stages are: {}",
                    self.stage_names().join(", ")
                )
            })
    }

    /// Indices of the stages a selection covers.
    pub fn select(&self, sel: &Selection) -> anyhow::Result<Vec<usize>> {
        if let Some(only) = &sel.only {
            if sel.from.is_some() || sel.to.is_some() {
                bail!("--only cannot be combined with --from or --to");
            }
            return Ok(vec![self.index_of(only)?]);
        }
        let from = sel
            .from
            .as_deref()
            .map(|s| self.index_of(s))
            .transpose()?
            .unwrap_or(0);
        let to = sel
            .to
            .as_deref()
            .map(|s| self.index_of(s))
            .transpose()?
            .unwrap_or(self.stages.len() - 1);
        if from > to {
            bail!(
                "--from {} comes after --to {}",
                self.stages[from].name,
                self.stages[to].name
            );
        }
        Ok((from..=to).collect())
    }

    /// Current inputs of a stage (capture files hashed, upstream output digests).
    fn current_inputs(
        &self,
        stage: &StageDef,
        capture: &Capture,
        config: &CaptureConfig,
        previous: Option<&Manifest>,
    ) -> anyhow::Result<BTreeMap<String, InputRecord>> {
        let mut inputs = BTreeMap::new();
        for path in expand_inputs((stage.inputs)(capture, config))? {
            let key = path
                .strip_prefix(&capture.root)
                .unwrap_or(&path)
                .to_string_lossy()
                .replace('\\', "/");
            let prev = previous.and_then(|m| m.inputs.get(&key));
            let record = record_input(&path, prev)
                .with_context(|| format!("cannot read input {}", path.display()))?;
            inputs.insert(key, record);
        }
        for up in &stage.after {
            let digest = Manifest::read(&capture.work_dir().join(up))
                .map(|m| m.outputs_digest)
                .unwrap_or_else(|| hash_bytes(b"missing"));
            inputs.insert(
                format!("stage:{up}"),
                InputRecord {
                    hash: digest,
                    size: None,
                    modified_ns: None,
                },
            );
        }
        Ok(inputs)
    }

    /// Compare a stage's manifest with its current inputs and parameters.
    fn freshness(
        stage_dir: &Path,
        previous: Option<&Manifest>,
        inputs: &BTreeMap<String, InputRecord>,
        params: &serde_json::Value,
        stage: &str,
    ) -> Freshness {
        let Some(prev) = previous else {
            return Freshness::Missing;
        };
        let mut reasons = Vec::new();
        diff_json(stage, &prev.parameters, params, &mut reasons);
        let keys: BTreeSet<&String> = prev.inputs.keys().chain(inputs.keys()).collect();
        for key in keys {
            let name = match key.strip_prefix("stage:") {
                Some(up) => format!("outputs of `{up}`"),
                None => format!("input {key}"),
            };
            match (prev.inputs.get(key), inputs.get(key)) {
                (Some(a), Some(b)) if a.hash != b.hash => reasons.push(format!("{name} changed")),
                (None, Some(_)) => reasons.push(format!("{name} added")),
                (Some(_), None) => reasons.push(format!("{name} removed")),
                _ => {}
            }
        }
        for (rel, out) in &prev.outputs {
            match file_stamp(&stage_dir.join(rel)) {
                Err(_) => reasons.push(format!("output {rel} is missing")),
                Ok((size, _)) if size != out.size => {
                    reasons.push(format!("output {rel} was modified"))
                }
                Ok(_) => {}
            }
        }
        if reasons.is_empty() {
            Freshness::UpToDate
        } else {
            Freshness::Stale(reasons)
        }
    }

    /// The state of every stage, for `pipeline status`.
    pub fn status(
        &self,
        capture: &Capture,
        config: &CaptureConfig,
    ) -> anyhow::Result<Vec<StageStatus>> {
        let work = capture.work_dir();
        let lock_held = CaptureLock::is_held(&work);
        let mut rows: Vec<StageStatus> = Vec::new();
        for stage in &self.stages {
            let dir = work.join(stage.name);
            let manifest = Manifest::read(&dir);
            let inputs = self.current_inputs(stage, capture, config, manifest.as_ref())?;
            let params = (stage.params)(config);
            let mut row = StageStatus {
                stage: stage.name.to_string(),
                state: State::Done,
                implemented: stage.run.is_some(),
                when: manifest.as_ref().map(|m| m.started),
                duration_s: manifest.as_ref().map(|m| m.duration_s),
                details: Vec::new(),
                job: None,
            };
            match Self::freshness(&dir, manifest.as_ref(), &inputs, &params, stage.name) {
                Freshness::UpToDate => {}
                Freshness::Missing => row.state = State::Missing,
                Freshness::Stale(reasons) => {
                    row.state = State::Stale;
                    row.details = reasons;
                }
            }
            for up in &stage.after {
                if let Some(up_row) = rows.iter().find(|r| r.stage == *up)
                    && up_row.state != State::Done
                    && row.state != State::Missing
                {
                    row.state = State::Stale;
                    let what = match up_row.state {
                        State::Missing => "has not run",
                        State::Failed => "failed",
                        State::Running => "is running",
                        State::Queued => "is queued",
                        State::Cancelled => "was cancelled",
                        _ => "is stale",
                    };
                    row.details.push(format!("upstream `{up}` {what}"));
                }
            }
            if let Some(record) = RunRecord::read(&work, stage.name) {
                let kept = if manifest.is_some() {
                    "; the previous outputs are kept"
                } else {
                    ""
                };
                match record.state {
                    RunState::Running if lock_held => {
                        row.state = State::Running;
                        row.details.insert(
                            0,
                            format!("running since {}", record.started.format("%H:%M:%S")),
                        );
                    }
                    RunState::Running => {
                        row.state = State::Failed;
                        row.details.insert(
                            0,
                            format!(
                                "interrupted (run started {}){kept}",
                                fmt_time(record.started)
                            ),
                        );
                    }
                    RunState::Failed => {
                        row.state = State::Failed;
                        let error = record.error.unwrap_or_default();
                        row.details.insert(
                            0,
                            format!("failed at {}: {error}{kept}", fmt_time(record.started)),
                        );
                    }
                }
            }
            if !row.implemented && row.state == State::Missing {
                row.details.push("not implemented yet".into());
            }
            rows.push(row);
        }
        Ok(rows)
    }

    /// Run the selected stages on a validated capture directory. Takes the capture's lock
    /// for the whole run.
    pub fn run(
        &self,
        capture: &Capture,
        config: &CaptureConfig,
        sel: &Selection,
        reporter: &Reporter,
    ) -> anyhow::Result<RunSummary> {
        let selected = self.select(sel)?;
        let work = capture.work_dir();
        let _lock = match sel.chunk {
            Some(_) if sel.only.as_deref() != Some("train") || sel.force => bail!(
                "--chunk K trains one time chunk of the train stage: give it with --only train and without --force"
            ),
            Some(_) => CaptureLock::acquire_shared(&work)?,
            None => CaptureLock::acquire(&work)?,
        };
        for stage in &self.stages {
            recover_interrupted_swap(&work.join(stage.name));
        }
        let mut summary = RunSummary::default();
        let mut unavailable: HashSet<&str> = HashSet::new();
        for &index in &selected {
            let stage = &self.stages[index];
            if let Some(up) = stage.after.iter().find(|up| unavailable.contains(**up)) {
                reporter.event(&Event::StageBlocked {
                    stage: stage.name,
                    upstream: up,
                });
                summary.blocked.push(stage.name.to_string());
                unavailable.insert(stage.name);
                continue;
            }
            let Some(run) = &stage.run else {
                reporter.event(&Event::StageNotImplemented { stage: stage.name });
                summary.not_implemented.push(stage.name.to_string());
                unavailable.insert(stage.name);
                continue;
            };
            if let Some(up) = stage
                .after
                .iter()
                .find(|up| Manifest::read(&work.join(up)).is_none())
            {
                let error = format!(
                    "needs the outputs of `{up}`, which has not run; run `pipeline run {} --to {up}` first",
                    capture.root.display()
                );
                reporter.event(&Event::StageFailed {
                    stage: stage.name,
                    error: &error,
                });
                summary.failed = Some((stage.name.to_string(), error));
                unavailable.insert(stage.name);
                continue;
            }
            let dir = work.join(stage.name);
            let previous = Manifest::read(&dir);
            let inputs = self.current_inputs(stage, capture, config, previous.as_ref())?;
            let params = (stage.params)(config);
            let reasons =
                match Self::freshness(&dir, previous.as_ref(), &inputs, &params, stage.name) {
                    Freshness::UpToDate if !sel.force => {
                        RunRecord::clear(&work, stage.name);
                        reporter.event(&Event::StageSkipped {
                            stage: stage.name,
                            reason: "up to date",
                        });
                        summary.skipped.push(stage.name.to_string());
                        continue;
                    }
                    Freshness::UpToDate => vec!["--force".to_string()],
                    Freshness::Missing => vec!["not run before".to_string()],
                    Freshness::Stale(reasons) => reasons,
                };
            reporter.event(&Event::StageStarted {
                stage: stage.name,
                reasons: &reasons,
            });
            match execute(stage, run, capture, config, params, inputs, sel, reporter) {
                Ok(manifest) => {
                    reporter.event(&Event::StageFinished {
                        stage: stage.name,
                        duration_s: manifest.duration_s,
                        outputs: manifest.outputs.len(),
                    });
                    summary.ran.push(stage.name.to_string());
                }
                Err(e) => {
                    let error = crate::error_chain(&e);
                    reporter.event(&Event::StageFailed {
                        stage: stage.name,
                        error: &error,
                    });
                    summary.failed = Some((stage.name.to_string(), error));
                    unavailable.insert(stage.name);
                }
            }
        }
        Ok(summary)
    }
}

/// Run one stage into its partial folder and swap the result in (a run of one chunk,
/// `sel.chunk`, leaves the partial folder as it is for the run that finishes the stage).
#[allow(clippy::too_many_arguments)] // one stage's whole context, each used once
fn execute(
    stage: &StageDef,
    run: &RunFn,
    capture: &Capture,
    config: &CaptureConfig,
    params: serde_json::Value,
    inputs: BTreeMap<String, InputRecord>,
    sel: &Selection,
    reporter: &Reporter,
) -> anyhow::Result<Manifest> {
    let work = capture.work_dir();
    let partial = partial_path(&work.join(stage.name));
    // A resumable stage continues from its partial folder only when that folder was
    // started with the same parameters and inputs (and without --force).
    let key = resume_key(&params, &inputs);
    let key_file = partial.join(RESUME_KEY_FILE);
    let resume =
        stage.resumable && !sel.force && fs::read_to_string(&key_file).is_ok_and(|k| k == key);
    // A later chunk joins the partial folder its first chunk started, never a fresh one.
    if let Some(k) = sel.chunk.filter(|&k| k > 0)
        && !resume
    {
        bail!(
            "chunk {k} trains on the first chunk's static scene, and {} holds no first chunk trained with these settings and inputs; run chunk 0 first (`pipeline run CAPTURE --only {} --chunk 0`)",
            partial.display(),
            stage.name
        );
    }
    if !resume && partial.exists() {
        fs::remove_dir_all(&partial)
            .with_context(|| format!("cannot clear {}", partial.display()))?;
    }
    fs::create_dir_all(&partial).with_context(|| format!("cannot create {}", partial.display()))?;
    if stage.resumable {
        shared_types::atomic::write_atomic(&key_file, key.as_bytes())
            .with_context(|| format!("cannot write {}", key_file.display()))?;
    }
    let started = Utc::now();
    let record = RunRecord {
        state: RunState::Running,
        pid: std::process::id(),
        started,
        error: None,
        duration_s: None,
    };
    record
        .write(&work, stage.name)
        .context("cannot write the run status")?;
    let progress = reporter.progress(stage.name);
    let mut tools = BTreeMap::new();
    tools.insert(
        "pipeline".to_string(),
        env!("CARGO_PKG_VERSION").to_string(),
    );
    let ctx = StageContext {
        capture,
        out_dir: partial.clone(),
        resume,
        chunk: sel.chunk,
        progress: &progress,
        tool_versions: Mutex::new(tools),
    };
    let clock = Instant::now();
    let outcome = match catch_unwind(AssertUnwindSafe(|| run(&ctx, config))) {
        Ok(result) => result,
        Err(panic) => {
            let msg = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(anyhow::anyhow!(
                "internal error (panic): {msg}; please report this"
            ))
        }
    };
    shared_types::Progress::finish(&progress);
    let duration_s = clock.elapsed().as_secs_f64();
    if sel.chunk.is_some() {
        // One chunk's work stays in the partial folder, with its resume key.
        return outcome.map(|()| {
            RunRecord::clear(&work, stage.name);
            Manifest {
                version: MANIFEST_VERSION,
                stage: stage.name.to_string(),
                parameters: params,
                inputs,
                outputs: BTreeMap::new(),
                outputs_digest: String::new(),
                started,
                duration_s,
                tool_versions: BTreeMap::new(),
            }
        });
    }
    let finished = outcome.and_then(|()| {
        if stage.resumable {
            fs::remove_file(&key_file)
                .with_context(|| format!("cannot remove {}", key_file.display()))?;
        }
        for required in &stage.outputs {
            if !required.is_in(&partial) {
                bail!("the stage finished without writing {}", required.describe());
            }
        }
        let (outputs, outputs_digest) =
            record_outputs(&partial).context("cannot hash the outputs")?;
        let manifest = Manifest {
            version: MANIFEST_VERSION,
            stage: stage.name.to_string(),
            parameters: params,
            inputs,
            outputs,
            outputs_digest,
            started,
            duration_s,
            tool_versions: ctx.tool_versions.into_inner().unwrap_or_default(),
        };
        manifest
            .write(&partial)
            .context("cannot write stage.json")?;
        swap_in(&partial, &work.join(stage.name))?;
        Ok(manifest)
    });
    match finished {
        Ok(manifest) => {
            RunRecord::clear(&work, stage.name);
            Ok(manifest)
        }
        Err(e) => {
            let full = crate::disk::is_full(&e);
            let last = work.join(stage.name);
            let needed = full.then(|| crate::disk::needed(&partial, &last, stage.resumable));
            if !stage.resumable {
                let _ = fs::remove_dir_all(&partial);
            }
            let e = match needed {
                Some(needed) => e.context(crate::disk::advice(
                    &work,
                    stage.name,
                    needed,
                    crate::disk::size_of(&last),
                    stage.resumable,
                )),
                None => e,
            };
            let failed = RunRecord {
                state: RunState::Failed,
                error: Some(crate::error_chain(&e)),
                duration_s: Some(duration_s),
                ..record
            };
            let _ = failed.write(&work, stage.name);
            Err(e)
        }
    }
}

/// File in a resumable stage's partial folder naming the run it belongs to.
const RESUME_KEY_FILE: &str = ".resume-key";

/// Identity of a stage run: its parameters and the hashes of its inputs.
fn resume_key(params: &serde_json::Value, inputs: &BTreeMap<String, InputRecord>) -> String {
    let hashes: Vec<(&String, &String)> = inputs.iter().map(|(k, v)| (k, &v.hash)).collect();
    let bytes = serde_json::to_vec(&(params, hashes)).unwrap_or_default();
    hash_bytes(&bytes)
}

/// Expand folders to the files inside them (sorted); skip paths that do not exist.
fn expand_inputs(paths: Vec<PathBuf>) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for path in paths {
        if path.is_dir() {
            for rel in crate::manifest::list_files(&path)
                .with_context(|| format!("cannot list {}", path.display()))?
            {
                out.push(path.join(rel));
            }
        } else if path.exists() {
            out.push(path);
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

/// Describe how two parameter sets differ, one line per changed key.
fn diff_json(
    prefix: &str,
    old: &serde_json::Value,
    new: &serde_json::Value,
    out: &mut Vec<String>,
) {
    use serde_json::Value;
    match (old, new) {
        (Value::Object(a), Value::Object(b)) => {
            let keys: BTreeSet<&String> = a.keys().chain(b.keys()).collect();
            for key in keys {
                let path = format!("{prefix}.{key}");
                match (a.get(key), b.get(key)) {
                    (Some(x), Some(y)) => diff_json(&path, x, y, out),
                    (None, Some(y)) => out.push(format!("parameter {path} added ({y})")),
                    (Some(x), None) => out.push(format!("parameter {path} removed (was {x})")),
                    (None, None) => {}
                }
            }
        }
        (a, b) if a != b => out.push(format!("parameter {prefix} changed: {a} → {b}")),
        _ => {}
    }
}

fn fmt_time(t: DateTime<Utc>) -> String {
    t.with_timezone(&chrono::Local)
        .format("%Y-%m-%d %H:%M:%S")
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_changes_are_named() {
        let mut out = Vec::new();
        diff_json(
            "sync",
            &serde_json::json!({"method": "auto", "max": 1.0, "nested": {"a": 1}}),
            &serde_json::json!({"method": "audio", "max": 1.0, "nested": {"a": 2}, "new": true}),
            &mut out,
        );
        assert_eq!(
            out,
            vec![
                "parameter sync.method changed: \"auto\" → \"audio\"",
                "parameter sync.nested.a changed: 1 → 2",
                "parameter sync.new added (true)",
            ]
        );
    }
}
