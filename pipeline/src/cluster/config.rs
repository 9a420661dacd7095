//! `[cluster]`: where and how `pipeline submit` runs each stage as a Slurm job.
//!
//! The section may sit in a capture's `capture.toml` and in a user-level file
//! ([`user_file`]) holding the same `[cluster]` table; a key set in `capture.toml` replaces
//! the same key of the user file (in `[cluster.stages.<stage>]` too). Nothing here is a
//! stage parameter: changing it reruns nothing. This module reads settings only; it never
//! talks to Slurm.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Environment variable naming the user-level cluster file (instead of [`user_file`]'s
/// default place).
pub const USER_FILE_ENV: &str = "PIPELINE_CLUSTER_CONFIG";
/// CPUs a job asks for when `cpus` is not set.
pub const DEFAULT_CPUS: u32 = 4;
/// GPUs a GPU stage asks for when `gpus` is not set.
pub const DEFAULT_GPUS: u32 = 1;

/// `[cluster]`. Every key is optional; unset keys leave the choice to Slurm (partition,
/// account, time, memory) or take the defaults named on each key.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClusterSettings {
    /// `--partition` of every job (default: the cluster's default partition).
    pub partition: Option<String>,
    /// `--partition` of the GPU stages (default: `partition`).
    pub gpu_partition: Option<String>,
    /// `--account` to charge.
    pub account: Option<String>,
    /// `--time` limit of each job, in Slurm's form (`30`, `4:00:00`, `1-12:00:00`).
    pub time: Option<String>,
    /// `--cpus-per-task` of each job (default 4).
    pub cpus: Option<u32>,
    /// `--mem` of each job (`16G`, `4000M`; default: sized to the capture for `train` and
    /// `eval` (`cluster::memory`), the cluster's `DefMemPerCPU` for the others).
    pub mem: Option<String>,
    /// GPUs a GPU stage asks for, `--gres=gpu:N` (default 1; 0: GPU stages ask for none).
    /// GPU stages are those that render with `[engine] backend`, unless it is `cpu`.
    pub gpus: Option<u32>,
    /// GPU type in the gres request (`a100` gives `--gres=gpu:a100:N`).
    pub gpu_type: Option<String>,
    /// More `sbatch` arguments for every job (`["--qos=long", "--exclusive"]`).
    pub sbatch_args: Option<Vec<String>>,
    /// Shell lines each job runs before the pipeline (`["module load cuda/12.2"]`).
    pub setup: Option<Vec<String>>,
    /// Words put before the pipeline command (a container runner:
    /// `"apptainer exec --nv /shared/4c4d.sif"`).
    pub prefix: Option<String>,
    /// The `pipeline` binary the jobs run, as the compute nodes see it (default: the
    /// binary that submits).
    pub pipeline: Option<PathBuf>,
    /// The binary the GPU stages run (default: `pipeline`), e.g. a build for GPU nodes.
    pub gpu_pipeline: Option<PathBuf>,
    /// Per-stage overrides: `[cluster.stages.train] time = "12:00:00"`.
    pub stages: BTreeMap<String, StageResources>,
}

/// `[cluster.stages.<stage>]`: what one stage's job asks for, over `[cluster]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StageResources {
    pub partition: Option<String>,
    pub time: Option<String>,
    pub cpus: Option<u32>,
    pub mem: Option<String>,
    pub gpus: Option<u32>,
    pub sbatch_args: Option<Vec<String>>,
}

/// What one stage's job asks Slurm for, all settings resolved.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JobRequest {
    pub partition: Option<String>,
    pub account: Option<String>,
    pub time: Option<String>,
    pub cpus: u32,
    pub mem: Option<String>,
    /// GPUs asked for (0 for a CPU stage).
    pub gpus: u32,
    pub gpu_type: Option<String>,
    pub sbatch_args: Vec<String>,
    /// Shell lines run before the command.
    pub setup: Vec<String>,
    /// Words before the command.
    pub prefix: Option<String>,
    /// The pipeline binary to run.
    pub program: PathBuf,
}

