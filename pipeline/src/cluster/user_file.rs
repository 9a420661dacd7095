//! The user-level cluster file: one `[cluster]` table (docs/cluster.md) that applies to
//! every capture; `capture.toml`'s keys override it ([`super::config`]).

use std::path::Path;

use serde::Deserialize;

use super::config::ClusterSettings;
use crate::config::ConfigError;

/// The `[cluster]` table of a user-level file (defaults when the file is absent), checked
/// like `capture.toml`'s.
pub fn load_user_file(path: &Path, stages: &[&str]) -> Result<ClusterSettings, ConfigError> {
    if !path.exists() {
        return Ok(ClusterSettings::default());
    }
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_user_file(&text, path, stages)
}

/// Parse a user-level cluster file: one `[cluster]` table, nothing else.
pub fn parse_user_file(
    text: &str,
    path: &Path,
    stages: &[&str],
) -> Result<ClusterSettings, ConfigError> {
    let invalid = |message: String| ConfigError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct UserFile {
        #[serde(default)]
        cluster: ClusterSettings,
    }
    let table: toml::Table = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
    crate::ranges::check(&table).map_err(invalid)?;
    let file: UserFile = toml::from_str(text).map_err(|e| {
        invalid(format!(
            "{}(a cluster file holds one [cluster] table, the keys of docs/cluster.md)",
            e
        ))
    })?;
    match file
        .cluster
        .stage_problem(stages)
        .or_else(|| file.cluster.value_problem())
    {
        Some(message) => Err(invalid(message)),
        None => Ok(file.cluster),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cluster::config::{DEFAULT_GPUS, StageResources};
    use std::collections::BTreeMap;

    const STAGES: &[&str] = &["ingest", "train"];

    #[test]
    fn capture_keys_override_the_user_file_and_stages_override_the_section() {
        let user = parse_user_file(
            "[cluster]\npartition = \"cpu\"\ngpu_partition = \"gpu\"\naccount = \"lab\"\ntime = \"1:00:00\"\nsbatch_args = [\"--qos=low\"]\n[cluster.stages.train]\ntime = \"12:00:00\"\nmem = \"64G\"\n",
            Path::new("u.toml"),
            STAGES,
        )
        .unwrap();
        let capture = ClusterSettings {
            account: Some("other".into()),
            cpus: Some(2),
            stages: BTreeMap::from([(
                "train".to_string(),
                StageResources {
                    mem: Some("32G".into()),
                    ..Default::default()
                },
            )]),
            ..Default::default()
        };
        let merged = user.overridden_by(&capture);
        let bin = Path::new("/shared/bin/pipeline");
        let ingest = merged.request("ingest", false, bin);
        assert_eq!(ingest.partition.as_deref(), Some("cpu"));
        assert_eq!(ingest.account.as_deref(), Some("other"));
        assert_eq!(ingest.time.as_deref(), Some("1:00:00"));
        assert_eq!((ingest.cpus, ingest.gpus), (2, 0));
        assert_eq!(ingest.sbatch_args, ["--qos=low"]);
        assert_eq!(ingest.program, bin);
        let train = merged.request("train", true, bin);
        assert_eq!(train.partition.as_deref(), Some("gpu"));
        assert_eq!(train.time.as_deref(), Some("12:00:00"));
        assert_eq!(train.mem.as_deref(), Some("32G"));
        assert_eq!(train.gpus, DEFAULT_GPUS);
        // A GPU stage with gpus = 0 asks for none and stays on the CPU partition.
        let none = ClusterSettings {
            gpus: Some(0),
            ..merged
        };
        let train = none.request("train", true, bin);
        assert_eq!((train.gpus, train.partition.as_deref()), (0, Some("cpu")));
    }

    #[test]
    fn bad_user_files_name_the_file_and_the_key() {
        for (text, needle) in [
            ("[cluster]\npartiton = \"x\"\n", "partiton"),
            ("[cluster]\ntime = \"4h\"\n", "[cluster] time = \"4h\""),
            ("[cluster]\nmem = \"16GB\"\n", "mem = \"16GB\""),
            ("[cluster]\ncpus = 0\n", "cpus = 0 is out of range"),
            (
                "[cluster.stages.trian]\ntime = \"1:00\"\n",
                "no stage `trian`",
            ),
            ("[train]\niterations = 5\n", "one [cluster] table"),
        ] {
            let err = parse_user_file(text, Path::new("/home/u/cluster.toml"), STAGES)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(needle) && err.contains("/home/u/cluster.toml"),
                "{text}: {err}"
            );
        }
    }
}
