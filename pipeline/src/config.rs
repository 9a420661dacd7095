//! `capture.toml`: the user's settings for one capture, overriding the defaults.
//!
//! Each stage reads its own section (`[sync]`, `[frames]`, …), whose type lives with the
//! stage in `stages`; the section, serialised to JSON, is that stage's parameter set in
//! its manifest, so changing a key reruns exactly the stages that read it. Unknown
//! sections and keys are errors that name the key. This module imports the stages'
//! sections; no stage imports it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::layout::CONFIG_FILE;
use crate::presets::{PRESET_KEYS, Preset};
use crate::stages::eval;
use crate::stages::export;
use crate::stages::frames;
use crate::stages::ingest;
use crate::stages::init;
use crate::stages::poses;
use crate::stages::render;
use crate::stages::sync;
use crate::stages::train;

/// All settings of a capture. Every section is optional in the file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CaptureConfig {
    pub capture: CaptureSection,
    pub ingest: ingest::IngestSettings,
    pub sync: sync::SyncSettings,
    pub frames: frames::FramesSettings,
    pub poses: poses::PosesSettings,
    pub init: init::InitSettings,
    pub train: train::TrainSettings,
    /// Long clips trained in time chunks (the `train` stage, and the init's moments).
    pub chunks: crate::chunks::ChunkSettings,
    /// The 4C4D opacity decay used by the `train` stage (`variant = "none"`: plain 4DGS).
    pub decay: train::DecaySettings,
    pub render: render::RenderSettings,
    pub eval: eval::EvalSettings,
    pub export: export::ExportSettings,
    /// The compute backend of the stages that render (not a stage parameter).
    pub engine: crate::engine_inputs::EngineSettings,
    /// Where and how `pipeline submit` runs the stages on Slurm (not a stage parameter).
    pub cluster: crate::cluster::config::ClusterSettings,
    /// The training preset applied (`[train] preset` or [`Self::with_preset`]); its values
    /// are in `train` already.
    #[serde(skip)]
    pub preset: Option<Preset>,
}

/// `[capture]`: the rig itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CaptureSection {
    /// Number of training video cameras: the folders `raw/camN/` not listed in `heldout`.
    pub cameras: usize,
    /// Extra camera folders `raw/<name>/` that are ingested, synchronised, aligned and
    /// posed like the training cameras but never trained on: the `eval` stage measures
    /// novel-view quality on them (docs/render-eval.md).
    pub heldout: Vec<String>,
}

impl Default for CaptureSection {
    fn default() -> Self {
        Self {
            cameras: 4,
            heldout: Vec::new(),
        }
    }
}

impl CaptureSection {
    /// What is wrong with `heldout`, if anything: an empty, hidden or nested name, or a
    /// name listed twice.
    fn heldout_problem(&self) -> Option<String> {
        for (i, name) in self.heldout.iter().enumerate() {
            if name.is_empty() || name.starts_with('.') || name.contains(['/', '\\']) {
                return Some(format!(
                    "[capture] heldout: {name:?} is not a camera folder name (use the name of a folder in raw/, e.g. \"cam4\")"
                ));
            }
            if self.heldout[..i].contains(name) {
                return Some(format!(
                    "[capture] heldout lists {name:?} twice; a camera is held out once (a held-out camera is never a training camera)"
                ));
            }
        }
        None
    }
}

/// A `capture.toml` that cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}\n(fix or remove that key; the README lists every setting)")]
    Invalid { path: PathBuf, message: String },
}

impl CaptureConfig {
    /// How eval estimates moving-region masks from static plates: the init's plates.
    pub fn plate_masks(&self) -> crate::masks::PlateMasks {
        crate::masks::PlateMasks {
            frames: self.init.plates,
            threshold: self.init.motion_threshold,
        }
    }

    /// Read `capture.toml` from a capture directory; defaults when the file is absent.
    pub fn load(capture_dir: &Path) -> Result<Self, ConfigError> {
        let path = capture_dir.join(CONFIG_FILE);
        if !path.exists() {
            return Ok(Self::default());
        }
        let text = std::fs::read_to_string(&path).map_err(|source| ConfigError::Read {
            path: path.clone(),
            source,
        })?;
        Self::parse(&text, &path)
    }

