//! The `ingest` stage: probe every camera's videos (training and held-out cameras) for
//! frame rate, size, exact per-frame timestamps and audio, into `streams.json`
//! (`rig::ingest`). It reads the videos only; it decodes no frame.

use rig::ingest::Streams;
use serde::{Deserialize, Serialize};

use crate::stage_context::StageContext;

/// `[ingest]` settings: none yet. Any key in the section is an error, so a typo never
/// passes silently.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IngestSettings {}

/// The `ingest` stage.
pub fn run(ctx: &StageContext) -> anyhow::Result<()> {
    let cameras: Vec<(String, std::path::PathBuf)> = ctx
        .capture
        .all_cameras()
        .map(|c| (c.name.clone(), c.dir.clone()))
        .collect();
    let streams = rig::ingest::ingest(&cameras, ctx.progress)?;
    streams.write_json(&ctx.output("streams.json"))?;
    Ok(())
}

/// The ingest stage's `streams.json`, for the stages that read it (sync, frames).
pub fn read_streams(ctx: &StageContext) -> anyhow::Result<Streams> {
    Ok(Streams::read_json(
        &ctx.stage_dir("ingest").join("streams.json"),
    )?)
}
