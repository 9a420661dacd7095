//! Captures on a Slurm cluster: `pipeline submit` makes every stale stage of a capture one
//! batch job, each waiting for the one before (`afterok`), so Slurm does all the
//! scheduling; `status` shows the jobs' states, `cancel` cancels them.
//!
//! The manifests decide what is stale, as for `pipeline run` (the same
//! [`Pipeline::status`]), and every job runs `pipeline run CAPTURE --only STAGE`. Nothing
//! here queues or dispatches work: a capture's jobs run one after another (they share the
//! capture's lock, `work/.lock`), different captures side by side as Slurm sees fit.
//!
//! - `config`: the `[cluster]` settings (capture.toml, and a user-level file).
//! - `jobs`: the jobs file, each job's script and `sbatch` arguments.
//! - `nodes`: what the nodes offer (`sinfo`); every request is checked against them
//!   before anything is queued.
//! - `slurm`: the Slurm commands and the parsers of their output.
//! - `user_file`: the user-level `[cluster]` file.

pub mod config;
pub mod jobs;
pub mod memory;
pub mod nodes;
pub mod slurm;
pub mod user_file;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use thiserror::Error;

use crate::config::{CaptureConfig, ConfigError};
use crate::layout::Capture;
use crate::lock::{CaptureLock, LockError};
use crate::manifest::Manifest;
use crate::runner::{Pipeline, Selection, StageStatus, State};
use config::ClusterSettings;
use jobs::{StageJob, Submission, SubmittedJob};
use slurm::{JobInfo, JobState, SlurmError};

/// Why a capture could not be submitted, shown or cancelled.
#[derive(Debug, Error)]
pub enum ClusterError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Slurm(#[from] SlurmError),
    #[error(transparent)]
    Lock(#[from] LockError),
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{capture} has jobs in Slurm ({jobs}); wait for them (`pipeline status {capture}`) or cancel them (`pipeline cancel {capture}`)",
        capture = .capture.display()
    )]
    Busy { capture: PathBuf, jobs: String },
    #[error(
        "stage `{stage}` needs the outputs of `{upstream}`, which has not run; submit from it (`--from {upstream}`)"
    )]
    MissingUpstream { stage: String, upstream: String },
    #[error(
        "submitting stage `{stage}` of {capture}: {source}; the jobs submitted before it were cancelled ({hint})",
        capture = .capture.display()
    )]
    Submit {
        stage: String,
        capture: PathBuf,
        source: SlurmError,
        hint: &'static str,
    },
    #[error(
        "nothing submitted for {capture}: {message} (docs/cluster.md)",
        capture = .capture.display()
    )]
    DoesNotFit { capture: PathBuf, message: String },
    #[error("cannot tell which stages of {capture} are stale: {message}", capture = .capture.display())]
    Stages { capture: PathBuf, message: String },
    #[error(
        "cannot find the path of this `pipeline` binary ({0}); set `pipeline` under [cluster] to the binary the compute nodes run"
    )]
    NoBinary(std::io::Error),
}

/// The `[cluster]` settings of a capture: the user-level file's, with the keys
/// `capture.toml` (at `config_path`) sets over them. A `[cluster.stages.<name>]` that
/// names no stage is an error naming the file.
pub fn settings_for(
    config: &CaptureConfig,
    config_path: &Path,
    stage_names: &[&str],
) -> Result<ClusterSettings, ConfigError> {
    if let Some(message) = config.cluster.stage_problem(stage_names) {
        return Err(ConfigError::Invalid {
            path: config_path.to_path_buf(),
            message,
        });
    }
    let user = match config::user_file() {
        Some(path) => user_file::load_user_file(&path, stage_names)?,
        None => ClusterSettings::default(),
    };
    Ok(user.overridden_by(&config.cluster))
}

/// What `submit` asked for, besides the capture.
#[derive(Clone, Debug, Default)]
pub struct SubmitOptions {
    /// The stages to consider (`--from`, `--to`, `--only`, `--force`).
    pub selection: Selection,
    /// Arguments each job passes to `pipeline run` (`--backend gpu`, `--preset best`).
    pub run_args: Vec<String>,
}