    /// Parse settings text; `path` is only used in error messages.
    /// A `[train] preset` sets its keys (`crate::presets`) over the rest of the file.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let invalid = |message: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            message: message.trim_end().to_string(),
        };
        let table: toml::Table = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        crate::ranges::check(&table).map_err(invalid)?;
        let config = match table
            .get("train")
            .and_then(|t| t.as_table())
            .and_then(|t| t.get("preset"))
        {
            // The common case parses the text itself, so errors point at its lines.
            None => toml::from_str::<Self>(text).map_err(|e| invalid(e.to_string()))?,
            Some(value) => {
                let preset = Preset::deserialize(value.clone()).map_err(|_| {
                    invalid(format!(
                        "[train] preset = {value} is not a preset: use \"preview\", \"balanced\", \"best\" or \"full\""
                    ))
                })?;
                let mut table = table.clone();
                if let Some(train) = table.get_mut("train").and_then(|t| t.as_table_mut()) {
                    train.remove("preset");
                    if let Some(key) = PRESET_KEYS.iter().find(|k| has_dotted(train, k)) {
                        return Err(invalid(format!(
                            "[train] preset = \"{}\" sets `{key}` ({}); remove `{key}` or the preset",
                            preset.name(),
                            preset.describe()
                        )));
                    }
                }
                Self::deserialize(table)
                    .map_err(|e| invalid(e.to_string()))?
                    .with_preset(preset)
            }
        };
        if config.capture.cameras == 0 {
            return Err(ConfigError::Invalid {
                path: path.to_path_buf(),
                message: "[capture] cameras must be at least 1".into(),
            });
        }
        if let Some(message) = config.capture.heldout_problem() {
            return Err(ConfigError::Invalid {
                path: path.to_path_buf(),
                message,
            });
        }
        // Stage names under [cluster.stages] are checked where the stages are known
        // (`cluster::settings_for`): this module does not import the stage list.
        if let Some(message) = config.cluster.value_problem() {
            return Err(ConfigError::Invalid {
                path: path.to_path_buf(),
                message,
            });
        }
        Ok(config)
    }

    /// These settings with a training preset applied over them.
    pub fn with_preset(mut self, preset: Preset) -> Self {
        (self.train, self.decay) = preset.apply(&self.train, &self.decay);
        self.preset = Some(preset);
        self
    }

    /// The parameters of one stage as JSON (its section of this file).
    pub fn section(&self, stage: &str) -> serde_json::Value {
        let all = serde_json::to_value(self).unwrap_or_default();
        all.get(stage)
            .cloned()
            .unwrap_or(serde_json::Value::Object(Default::default()))
    }
}

