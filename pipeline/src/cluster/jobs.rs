//! One capture's submission: the jobs file `work/.cluster/jobs.json` (which stage runs as
//! which job), and for each stage its batch script and `sbatch` arguments.
//!
//! Each job runs `pipeline run CAPTURE --only STAGE`, the same entry point as a local run,
//! so the manifests decide at run time exactly as they do locally. Slurm writes the job's
//! output to `work/.cluster/logs/<stage>-<job>.log` (a folder no stage replaces); at the
//! end the job copies it beside `stage.json` as `work/<stage>/slurm-<job>.log`.

use std::fs;
use std::path::{Path, PathBuf};

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use super::config::JobRequest;

/// Environment variable a job sets to its submission's token: a `pipeline run` inside one
/// of the capture's own jobs is not refused for the jobs still queued behind it.
pub const SUBMISSION_ENV: &str = "PIPELINE_SUBMISSION";

/// `work/.cluster/`: the jobs file, the batch scripts and Slurm's logs.
pub fn cluster_dir(work: &Path) -> PathBuf {
    work.join(".cluster")
}

/// `work/.cluster/jobs.json`.
pub fn jobs_file(work: &Path) -> PathBuf {
    cluster_dir(work).join("jobs.json")
}

/// Where Slurm writes a stage job's output while it runs.
pub fn slurm_log(work: &Path, stage: &str, job: &str) -> PathBuf {
    cluster_dir(work)
        .join("logs")
        .join(format!("{stage}-{job}.log"))
}

/// Where the job copies its output when it ends: beside the stage's `stage.json`.
pub fn stage_log(work: &Path, stage: &str, job: &str) -> PathBuf {
    work.join(stage).join(format!("slurm-{job}.log"))
}

/// The batch script of a stage's job (of one time chunk of it: `train-chunk003.sbatch`).
pub fn script_path(work: &Path, stage: &str, chunk: Option<usize>) -> PathBuf {
    match chunk {
        Some(k) => cluster_dir(work).join(format!("{stage}-chunk{k:03}.sbatch")),
        None => cluster_dir(work).join(format!("{stage}.sbatch")),
    }
}

/// The latest submission of a capture (`work/.cluster/jobs.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Submission {
    /// Names this submission; its jobs check it to see they have the submitted capture.
    pub token: String,
    pub submitted: DateTime<Utc>,
    /// The host that submitted.
    pub host: String,
    /// The jobs in stage order (each depends on the one before).
    pub jobs: Vec<SubmittedJob>,
}

/// One stage's job.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SubmittedJob {
    pub stage: String,
    /// The time chunk it trains (`pipeline run --only train --chunk K`), for a clip cut
    /// into chunks; the stage's own job (without) merges them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chunk: Option<usize>,
    pub job_id: String,
    /// The jobs it waits for (`afterok`; several are joined by `:`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub after: Option<String>,
    /// GPUs it asked for.
    #[serde(default)]
    pub gpus: u32,
}

impl Submission {
    /// The submission recorded under `work`, if any.
    pub fn read(work: &Path) -> Option<Self> {
        serde_json::from_str(&fs::read_to_string(jobs_file(work)).ok()?).ok()
    }

    pub fn write(&self, work: &Path) -> std::io::Result<()> {
        shared_types::atomic::write_json(&jobs_file(work), self)
    }

    pub fn job_ids(&self) -> Vec<String> {
        self.jobs.iter().map(|j| j.job_id.clone()).collect()
    }

    /// The stage's own job (not one of its chunks').
    pub fn job_of(&self, stage: &str) -> Option<&SubmittedJob> {
        self.jobs
            .iter()
            .find(|j| j.stage == stage && j.chunk.is_none())
    }
}