/// What `submit` did for one capture.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Submitted {
    pub capture: PathBuf,
    pub jobs: Vec<SubmittedJob>,
    /// Selected stages that are up to date (not submitted).
    pub up_to_date: Vec<String>,
    /// What `submit` changed in the requests to fit the nodes (a default lowered).
    pub notes: Vec<String>,
}

/// Submit the stale stages of a capture as a chain of jobs. Refused while the capture has
/// jobs in Slurm or a local run holds its lock. `config` carries any `--backend` /
/// `--preset` override already (the jobs get them through `options.run_args`).
pub fn submit(
    pipeline: &Pipeline,
    capture: &Capture,
    config: &CaptureConfig,
    settings: &ClusterSettings,
    options: &SubmitOptions,
) -> Result<Submitted, ClusterError> {
    let root = capture
        .root
        .canonicalize()
        .map_err(|source| ClusterError::Write {
            path: capture.root.clone(),
            source,
        })?;
    let work = root.join("work");
    refuse_if_busy(&root)?;
    let lock = CaptureLock::acquire(&work)?;
    let stages_error = |e: anyhow::Error| ClusterError::Stages {
        capture: root.clone(),
        message: crate::error_chain(&e),
    };
    let selected = pipeline.select(&options.selection).map_err(stages_error)?;
    let rows = pipeline.status(capture, config).map_err(stages_error)?;
    let mut chosen: Vec<usize> = Vec::new();
    let mut up_to_date = Vec::new();
    for &i in &selected {
        let stage = &pipeline.stages[i];
        let stale = rows[i].state != State::Done
            || options.selection.force
            || stage
                .after
                .iter()
                .any(|up| chosen.iter().any(|&c| pipeline.stages[c].name == *up));
        if stale && stage.run.is_some() {
            for up in &stage.after {
                let submitted = chosen.iter().any(|&c| pipeline.stages[c].name == *up);
                if !submitted && Manifest::read(&work.join(up)).is_none() {
                    return Err(ClusterError::MissingUpstream {
                        stage: stage.name.into(),
                        upstream: up.to_string(),
                    });
                }
            }
            chosen.push(i);
        } else {
            up_to_date.push(stage.name.to_string());
        }
    }
    if chosen.is_empty() {
        return Ok(Submitted {
            capture: root,
            jobs: Vec::new(),
            up_to_date,
            notes: Vec::new(),
        });
    }
    let binary = match &settings.pipeline {
        Some(p) => p.clone(),
        None => std::env::current_exe().map_err(ClusterError::NoBinary)?,
    };
    let host = crate::lock::host_name();
    let mut submission = Submission {
        token: crate::manifest::hash_bytes(
            format!(
                "{}{}{:?}",
                root.display(),
                std::process::id(),
                Instant::now()
            )
            .as_bytes(),
        )[..16]
            .to_string(),
        submitted: chrono::Utc::now(),
        host: host.clone(),
        jobs: Vec::new(),
    };
    let write = |submission: &Submission| {
        submission
            .write(&work)
            .map_err(|source| ClusterError::Write {
                path: jobs::jobs_file(&work),
                source,
            })
    };
    // Counted once, and only when a job needs it (it may probe the recordings).
    let frames = std::cell::OnceCell::new();
    // A clip cut into time chunks trains one job per chunk when its frames are known now
    // (the frames stage is done and not resubmitted) and nothing is forced.
    let chunked = chosen
        .iter()
        .all(|&i| pipeline.stages[i].name != "frames")
        .then(|| crate::chunks::plan::ChunkPlan::read(&work, &config.chunks))
        .flatten()
        .filter(|plan| plan.is_chunked() && !options.selection.force);
    // Every job's request, checked against the nodes before any is queued.
    let nodes = nodes::read()?;
    let mut requests = Vec::new();
    let mut notes = Vec::new();
    for &i in &chosen {
        let stage = &pipeline.stages[i];
        let gpu = stage.engine && config.engine.backend != crate::engine_inputs::BackendChoice::Cpu;
        let mut request = settings.request(stage.name, gpu, &binary);
        if request.mem.is_none()
            && memory::sized(stage.name)
            && let Some(mut frames) =
                *frames.get_or_init(|| memory::footprint(&work, capture, config))
        {
            if let Some(plan) = chunked.as_ref().filter(|_| stage.name == "train") {
                frames = frames.share(plan.largest_window(), plan.frames());
            }
            request.mem = memory::request(stage.name, frames, config.train.densify.max_gaussians);
        }
        match nodes::check(
            stage.name,
            &request,
            settings.set_by_user(stage.name),
            &nodes,
        ) {
            Ok(None) => {}
            Ok(Some(cpus)) => {
                let note = format!(
                    "cpus: the default {} is more than the nodes of the jobs' partition have; the jobs ask for {cpus} (set [cluster] cpus to choose)",
                    request.cpus
                );
                if !notes.contains(&note) {
                    notes.push(note);
                }
                request.cpus = cpus;
            }
            Err(message) => {
                return Err(ClusterError::DoesNotFit {
                    capture: root.clone(),
                    message,
                });
            }
        }
        requests.push(request);
    }
    let logs = jobs::cluster_dir(&work).join("logs");
    std::fs::create_dir_all(&logs).map_err(|source| ClusterError::Write {
        path: logs.clone(),
        source,
    })?;
    write(&submission)?;
    for (&i, request) in chosen.iter().zip(&requests) {
        let stage = &pipeline.stages[i];
        let chunks = match &chunked {
            Some(plan) if stage.name == "train" => Some(plan),
            _ => None,
        };
        let previous = submission.jobs.last().map(|j| j.job_id.clone());
        let mut queue = |chunk: Option<usize>, after: Option<String>| {
            let job = StageJob {
                stage: stage.name,
                chunk,
                root: &root,
                request,
                after: after.as_deref(),
                hold: after.is_none(),
                run_args: &options.run_args,
                token: &submission.token,
                host: &host,
            };
            let script = jobs::script_path(&work, stage.name, chunk);
            let submitted = shared_types::atomic::write_atomic(&script, job.script().as_bytes())
                .map_err(|source| ClusterError::Write {
                    path: script.clone(),
                    source,
                })
                .and_then(|()| {
                    slurm::sbatch(&job.sbatch_args(&script)).map_err(|source| ClusterError::Submit {
                        stage: stage.name.into(),
                        capture: root.clone(),
                        source,
                        hint: "check the [cluster] settings in capture.toml or the user cluster file, docs/cluster.md",
                    })
                });
            match submitted {
                Ok(job_id) => {
                    submission.jobs.push(SubmittedJob {
                        stage: stage.name.into(),
                        chunk,
                        job_id: job_id.clone(),
                        after,
                        gpus: request.gpus,
                    });
                    write(&submission)?;
                    Ok(job_id)
                }
                Err(e) => {
                    let _ = slurm::scancel(&submission.job_ids());
                    Err(e)
                }
            }
        };
        match chunks {
            // The first chunk after the stage before; the others after the first (they
            // train on its static scene), side by side; the stage's job, which merges
            // them, after all of them.
            Some(plan) => {
                let first = queue(Some(0), previous)?;
                let mut all = vec![first.clone()];
                for k in 1..plan.chunks.len() {
                    all.push(queue(Some(k), Some(first.clone()))?);
                }
                queue(None, Some(all.join(":")))?;
            }
            None => {
                queue(None, previous)?;
            }
        }
    }
    // The chain is in and recorded: let it start once the lock is free.
    drop(lock);
    if let Some(first) = submission.jobs.first()
        && let Err(e) = slurm::release(&first.job_id)
    {
        let _ = slurm::scancel(&submission.job_ids());
        return Err(e.into());
    }
    Ok(Submitted {
        capture: root,
        jobs: submission.jobs,
        up_to_date,
        notes,
    })
}