/// Which of a request's values the user set (the others are defaults or sized by
/// `submit`); an error names a setting only where there is one to change.
#[derive(Clone, Copy, Debug, Default)]
pub struct SetByUser {
    pub cpus: bool,
    pub mem: bool,
}

impl ClusterSettings {
    /// These settings with every key that `over` sets replaced by its value.
    pub fn overridden_by(self, over: &Self) -> Self {
        fn pick<T: Clone>(base: Option<T>, over: &Option<T>) -> Option<T> {
            over.clone().or(base)
        }
        let mut stages = self.stages;
        for (name, o) in &over.stages {
            let base = stages.remove(name).unwrap_or_default();
            stages.insert(
                name.clone(),
                StageResources {
                    partition: pick(base.partition, &o.partition),
                    time: pick(base.time, &o.time),
                    cpus: pick(base.cpus, &o.cpus),
                    mem: pick(base.mem, &o.mem),
                    gpus: pick(base.gpus, &o.gpus),
                    sbatch_args: pick(base.sbatch_args, &o.sbatch_args),
                },
            );
        }
        Self {
            partition: pick(self.partition, &over.partition),
            gpu_partition: pick(self.gpu_partition, &over.gpu_partition),
            account: pick(self.account, &over.account),
            time: pick(self.time, &over.time),
            cpus: pick(self.cpus, &over.cpus),
            mem: pick(self.mem, &over.mem),
            gpus: pick(self.gpus, &over.gpus),
            gpu_type: pick(self.gpu_type, &over.gpu_type),
            sbatch_args: pick(self.sbatch_args, &over.sbatch_args),
            setup: pick(self.setup, &over.setup),
            prefix: pick(self.prefix, &over.prefix),
            pipeline: pick(self.pipeline, &over.pipeline),
            gpu_pipeline: pick(self.gpu_pipeline, &over.gpu_pipeline),
            stages,
        }
    }

    /// The request of `stage`'s job; `gpu_stage`: it renders on a GPU backend.
    /// `submitting_binary` is the default program.
    pub fn request(&self, stage: &str, gpu_stage: bool, submitting_binary: &Path) -> JobRequest {
        let own = self.stages.get(stage).cloned().unwrap_or_default();
        let gpus = if gpu_stage {
            own.gpus.or(self.gpus).unwrap_or(DEFAULT_GPUS)
        } else {
            0
        };
        let partition = own.partition.or_else(|| {
            if gpus > 0 {
                self.gpu_partition.clone().or(self.partition.clone())
            } else {
                self.partition.clone()
            }
        });
        let base_program = self
            .pipeline
            .clone()
            .unwrap_or_else(|| submitting_binary.to_path_buf());
        let program = if gpu_stage {
            self.gpu_pipeline.clone().unwrap_or(base_program)
        } else {
            base_program
        };
        let mut sbatch_args = self.sbatch_args.clone().unwrap_or_default();
        sbatch_args.extend(own.sbatch_args.unwrap_or_default());
        JobRequest {
            partition,
            account: self.account.clone(),
            time: own.time.or(self.time.clone()),
            cpus: own.cpus.or(self.cpus).unwrap_or(DEFAULT_CPUS),
            mem: own.mem.or(self.mem.clone()),
            gpus,
            gpu_type: self.gpu_type.clone(),
            sbatch_args,
            setup: self.setup.clone().unwrap_or_default(),
            prefix: self.prefix.clone(),
            program,
        }
    }

    /// Which of `stage`'s request values a setting gives (the others are defaults).
    pub fn set_by_user(&self, stage: &str) -> SetByUser {
        let own = self.stages.get(stage);
        SetByUser {
            cpus: own.and_then(|s| s.cpus).or(self.cpus).is_some(),
            mem: own
                .and_then(|s| s.mem.as_ref())
                .or(self.mem.as_ref())
                .is_some(),
        }
    }

