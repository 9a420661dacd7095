//! A stage, declared once: its name, the stages it reads from, the capture files it
//! reads, the outputs it must produce, its parameters and the function that does the work.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use shared_types::Progress;

use crate::config::CaptureConfig;
use crate::layout::Capture;

/// The work of a stage: read inputs, write outputs under `ctx.out_dir`.
pub type RunFn = Box<dyn Fn(&StageContext) -> anyhow::Result<()> + Send + Sync>;
/// The capture files (or folders) a stage reads, given the capture directory.
pub type InputsFn = Box<dyn Fn(&Capture) -> Vec<PathBuf> + Send + Sync>;
/// The parameters of a stage, given the settings.
pub type ParamsFn = Box<dyn Fn(&CaptureConfig) -> serde_json::Value + Send + Sync>;

/// One stage of the pipeline.
pub struct StageDef {
    pub name: &'static str,
    /// One line for `--help` and `status`.
    pub summary: &'static str,
    /// Upstream stages whose outputs this stage reads.
    pub after: Vec<&'static str>,
    /// Capture files it reads (absolute paths; folders are read recursively; absent paths
    /// are skipped, so optional inputs are simply listed).
    pub inputs: InputsFn,
    /// Files (relative to the stage folder) that must exist when the stage succeeds.
    pub outputs: Vec<&'static str>,
    pub params: ParamsFn,
    /// `None` until the stage is implemented.
    pub run: Option<RunFn>,
    /// Keep the partial output folder between attempts (checkpoints for `--resume`).
    pub resumable: bool,
}

impl StageDef {
    /// A stage with no capture inputs, no required outputs, parameters = its own
    /// `capture.toml` section, and no implementation yet.
    pub fn new(name: &'static str, summary: &'static str) -> Self {
        Self {
            name,
            summary,
            after: Vec::new(),
            inputs: Box::new(|_| Vec::new()),
            outputs: Vec::new(),
            params: Box::new(move |config| config.section(name)),
            run: None,
            resumable: false,
        }
    }

    pub fn after(mut self, stages: &[&'static str]) -> Self {
        self.after = stages.to_vec();
        self
    }

    pub fn inputs(mut self, f: impl Fn(&Capture) -> Vec<PathBuf> + Send + Sync + 'static) -> Self {
        self.inputs = Box::new(f);
        self
    }

    pub fn outputs(mut self, files: &[&'static str]) -> Self {
        self.outputs = files.to_vec();
        self
    }

    pub fn params(
        mut self,
        f: impl Fn(&CaptureConfig) -> serde_json::Value + Send + Sync + 'static,
    ) -> Self {
        self.params = Box::new(f);
        self
    }

    pub fn run(
        mut self,
        f: impl Fn(&StageContext) -> anyhow::Result<()> + Send + Sync + 'static,
    ) -> Self {
        self.run = Some(Box::new(f));
        self
    }

    pub fn resumable(mut self) -> Self {
        self.resumable = true;
        self
    }
}

/// What a running stage sees.
pub struct StageContext<'a> {
    pub capture: &'a Capture,
    pub config: &'a CaptureConfig,
    /// Where to write outputs. It becomes `work/<stage>/` only if the stage succeeds.
    pub out_dir: PathBuf,
    /// A resumable stage finds its own earlier, interrupted work in `out_dir` (same
    /// parameters and inputs): continue it.
    pub resume: bool,
    pub progress: &'a dyn Progress,
    pub(crate) tool_versions: Mutex<BTreeMap<String, String>>,
}

impl StageContext<'_> {
    /// Finished outputs of another (upstream) stage.
    pub fn stage_dir(&self, stage: &str) -> PathBuf {
        self.capture.work_dir().join(stage)
    }

    /// Record the version of a program or library used, for the manifest.
    pub fn record_tool(&self, name: &str, version: &str) {
        if let Ok(mut tools) = self.tool_versions.lock() {
            tools.insert(name.to_string(), version.to_string());
        }
    }

    /// A path inside the output folder.
    pub fn output(&self, relative: impl AsRef<Path>) -> PathBuf {
        self.out_dir.join(relative)
    }
}
