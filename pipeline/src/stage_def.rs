//! A stage, declared once: its name, the stages it reads from, the capture files it
//! reads, the outputs it must produce, its parameters and the function that does the
//! work. This module only declares; `stages` lists the pipeline's stages and `runner`
//! runs them.

use std::path::PathBuf;

use crate::config::CaptureConfig;
use crate::layout::Capture;
use crate::stage_context::StageContext;

/// The work of a stage: read inputs and the settings, write outputs under `ctx.out_dir`.
pub type RunFn = Box<dyn Fn(&StageContext, &CaptureConfig) -> anyhow::Result<()> + Send + Sync>;
/// The capture files (or folders) a stage reads, given the capture directory and the
/// settings (which may name files, e.g. `[init] model`).
pub type InputsFn = Box<dyn Fn(&Capture, &CaptureConfig) -> Vec<PathBuf> + Send + Sync>;
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
            inputs: Box::new(|_, _| Vec::new()),
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

    pub fn inputs(
        mut self,
        f: impl Fn(&Capture, &CaptureConfig) -> Vec<PathBuf> + Send + Sync + 'static,
    ) -> Self {
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
        f: impl Fn(&StageContext, &CaptureConfig) -> anyhow::Result<()> + Send + Sync + 'static,
    ) -> Self {
        self.run = Some(Box::new(f));
        self
    }

    pub fn resumable(mut self) -> Self {
        self.resumable = true;
        self
    }
}