    /// What is wrong with these settings' values, if anything: a time or memory Slurm
    /// would refuse.
    pub fn value_problem(&self) -> Option<String> {
        let check = |section: &str, time: &Option<String>, mem: &Option<String>| {
            if let Some(t) = time
                && !is_slurm_time(t)
            {
                return Some(format!(
                    "[{section}] time = {t:?} is not a Slurm time limit: use minutes (\"90\"), \"HH:MM:SS\" or \"D-HH:MM:SS\""
                ));
            }
            if let Some(m) = mem
                && !is_slurm_memory(m)
            {
                return Some(format!(
                    "[{section}] mem = {m:?} is not a Slurm memory size: use a number with K, M, G or T (\"16G\")"
                ));
            }
            None
        };
        check("cluster", &self.time, &self.mem).or_else(|| {
            self.stages.iter().find_map(|(name, own)| {
                check(&format!("cluster.stages.{name}"), &own.time, &own.mem)
            })
        })
    }

    /// A `[cluster.stages.<name>]` table that names no stage of `stages`, if any.
    pub fn stage_problem(&self, stages: &[&str]) -> Option<String> {
        self.stages
            .keys()
            .find(|name| !stages.contains(&name.as_str()))
            .map(|name| {
                format!(
                    "[cluster.stages.{name}]: there is no stage `{name}`; the stages are: {}",
                    stages.join(", ")
                )
            })
    }
}

/// Slurm's time forms: `M`, `M:S`, `H:M:S`, `D-H`, `D-H:M`, `D-H:M:S`, or `UNLIMITED`.
pub fn is_slurm_time(text: &str) -> bool {
    if text.eq_ignore_ascii_case("unlimited") || text.eq_ignore_ascii_case("infinite") {
        return true;
    }
    let numbers = |s: &str, most: usize| {
        let parts: Vec<&str> = s.split(':').collect();
        parts.len() <= most
            && parts
                .iter()
                .all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()))
    };
    match text.split_once('-') {
        Some((days, rest)) => {
            !days.is_empty() && days.bytes().all(|b| b.is_ascii_digit()) && numbers(rest, 3)
        }
        None => numbers(text, 3),
    }
}

/// A Slurm memory size: digits with an optional K, M, G or T.
pub fn is_slurm_memory(text: &str) -> bool {
    let digits = text.trim_end_matches(['K', 'M', 'G', 'T', 'k', 'm', 'g', 't']);
    !digits.is_empty()
        && digits.bytes().all(|b| b.is_ascii_digit())
        && text.len() - digits.len() <= 1
}

/// The user-level cluster file: `$PIPELINE_CLUSTER_CONFIG`, else
/// `$XDG_CONFIG_HOME/4c4d/cluster.toml` (`~/.config/4c4d/cluster.toml`).
pub fn user_file() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os(USER_FILE_ENV).filter(|p| !p.is_empty()) {
        return Some(PathBuf::from(path));
    }
    let config = std::env::var_os("XDG_CONFIG_HOME")
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(config.join("4c4d").join("cluster.toml"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slurm_times_and_sizes() {
        for t in [
            "30",
            "30:00",
            "4:00:00",
            "1-12",
            "1-12:30",
            "2-00:00:00",
            "UNLIMITED",
        ] {
            assert!(is_slurm_time(t), "{t}");
        }
        for t in ["", "4h", "1:2:3:4", "-1", "1-", "a:00", "1-1:2:3:4"] {
            assert!(!is_slurm_time(t), "{t}");
        }
        for m in ["16G", "4000", "512M", "1t"] {
            assert!(is_slurm_memory(m), "{m}");
        }
        for m in ["", "G", "16GB", "1.5G", "-2G"] {
            assert!(!is_slurm_memory(m), "{m}");
        }
    }
}
