//! Talking to Slurm through its commands, the way workflow tools do: `sbatch --parsable`
//! submits, `squeue -t all` (then `sacct`, when accounting is on) reports, `scontrol show
//! job` gives a finished job's exit code, `scancel` cancels. Each parser is a plain
//! function of the command's output, tested on captured text.
//!
//! Without accounting (no slurmdbd) a finished job is known only to `squeue -t all` and
//! `scontrol` for `MinJobAge` seconds (300 by default); after that it is simply unknown,
//! and the manifests tell what happened.

use std::collections::BTreeMap;
use std::process::Command;

use thiserror::Error;

/// A Slurm command that could not be used.
#[derive(Debug, Error)]
pub enum SlurmError {
    #[error(
        "`{program}` was not found: the cluster commands need Slurm's client tools on PATH (run this on a login node of the cluster)"
    )]
    Missing { program: String },
    #[error("cannot run `{program}`: {source}")]
    Io {
        program: String,
        source: std::io::Error,
    },
    #[error("`{command}` failed: {message}")]
    Failed { command: String, message: String },
    #[error("`{program}` printed {output:?}, not a job id")]
    Unparsable { program: String, output: String },
}

/// A job's state, as `squeue %T`, `scontrol JobState` and `sacct State` name it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobState {
    Pending,
    Running,
    /// Ended; Slurm is cleaning up after it.
    Completing,
    Completed,
    Cancelled,
    Failed,
    Timeout,
    OutOfMemory,
    NodeFail,
    /// Any other state (`SUSPENDED`, `PREEMPTED`, `BOOT_FAIL`, …), by its Slurm name.
    Other(String),
}

impl JobState {
    /// From Slurm's word (`CANCELLED by 0` from sacct counts as `CANCELLED`).
    pub fn parse(word: &str) -> Self {
        let word = word
            .split_whitespace()
            .next()
            .unwrap_or("")
            .trim_end_matches('+');
        match word {
            "PENDING" | "PD" => Self::Pending,
            "RUNNING" | "R" | "CONFIGURING" | "CF" => Self::Running,
            "COMPLETING" | "CG" => Self::Completing,
            "COMPLETED" | "CD" => Self::Completed,
            "CANCELLED" | "CA" => Self::Cancelled,
            "FAILED" | "F" => Self::Failed,
            "TIMEOUT" | "TO" => Self::Timeout,
            "OUT_OF_MEMORY" | "OOM" => Self::OutOfMemory,
            "NODE_FAIL" | "NF" => Self::NodeFail,
            other => Self::Other(other.to_string()),
        }
    }

    /// Waiting or running: the job still holds (or will hold) the capture.
    pub fn is_active(&self) -> bool {
        match self {
            Self::Pending | Self::Running => true,
            Self::Other(s) => matches!(
                s.as_str(),
                "SUSPENDED"
                    | "REQUEUED"
                    | "REQUEUE_FED"
                    | "REQUEUE_HOLD"
                    | "RESIZING"
                    | "SIGNALING"
            ),
            _ => false,
        }
    }

    /// Ended without success (and not by a cancel).
    pub fn is_failure(&self) -> bool {
        match self {
            Self::Failed | Self::Timeout | Self::OutOfMemory | Self::NodeFail => true,
            Self::Other(s) => matches!(
                s.as_str(),
                "BOOT_FAIL" | "DEADLINE" | "PREEMPTED" | "SPECIAL_EXIT" | "REVOKED"
            ),
            _ => false,
        }
    }

    /// Slurm's name of the state.
    pub fn name(&self) -> &str {
        match self {
            Self::Pending => "PENDING",
            Self::Running => "RUNNING",
            Self::Completing => "COMPLETING",
            Self::Completed => "COMPLETED",
            Self::Cancelled => "CANCELLED",
            Self::Failed => "FAILED",
            Self::Timeout => "TIMEOUT",
            Self::OutOfMemory => "OUT_OF_MEMORY",
            Self::NodeFail => "NODE_FAIL",
            Self::Other(s) => s,
        }
    }
}