/// A stage's job before it is submitted.
#[derive(Clone, Debug)]
pub struct StageJob<'a> {
    pub stage: &'a str,
    /// The time chunk it trains, if it is a chunk's job.
    pub chunk: Option<usize>,
    /// The capture directory, absolute, as the compute nodes see it.
    pub root: &'a Path,
    pub request: &'a JobRequest,
    /// The jobs this one waits for (`:`-separated).
    pub after: Option<&'a str>,
    /// Submit held (released once the whole chain is in).
    pub hold: bool,
    /// Arguments after `pipeline run CAPTURE --only STAGE` (`--force`, `--backend cpu`).
    pub run_args: &'a [String],
    pub token: &'a str,
    pub host: &'a str,
}

impl StageJob<'_> {
    /// `train:take03`: the stage (`train[2]` for a chunk's job), then the capture
    /// folder's name.
    pub fn name(&self) -> String {
        let capture = self
            .root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "capture".into());
        match self.chunk {
            Some(k) => format!("{}[{k}]:{capture}", self.stage),
            None => format!("{}:{capture}", self.stage),
        }
    }

    /// The `sbatch` arguments (without `--parsable`), the script path last.
    pub fn sbatch_args(&self, script: &Path) -> Vec<String> {
        let work = self.root.join("work");
        let r = self.request;
        let mut args = vec![
            format!("--job-name={}", self.name()),
            format!(
                "--output={}",
                slurm_log(&work, self.stage, "%j").to_string_lossy()
            ),
            format!("--chdir={}", self.root.to_string_lossy()),
            "--kill-on-invalid-dep=yes".to_string(),
            // Back in the queue after a node failure or preemption (or `scontrol
            // requeue`): the stage continues from its last checkpoint.
            "--requeue".to_string(),
            // A requeued job's log goes on after the earlier runs' instead of over them.
            "--open-mode=append".to_string(),
        ];
        if let Some(after) = self.after {
            args.push(format!("--dependency=afterok:{after}"));
        }
        if self.hold {
            args.push("--hold".into());
        }
        if let Some(p) = &r.partition {
            args.push(format!("--partition={p}"));
        }
        if let Some(a) = &r.account {
            args.push(format!("--account={a}"));
        }
        if let Some(t) = &r.time {
            args.push(format!("--time={t}"));
            if let Some(minutes) = super::nodes::minutes(t) {
                args.push(format!("--signal=B:USR1@{}", warning_seconds(minutes)));
            }
        }
        args.push(format!("--cpus-per-task={}", r.cpus));
        if let Some(m) = &r.mem {
            args.push(format!("--mem={m}"));
        }
        if r.gpus > 0 {
            args.push(match &r.gpu_type {
                Some(kind) => format!("--gres=gpu:{kind}:{}", r.gpus),
                None => format!("--gres=gpu:{}", r.gpus),
            });
        }
        args.extend(r.sbatch_args.iter().cloned());
        args.push(script.to_string_lossy().into_owned());
        args
    }

    /// The batch script: check the capture is the one submitted, run the stage, copy the
    /// log beside `stage.json`, exit with the stage's status.
    pub fn script(&self) -> String {
        let root = quote(&self.root.to_string_lossy());
        let stage = self.stage;
        let mut command = Vec::new();
        if let Some(prefix) = &self.request.prefix {
            command.push(prefix.clone());
        }
        command.push(quote(&self.request.program.to_string_lossy()));
        command.extend([
            "run".into(),
            "\"$capture\"".into(),
            "--only".into(),
            stage.into(),
        ]);
        if let Some(k) = self.chunk {
            command.extend(["--chunk".into(), k.to_string()]);
        }
        command.extend(self.run_args.iter().map(|a| quote(a)));
        // A chunk's job leaves its log in work/.cluster/logs/: the stage's folder appears
        // only when the job that merges the chunks finishes.
        let keep_log = match self.chunk {
            Some(_) => String::new(),
            None => format!(
                "mkdir -p \"$capture/work/{stage}\" && cp -f \"$log\" \"$capture/work/{stage}/slurm-$SLURM_JOB_ID.log\"\n"
            ),
        };
        let setup: String = self
            .request
            .setup
            .iter()
            .map(|line| format!("{line}\n"))
            .collect();
        format!(
            "#!/bin/bash\n\
             # Stage `{stage}` of {root}, as one Slurm job (written by `pipeline submit`).\n\
             capture={root}\n\
             log=\"$capture/work/.cluster/logs/{stage}-$SLURM_JOB_ID.log\"\n\
             if ! grep -qs {token} \"$capture/work/.cluster/jobs.json\"; then\n\
             \x20 echo \"error: $capture on $(hostname) is not the capture submitted from {host}: \
             pipeline submit needs the capture directory on a filesystem that the compute nodes share, at the same path\" >&2\n\
             \x20 exit 2\n\
             fi\n\
             cd \"$capture\" || exit 2\n\
             export {env}={token}\n\
             {setup}\
             # In the background, so that the time limit's warning (USR1) reaches this\n\
             # script: the stage stops at a checkpoint and the job goes back in the queue.\n\
             {command} &\n\
             child=$!\n\
             trap 'warned=1; kill -TERM \"$child\" 2>/dev/null' USR1\n\
             wait \"$child\"; status=$?\n\
             while kill -0 \"$child\" 2>/dev/null; do wait \"$child\"; status=$?; done\n\
             {keep_log}\
             if [ -n \"$warned\" ]; then\n\
             \x20 echo \"the job's time is nearly up: {stage} stopped at a checkpoint; requeueing job $SLURM_JOB_ID to continue\" >&2\n\
             \x20 scontrol requeue \"$SLURM_JOB_ID\"\n\
             fi\n\
             exit $status\n",
            token = quote(self.token),
            host = self.host.replace(['"', '`', '$', '\\'], ""),
            env = SUBMISSION_ENV,
            command = command.join(" "),
        )
    }
}