/// The capture's recorded jobs that Slurm still has waiting or running.
fn active_jobs(work: &Path) -> Result<Vec<(SubmittedJob, JobInfo)>, SlurmError> {
    let Some(submission) = Submission::read(work) else {
        return Ok(Vec::new());
    };
    let known = slurm::query(&submission.job_ids())?;
    Ok(submission
        .jobs
        .into_iter()
        .filter_map(|job| {
            let info = known.get(&job.job_id)?.clone();
            info.state.is_active().then_some((job, info))
        })
        .collect())
}

fn refuse_if_busy(root: &Path) -> Result<(), ClusterError> {
    let active = active_jobs(&root.join("work"))?;
    if active.is_empty() {
        return Ok(());
    }
    let jobs: Vec<String> = active
        .iter()
        .map(|(job, info)| {
            format!(
                "{} job {} {}",
                job.stage,
                job.job_id,
                info.state.name().to_lowercase()
            )
        })
        .collect();
    Err(ClusterError::Busy {
        capture: root.to_path_buf(),
        jobs: jobs.join(", "),
    })
}

/// For `pipeline run`: refuse while the capture has jobs in Slurm, unless this process is
/// one of them. When Slurm cannot be asked (no client tools here), the run goes ahead.
pub fn check_local_run(capture: &Capture) -> Result<(), ClusterError> {
    let work = capture.work_dir();
    let Some(submission) = Submission::read(&work) else {
        return Ok(());
    };
    if std::env::var(jobs::SUBMISSION_ENV).is_ok_and(|t| t == submission.token) {
        return Ok(());
    }
    match refuse_if_busy(&capture.root) {
        Err(ClusterError::Slurm(e)) => {
            tracing::debug!("cannot ask Slurm about this capture's jobs: {e}");
            Ok(())
        }
        other => other,
    }
}