/// What Slurm says about one job.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JobInfo {
    pub id: String,
    pub state: JobState,
    /// Why it waits or ended (`Dependency`, `DependencyNeverSatisfied`, `Resources`, …).
    pub reason: Option<String>,
    /// The node it runs or ran on.
    pub node: Option<String>,
    /// `exit:signal`, when known (`1:0`).
    pub exit_code: Option<String>,
}

/// The reason Slurm gives a job that waits on a dependency that failed.
pub const NEVER_SATISFIED: &str = "DependencyNeverSatisfied";

impl JobInfo {
    /// Waiting on, or cancelled because of, an upstream job that did not succeed.
    pub fn dependency_never_satisfied(&self) -> bool {
        self.reason.as_deref() == Some(NEVER_SATISFIED)
    }
}

fn meaningful(text: &str) -> Option<String> {
    let text = text.trim();
    (!text.is_empty() && text != "None" && text != "(null)").then(|| text.to_string())
}

/// The job id `sbatch --parsable` prints (`12` or `12;cluster`).
pub fn parse_sbatch(stdout: &str) -> Result<String, SlurmError> {
    let line = stdout.lines().map(str::trim).find(|l| !l.is_empty());
    let id = line.and_then(|l| l.split(';').next()).unwrap_or("").trim();
    if !id.is_empty() && id.bytes().all(|b| b.is_ascii_digit() || b == b'_') {
        Ok(id.to_string())
    } else {
        Err(SlurmError::Unparsable {
            program: "sbatch".into(),
            output: stdout.trim().to_string(),
        })
    }
}

/// The `squeue` format [`parse_squeue`] reads, and its columns.
pub const SQUEUE_FORMAT: &str = "%i|%T|%r|%N";
const SQUEUE_COLUMNS: [Column; 4] = [Column::Id, Column::State, Column::Reason, Column::Node];

/// `squeue --noheader --format=%i|%T|%r|%N` lines.
pub fn parse_squeue(stdout: &str) -> Vec<JobInfo> {
    parse_columns(stdout, &SQUEUE_COLUMNS)
}

/// `scontrol show job -o` lines: `JobId=12 JobName=… JobState=FAILED Reason=… ExitCode=1:0 …`.
pub fn parse_scontrol(stdout: &str) -> Vec<JobInfo> {
    stdout
        .lines()
        .filter_map(|line| {
            let fields: BTreeMap<&str, &str> = line
                .split_whitespace()
                .filter_map(|token| token.split_once('='))
                .collect();
            Some(JobInfo {
                id: fields.get("JobId")?.to_string(),
                state: JobState::parse(fields.get("JobState")?),
                reason: fields.get("Reason").and_then(|r| meaningful(r)),
                node: fields.get("NodeList").and_then(|n| meaningful(n)),
                exit_code: fields.get("ExitCode").and_then(|e| meaningful(e)),
            })
        })
        .collect()
}

/// The `sacct` fields [`parse_sacct`] reads, and its columns.
pub const SACCT_FORMAT: &str = "JobIDRaw,State,ExitCode,NodeList";
const SACCT_COLUMNS: [Column; 4] = [Column::Id, Column::State, Column::ExitCode, Column::Node];

/// `sacct --noheader --parsable2 --allocations --format=JobIDRaw,State,ExitCode,NodeList`.
pub fn parse_sacct(stdout: &str) -> Vec<JobInfo> {
    parse_columns(stdout, &SACCT_COLUMNS)
}

/// A column of `squeue`'s or `sacct`'s `|`-separated output.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Column {
    Id,
    State,
    Reason,
    ExitCode,
    Node,
}

/// `|`-separated lines holding `columns` in order; lines without an id or a state, and
/// job steps (`12.batch`), are skipped.
fn parse_columns(stdout: &str, columns: &[Column]) -> Vec<JobInfo> {
    stdout
        .lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.trim().split('|').collect();
            let cell = |c: Column| {
                let i = columns.iter().position(|&k| k == c)?;
                cells.get(i).copied()
            };
            let id = cell(Column::Id)?.trim();
            let state = cell(Column::State)?;
            if id.is_empty() || id.contains('.') {
                return None;
            }
            Some(JobInfo {
                id: id.to_string(),
                state: JobState::parse(state),
                reason: cell(Column::Reason).and_then(meaningful),
                node: cell(Column::Node).and_then(meaningful),
                exit_code: cell(Column::ExitCode).and_then(meaningful),
            })
        })
        .collect()
}

