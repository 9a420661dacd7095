//! A stage, declared once: its name, the stages it reads from, the capture files it
//! reads, the outputs that prove it ran, its parameters and the function that does the
//! work. This module only declares; `stages` lists the pipeline's stages and `runner`
//! runs them.

use std::path::{Path, PathBuf};

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

/// An output that proves a stage ran, relative to its folder: a file, or a folder
/// (`name/`) holding at least one file; with alternatives, any one of them will do.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RequiredOutput {
    pub any_of: Vec<&'static str>,
}

impl RequiredOutput {
    /// Whether the stage folder `dir` holds it.
    pub fn is_in(&self, dir: &Path) -> bool {
        self.any_of.iter().any(|alt| match alt.strip_suffix('/') {
            Some(folder) => {
                crate::manifest::list_files(&dir.join(folder)).is_ok_and(|files| !files.is_empty())
            }
            None => dir.join(alt).exists(),
        })
    }

    /// How an error names it: `model.bin`, or `render.mp4 or a file in rgb/`.
    pub fn describe(&self) -> String {
        let names: Vec<String> = self
            .any_of
            .iter()
            .map(|alt| {
                if alt.ends_with('/') {
                    format!("a file in {alt}")
                } else {
                    alt.to_string()
                }
            })
            .collect();
        names.join(" or ")
    }
}

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
    /// What must exist in the stage folder when the stage succeeds: the outputs that prove
    /// it ran (a stage that wrote none of them failed).
    pub outputs: Vec<RequiredOutput>,
    pub params: ParamsFn,
    /// `None` until the stage is implemented.
    pub run: Option<RunFn>,
    /// Keep the partial output folder between attempts (checkpoints for `--resume`).
    pub resumable: bool,
    /// Trains or renders on `[engine] backend`: a GPU stage unless the backend is `cpu`
    /// (`pipeline submit` asks Slurm for a GPU for it).
    pub engine: bool,
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
            engine: false,
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

    /// Files (relative to the stage folder) that must each exist when the stage succeeds.
    pub fn outputs(mut self, files: &[&'static str]) -> Self {
        self.outputs.extend(
            files
                .iter()
                .map(|&file| RequiredOutput { any_of: vec![file] }),
        );
        self
    }

    /// Files or folders (`name/`, holding at least one file) of which at least one must
    /// exist when the stage succeeds.
    pub fn output_one_of(mut self, alternatives: &[&'static str]) -> Self {
        self.outputs.push(RequiredOutput {
            any_of: alternatives.to_vec(),
        });
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

    /// Marks a stage that runs on the engine's backend (a GPU unless it is `cpu`).
    pub fn on_engine(mut self) -> Self {
        self.engine = true;
        self
    }
}