/// Show the Slurm jobs of the capture's latest submission in its status rows: queued,
/// running, failed (with the log), or cancelled (by `cancel`, or by Slurm because the
/// job it waited for failed). A finished job Slurm no longer knows leaves the row as the
/// manifests say.
pub fn annotate_status(rows: &mut [StageStatus], capture: &Capture) -> Result<(), SlurmError> {
    let work = capture.work_dir();
    let Some(submission) = Submission::read(&work) else {
        return Ok(());
    };
    let known = slurm::query(&submission.job_ids())?;
    let by_stage: BTreeMap<&str, &SubmittedJob> = submission
        .jobs
        .iter()
        .map(|j| (j.stage.as_str(), j))
        .collect();
    for row in rows.iter_mut() {
        let Some(job) = by_stage.get(row.stage.as_str()) else {
            continue;
        };
        let Some(info) = known.get(&job.job_id) else {
            continue;
        };
        let id = &job.job_id;
        let (state, detail) = match &info.state {
            JobState::Pending if info.dependency_never_satisfied() => (
                State::Cancelled,
                format!(
                    "job {id} will never start: the job it waits for failed ({})",
                    slurm::NEVER_SATISFIED
                ),
            ),
            JobState::Pending => (
                State::Queued,
                match (&info.reason, &job.after) {
                    (Some(r), Some(after)) if r == "Dependency" => {
                        format!("job {id} queued, after job {after}")
                    }
                    (Some(r), _) => format!("job {id} queued ({r})"),
                    (None, _) => format!("job {id} queued"),
                },
            ),
            JobState::Running => (
                State::Running,
                match &info.node {
                    Some(node) => format!("job {id} running on {node}"),
                    None => format!("job {id} running"),
                },
            ),
            s if s.is_active() => (State::Running, format!("job {id} {}", s.name())),
            _ if row.state == State::Done => {
                row.job = Some(id.clone());
                continue;
            }
            JobState::Cancelled if info.dependency_never_satisfied() => (
                State::Cancelled,
                format!(
                    "job {id} cancelled by Slurm: the job it waited for failed ({})",
                    slurm::NEVER_SATISFIED
                ),
            ),
            JobState::Cancelled => (State::Cancelled, format!("job {id} cancelled")),
            s if s.is_failure() => (State::Failed, failed_detail(&work, &row.stage, id, info)),
            _ => {
                row.job = Some(id.clone());
                continue;
            }
        };
        row.state = state;
        row.job = Some(id.clone());
        // A queued or cancelled stage's manifest notes ("stale: …") still say why it runs.
        row.details.insert(0, detail);
    }
    Ok(())
}