/// Whether `table` has the dotted key `key` (`densify.max_gaussians`).
fn has_dotted(table: &toml::Table, key: &str) -> bool {
    match key.split_once('.') {
        Some((head, rest)) => table
            .get(head)
            .and_then(|t| t.as_table())
            .is_some_and(|t| has_dotted(t, rest)),
        None => table.contains_key(key),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_file_gives_defaults() {
        let c = CaptureConfig::parse("", Path::new("capture.toml")).unwrap();
        assert_eq!(c, CaptureConfig::default());
        assert_eq!(c.capture.cameras, 4);
    }

    #[test]
    fn unknown_key_names_the_key_and_file() {
        let err = CaptureConfig::parse("[capture]\ncamras = 3\n", Path::new("/x/capture.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("camras"), "{err}");
        assert!(err.contains("/x/capture.toml"), "{err}");
        let err = CaptureConfig::parse("[trian]\n", Path::new("capture.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("trian"), "{err}");
        let err = CaptureConfig::parse("[train]\nitertions = 5\n", Path::new("capture.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("itertions"), "{err}");
    }

    #[test]
    fn camera_count_overrides_and_sections_serialise() {
        let c = CaptureConfig::parse("[capture]\ncameras = 3\n", Path::new("c.toml")).unwrap();
        assert_eq!(c.capture.cameras, 3);
        assert_eq!(c.section("capture")["cameras"], 3);
        assert_eq!(c.section("sync")["method"], "auto");
        assert_eq!(c.section("frames")["long_side"], 960);
        assert_eq!(c.section("train")["iterations"], 30_000);
        assert_eq!(c.section("export")["viewer"], true);
        assert_eq!(c.section("render")["path"], "orbit");
        assert_eq!(c.section("ingest"), serde_json::json!({}));
        let c = CaptureConfig::parse("[train]\niterations = 5\n", Path::new("c.toml")).unwrap();
        assert_eq!(c.train.iterations, 5);
        assert!(CaptureConfig::parse("[capture]\ncameras = 0\n", Path::new("c.toml")).is_err());
    }

    #[test]
    fn a_preset_sets_its_keys_and_refuses_them_beside_it() {
        let text = "[train]\npreset = \"preview\"\nbatch_size = 2\n[decay]\nwarmup = 3000\n";
        let c = CaptureConfig::parse(text, Path::new("c.toml")).unwrap();
        let v = Preset::Preview.values();
        assert_eq!(c.train.iterations, v.iterations);
        assert_eq!(c.train.resolution, v.resolution);
        assert_eq!(c.train.densify.max_gaussians, v.max_gaussians);
        assert_eq!(c.train.batch_size, 2);
        // The warm-up scales with the iterations (30 000 → the preset's).
        assert_eq!(c.decay.warmup, (3000 * v.iterations).div_ceil(30_000));
        assert_eq!(c.section("train")["iterations"], v.iterations);
        assert_eq!(c.preset, Some(Preset::Preview), "the preset is remembered");
        for (text, needle) in [
            (
                "[train]\npreset = \"best\"\niterations = 5\n",
                "remove `iterations`",
            ),
            (
                "[train]\npreset = \"best\"\n[train.densify]\nmax_gaussians = 5\n",
                "remove `densify.max_gaussians`",
            ),
            (
                "[train]\npreset = \"fast\"\n",
                "\"preview\", \"balanced\", \"best\" or \"full\"",
            ),
            ("[train]\npreset = \"best\"\nitertions = 5\n", "itertions"),
        ] {
            let err = CaptureConfig::parse(text, Path::new("/x/c.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(needle) && err.contains("/x/c.toml"), "{err}");
        }
        // Without a preset, errors keep their line numbers.
        let err = CaptureConfig::parse("\n[train]\nitertions = 5\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("line 3"), "{err}");
    }

    #[test]
    fn the_cluster_section_is_read_checked_and_no_stage_parameter() {
        let text = "[cluster]\npartition = \"batch\"\ntime = \"2:00:00\"\ncpus = 8\n\
                    setup = [\"module load cuda\"]\n[cluster.stages.train]\ngpus = 2\nmem = \"64G\"\n";
        let c = CaptureConfig::parse(text, Path::new("c.toml")).unwrap();
        assert_eq!(c.cluster.partition.as_deref(), Some("batch"));
        assert_eq!(c.cluster.cpus, Some(8));
        assert_eq!(c.cluster.stages["train"].gpus, Some(2));
        let plain = CaptureConfig::default();
        for stage in crate::stages::pipeline().stages {
            assert_eq!((stage.params)(&c), (stage.params)(&plain), "{}", stage.name);
        }
        for (text, needle) in [
            ("[cluster]\nqueue = \"x\"\n", "queue"),
            (
                "[cluster]\ntime = \"2h\"\n",
                "[cluster] time = \"2h\" is not a Slurm time",
            ),
            (
                "[cluster]\ngpus = -1\n",
                "[cluster] gpus = -1 is out of range",
            ),
            (
                "[cluster.stages.train]\nmem = \"lots\"\n",
                "[cluster.stages.train] mem",
            ),
            ("[cluster.stages.train]\nqos = \"x\"\n", "qos"),
        ] {
            let err = CaptureConfig::parse(text, Path::new("/x/c.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(needle) && err.contains("/x/c.toml"), "{err}");
        }
    }

    #[test]
    fn heldout_cameras_parse_and_bad_lists_are_refused() {
        let c = CaptureConfig::parse("", Path::new("c.toml")).unwrap();
        assert!(c.capture.heldout.is_empty());
        let c = CaptureConfig::parse(
            "[capture]\nheldout = [\"cam4\", \"cam5\"]\n",
            Path::new("c.toml"),
        )
        .unwrap();
        assert_eq!(c.capture.heldout, ["cam4", "cam5"]);
        assert_eq!(c.capture.cameras, 4);
        for (text, needle) in [
            ("heldout = [\"cam4\", \"cam4\"]", "twice"),
            ("heldout = [\"\"]", "not a camera folder name"),
            ("heldout = [\"../cam4\"]", "not a camera folder name"),
        ] {
            let err = CaptureConfig::parse(&format!("[capture]\n{text}\n"), Path::new("c.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(needle) && err.contains("heldout"), "{err}");
        }
    }
}