/// Run a Slurm command; its stdout, or its stderr as the error.
pub(super) fn call(program: &str, args: &[String]) -> Result<String, SlurmError> {
    let output = Command::new(program)
        .args(args)
        .output()
        .map_err(|source| match source.kind() {
            std::io::ErrorKind::NotFound => SlurmError::Missing {
                program: program.into(),
            },
            _ => SlurmError::Io {
                program: program.into(),
                source,
            },
        })?;
    if output.status.success() {
        return Ok(String::from_utf8_lossy(&output.stdout).into_owned());
    }
    let stderr = String::from_utf8_lossy(&output.stderr);
    let message = stderr
        .lines()
        .map(|l| l.trim().trim_start_matches(&format!("{program}: ")).trim())
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("; ");
    Err(SlurmError::Failed {
        command: format!("{program} {}", args.join(" ")),
        message: if message.is_empty() {
            format!("exit status {}", output.status)
        } else {
            message
        },
    })
}

/// Submit a batch script; its job id.
pub fn sbatch(args: &[String]) -> Result<String, SlurmError> {
    let mut all = vec!["--parsable".to_string()];
    all.extend_from_slice(args);
    parse_sbatch(&call("sbatch", &all)?)
}

/// What Slurm knows about these jobs: `squeue -t all` (jobs the controller still holds),
/// then `sacct` for the others when accounting is on. Jobs neither knows are left out.
pub fn query(ids: &[String]) -> Result<BTreeMap<String, JobInfo>, SlurmError> {
    let mut known = BTreeMap::new();
    if ids.is_empty() {
        return Ok(known);
    }
    let args = vec![
        "--noheader".to_string(),
        "--states=all".to_string(),
        format!("--jobs={}", ids.join(",")),
        format!("--format={SQUEUE_FORMAT}"),
    ];
    match call("squeue", &args) {
        Ok(out) => known.extend(parse_squeue(&out).into_iter().map(|j| (j.id.clone(), j))),
        // One job id, no longer held: squeue says "Invalid job id specified".
        Err(SlurmError::Failed { message, .. }) if message.contains("Invalid job id") => {}
        Err(e) => return Err(e),
    }
    let missing: Vec<String> = ids
        .iter()
        .filter(|id| !known.contains_key(*id))
        .cloned()
        .collect();
    if !missing.is_empty() {
        let args = vec![
            "--noheader".to_string(),
            "--parsable2".to_string(),
            "--allocations".to_string(),
            format!("--jobs={}", missing.join(",")),
            format!("--format={SACCT_FORMAT}"),
        ];
        // Without accounting sacct fails ("accounting storage is disabled"): nothing more
        // is known, which is not an error.
        if let Ok(out) = call("sacct", &args) {
            for job in parse_sacct(&out) {
                known.entry(job.id.clone()).or_insert(job);
            }
        }
    }
    Ok(known)
}

/// A finished job's `exit:signal` from `scontrol show job`, when the controller still
/// holds it.
pub fn exit_code(id: &str) -> Option<String> {
    let out = call(
        "scontrol",
        &["show".into(), "job".into(), "-o".into(), id.into()],
    )
    .ok()?;
    parse_scontrol(&out)
        .into_iter()
        .find(|j| j.id == id)
        .and_then(|j| j.exit_code)
}

/// Let a job submitted with `--hold` start.
pub fn release(id: &str) -> Result<(), SlurmError> {
    call("scontrol", &["release".into(), id.into()]).map(|_| ())
}