/// `job 12 FAILED (exit 1); log work/sync/slurm-12.log`, or the shared-filesystem hint
/// when the job never wrote its log here.
fn failed_detail(work: &Path, stage: &str, id: &str, info: &JobInfo) -> String {
    let exit = info.exit_code.clone().or_else(|| slurm::exit_code(id));
    let mut text = format!("job {id} {}", info.state.name());
    if let Some(code) = exit.as_deref().filter(|c| *c != "0:0") {
        text += &format!(" (exit {code})");
    }
    let logs = [
        jobs::stage_log(work, stage, id),
        jobs::slurm_log(work, stage, id),
    ];
    match logs.iter().find(|p| p.exists()) {
        Some(log) => {
            let shown = log
                .strip_prefix(work.parent().unwrap_or(work))
                .unwrap_or(log);
            text += &format!("; log {}", shown.display());
        }
        None => {
            text += &format!(
                "; its log {} was never written here: is the capture directory on a filesystem the compute nodes share, at the same path? (pipeline submit needs one)",
                logs[1].display()
            )
        }
    }
    text
}

/// Cancel the capture's jobs that Slurm still has waiting or running, and wait (up to
/// `wait`) until Slurm has ended them and their processes. Returns the jobs cancelled.
pub fn cancel(capture: &Capture, wait: Duration) -> Result<Vec<SubmittedJob>, ClusterError> {
    let work = capture.work_dir();
    let active = active_jobs(&work)?;
    let ids: Vec<String> = active.iter().map(|(j, _)| j.job_id.clone()).collect();
    slurm::scancel(&ids)?;
    let start = Instant::now();
    while !ids.is_empty() && start.elapsed() < wait {
        let known = slurm::query(&ids)?;
        // Until the running ones are past COMPLETING, their processes may still be there.
        if !known
            .values()
            .any(|j| j.state.is_active() || j.state == JobState::Completing)
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    Ok(active.into_iter().map(|(j, _)| j).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn failed(state: JobState) -> JobInfo {
        JobInfo {
            id: "7".into(),
            state,
            reason: None,
            node: None,
            exit_code: Some("1:0".into()),
        }
    }

    #[test]
    fn a_cluster_table_for_no_stage_is_an_error_naming_capture_toml() {
        let config =
            CaptureConfig::parse("[cluster.stages.training]\ncpus = 2\n", Path::new("c.toml"))
                .unwrap();
        let names = crate::stages::pipeline().stage_names();
        let err = settings_for(&config, Path::new("/x/capture.toml"), &names)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("no stage `training`") && err.contains("/x/capture.toml"),
            "{err}"
        );
        let ok = CaptureConfig::parse("[cluster.stages.train]\ncpus = 2\n", Path::new("c.toml"))
            .unwrap();
        assert_eq!(
            settings_for(&ok, Path::new("c.toml"), &names)
                .unwrap()
                .stages["train"]
                .cpus,
            Some(2)
        );
    }

    #[test]
    fn a_failed_job_names_its_log_or_the_shared_filesystem() {
        let tmp = tempfile::tempdir().unwrap();
        let work = tmp.path().join("work");
        let text = failed_detail(&work, "sync", "7", &failed(JobState::Failed));
        assert!(
            text.starts_with("job 7 FAILED (exit 1:0); its log")
                && text.contains("logs/sync-7.log was never written here")
                && text.contains("filesystem the compute nodes share"),
            "{text}"
        );
        let log = jobs::stage_log(&work, "sync", "7");
        std::fs::create_dir_all(log.parent().unwrap()).unwrap();
        std::fs::write(&log, "error").unwrap();
        let text = failed_detail(&work, "sync", "7", &failed(JobState::Timeout));
        assert_eq!(text, "job 7 TIMEOUT (exit 1:0); log work/sync/slurm-7.log");
    }
}
