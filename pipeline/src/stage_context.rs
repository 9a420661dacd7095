//! What a running stage sees: the capture, the folder to write its outputs to, whether to
//! continue earlier interrupted work, a progress sink, and a place to record the tools it
//! used. The stage's settings are handed to its run function beside it (see `stages`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use shared_types::Progress;

use crate::layout::Capture;

/// What a running stage sees.
pub struct StageContext<'a> {
    pub capture: &'a Capture,
    /// Where to write outputs. It becomes `work/<stage>/` only if the stage succeeds.
    pub out_dir: PathBuf,
    /// A resumable stage finds its own earlier, interrupted work in `out_dir` (same
    /// parameters and inputs): continue it.
    pub resume: bool,
    /// Train just this time chunk (`crate::chunks`; only the `train` stage reads it).
    pub chunk: Option<usize>,
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