/// How long before a time limit of `minutes` Slurm warns the job (`--signal`): a tenth
/// of it, between 30 s and 5 minutes, time for a training to reach its next iteration
/// and write a checkpoint.
fn warning_seconds(minutes: u64) -> u64 {
    (minutes * 6).clamp(30, 300)
}

/// `text` as one shell word (single quotes).
pub fn quote(text: &str) -> String {
    if !text.is_empty()
        && text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_./:=,+@%".contains(&b))
    {
        return text.to_string();
    }
    format!("'{}'", text.replace('\'', "'\\''"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request() -> JobRequest {
        JobRequest {
            partition: Some("gpu".into()),
            account: Some("lab".into()),
            time: Some("12:00:00".into()),
            cpus: 8,
            mem: Some("64G".into()),
            gpus: 2,
            gpu_type: Some("a100".into()),
            sbatch_args: vec!["--qos=long".into()],
            setup: vec!["module load cuda/12.2".into()],
            prefix: Some("apptainer exec --nv /shared/4c4d.sif".into()),
            program: PathBuf::from("/shared/bin/pipeline"),
        }
    }

    #[test]
    fn sbatch_arguments_carry_the_request_and_the_chain() {
        let request = request();
        let job = StageJob {
            stage: "train",
            chunk: None,
            root: Path::new("/shared/take 03"),
            request: &request,
            after: Some("41"),
            hold: false,
            run_args: &[],
            token: "t0k",
            host: "login1",
        };
        let args = job.sbatch_args(Path::new("/shared/take 03/work/.cluster/train.sbatch"));
        assert_eq!(
            args,
            [
                "--job-name=train:take 03",
                "--output=/shared/take 03/work/.cluster/logs/train-%j.log",
                "--chdir=/shared/take 03",
                "--kill-on-invalid-dep=yes",
                "--requeue",
                "--open-mode=append",
                "--dependency=afterok:41",
                "--partition=gpu",
                "--account=lab",
                "--time=12:00:00",
                "--signal=B:USR1@300",
                "--cpus-per-task=8",
                "--mem=64G",
                "--gres=gpu:a100:2",
                "--qos=long",
                "/shared/take 03/work/.cluster/train.sbatch",
            ]
        );
        // The first job of a chain: held, no dependency; a CPU stage asks for no GPU.
        let cpu = JobRequest {
            partition: None,
            account: None,
            time: None,
            mem: None,
            gpus: 0,
            sbatch_args: vec![],
            ..request.clone()
        };
        let first = StageJob {
            stage: "ingest",
            after: None,
            hold: true,
            request: &cpu,
            ..job
        };
        let args = first.sbatch_args(Path::new("s.sbatch"));
        assert!(args.contains(&"--hold".to_string()), "{args:?}");
        assert!(
            !args
                .iter()
                .any(|a| a.starts_with("--dependency") || a.starts_with("--gres")),
            "{args:?}"
        );
        assert!(args.contains(&"--cpus-per-task=8".to_string()));
    }

    #[test]
    fn the_script_checks_the_capture_runs_the_stage_and_keeps_its_log() {
        let request = request();
        let run_args = ["--force".to_string(), "--backend".into(), "gpu".into()];
        let job = StageJob {
            stage: "render",
            chunk: None,
            root: Path::new("/shared/it's"),
            request: &request,
            after: None,
            hold: false,
            run_args: &run_args,
            token: "abc123",
            host: "login1",
        };
        let script = job.script();
        assert!(script.starts_with("#!/bin/bash\n"), "{script}");
        assert!(script.contains("capture='/shared/it'\\''s'\n"), "{script}");
        assert!(
            script.contains("grep -qs abc123 \"$capture/work/.cluster/jobs.json\""),
            "{script}"
        );
        assert!(script.contains("export PIPELINE_SUBMISSION=abc123\n"));
        assert!(script.contains("module load cuda/12.2\n"));
        assert!(script.contains(
            "apptainer exec --nv /shared/4c4d.sif /shared/bin/pipeline run \"$capture\" --only render --force --backend gpu &\n"
        ), "{script}");
        assert!(script.contains("cp -f \"$log\" \"$capture/work/render/slurm-$SLURM_JOB_ID.log\""));
        assert!(script.contains("trap 'warned=1; kill -TERM \"$child\" 2>/dev/null' USR1\n"));
        assert!(script.contains("scontrol requeue \"$SLURM_JOB_ID\""));
        assert!(script.trim_end().ends_with("exit $status"));
    }

    #[test]
    fn a_chunk_job_trains_its_chunk_and_leaves_its_log_in_the_cluster_folder() {
        let request = request();
        let job = StageJob {
            stage: "train",
            chunk: Some(2),
            root: Path::new("/shared/take03"),
            request: &request,
            after: Some("41:42"),
            hold: false,
            run_args: &[],
            token: "abc123",
            host: "login1",
        };
        assert_eq!(job.name(), "train[2]:take03");
        let script = job.script();
        assert!(
            script.contains("/shared/bin/pipeline run \"$capture\" --only train --chunk 2 &\n"),
            "{script}"
        );
        assert!(!script.contains("cp -f"), "{script}");
        let work = Path::new("/shared/take03/work");
        let path = script_path(work, "train", Some(2));
        assert_eq!(path, work.join(".cluster/train-chunk002.sbatch"));
        let args = job.sbatch_args(&path);
        assert!(
            args.contains(&"--dependency=afterok:41:42".to_string()),
            "{args:?}"
        );
        assert_eq!(
            script_path(work, "train", None),
            work.join(".cluster/train.sbatch")
        );
    }

    #[test]
    fn shell_words() {
        assert_eq!(quote("/a/b-c_1.x"), "/a/b-c_1.x");
        assert_eq!(quote("a b"), "'a b'");
        assert_eq!(quote(""), "''");
        assert_eq!(quote("it's"), "'it'\\''s'");
        assert_eq!(quote("$HOME"), "'$HOME'");
    }
}