/// Cancel jobs.
pub fn scancel(ids: &[String]) -> Result<(), SlurmError> {
    if ids.is_empty() {
        return Ok(());
    }
    call("scancel", ids).map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sbatch_parsable_gives_the_job_id() {
        assert_eq!(parse_sbatch("12\n").unwrap(), "12");
        assert_eq!(parse_sbatch("4711;cluster2\n").unwrap(), "4711");
        for bad in ["", "Submitted batch job 12", "abc"] {
            assert!(parse_sbatch(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn squeue_lines_with_all_states() {
        // Captured from Slurm 22.05: a failed job, its dependents cancelled by Slurm, one
        // running, one waiting on its dependency.
        let out = "2|CANCELLED|DependencyNeverSatisfied|\n3|PENDING|Dependency|\n\
                   4|RUNNING|None|vm\n1|FAILED|NonZeroExitCode|vm\n5|COMPLETING|None|vm\n";
        let jobs = parse_squeue(out);
        assert_eq!(jobs.len(), 5);
        assert_eq!(jobs[0].state, JobState::Cancelled);
        assert!(jobs[0].dependency_never_satisfied());
        assert_eq!(jobs[0].node, None);
        assert_eq!(jobs[1].reason.as_deref(), Some("Dependency"));
        assert!(jobs[1].state.is_active() && jobs[2].state.is_active());
        assert_eq!(jobs[2].reason, None);
        assert_eq!(jobs[2].node.as_deref(), Some("vm"));
        assert!(jobs[3].state.is_failure() && !jobs[3].state.is_active());
        assert!(!jobs[4].state.is_active() && !jobs[4].state.is_failure());
        assert!(parse_squeue("").is_empty());
    }

    #[test]
    fn scontrol_show_job_one_line_per_job() {
        let out = "JobId=1 JobName=wrap UserId=root(0) GroupId=root(0) MCS_label=N/A \
                   Priority=4294901759 Nice=0 Account=(null) QOS=(null) JobState=FAILED \
                   Reason=NonZeroExitCode Dependency=(null) Requeue=1 Restarts=0 BatchFlag=1 \
                   ExitCode=3:0 RunTime=00:00:01 NodeList=vm BatchHost=vm StdOut=/tmp/st/jobs/1.log\n\
                   JobId=3 JobName=wrap JobState=CANCELLED Reason=DependencyNeverSatisfied \
                   Dependency=afterok:2(failed) ExitCode=0:0 NodeList= KillOInInvalidDependent=Yes\n";
        let jobs = parse_scontrol(out);
        assert_eq!(
            jobs[0],
            JobInfo {
                id: "1".into(),
                state: JobState::Failed,
                reason: Some("NonZeroExitCode".into()),
                node: Some("vm".into()),
                exit_code: Some("3:0".into()),
            }
        );
        assert_eq!(jobs[1].state, JobState::Cancelled);
        assert!(jobs[1].dependency_never_satisfied());
        assert_eq!(jobs[1].node, None);
    }

    #[test]
    fn sacct_parsable_rows_skip_steps() {
        let out = "12|COMPLETED|0:0|node1\n12.batch|COMPLETED|0:0|node1\n\
                   13|CANCELLED by 1000|0:0|None assigned\n14|TIMEOUT|0:15|node2\n15|OUT_OF_MEMORY|0:125|n3\n";
        let jobs = parse_sacct(out);
        let states: Vec<&JobState> = jobs.iter().map(|j| &j.state).collect();
        assert_eq!(
            states,
            [
                &JobState::Completed,
                &JobState::Cancelled,
                &JobState::Timeout,
                &JobState::OutOfMemory
            ]
        );
        assert_eq!(jobs[2].exit_code.as_deref(), Some("0:15"));
        assert!(jobs[2].state.is_failure() && jobs[3].state.is_failure());
    }

    #[test]
    fn state_words() {
        assert_eq!(JobState::parse("CANCELLED+"), JobState::Cancelled);
        assert_eq!(JobState::parse("PD"), JobState::Pending);
        assert!(JobState::parse("SUSPENDED").is_active());
        assert!(JobState::parse("PREEMPTED").is_failure());
        assert_eq!(JobState::parse("BOOT_FAIL").name(), "BOOT_FAIL");
    }
}
