//! The `ingest` stage: probe every camera's videos (training and held-out cameras) for
//! frame rate, size, exact per-frame timestamps and audio, into `streams.json`
//! (`rig::ingest`). It reads the videos only; it decodes no frame.

use rig::ingest::{IngestOptions, Streams};
use serde::{Deserialize, Serialize};

use crate::stage_context::StageContext;

/// `[ingest]` settings. Any other key in the section is an error, so a typo never passes
/// silently.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestSettings {
    /// Images per second of image-sequence cameras (folders of numbered images, no
    /// video): image `k` is at `k / image_fps` seconds. Left out of the manifest while
    /// it is the default, so captures ingested before the key existed stay up to date.
    #[serde(skip_serializing_if = "is_default_image_fps")]
    pub image_fps: f64,
}

fn is_default_image_fps(fps: &f64) -> bool {
    *fps == IngestOptions::default().image_fps
}

impl Default for IngestSettings {
    fn default() -> Self {
        Self {
            image_fps: IngestOptions::default().image_fps,
        }
    }
}

/// The `ingest` stage.
#[cfg(not(feature = "ffmpeg"))]
pub fn run(_: &StageContext, _: &IngestSettings) -> anyhow::Result<()> {
    Err(crate::without_ffmpeg("the ingest stage"))
}

#[cfg(feature = "ffmpeg")]
pub fn run(ctx: &StageContext, settings: &IngestSettings) -> anyhow::Result<()> {
    let cameras: Vec<(String, std::path::PathBuf)> = ctx
        .capture
        .all_cameras()
        .map(|c| (c.name.clone(), c.dir.clone()))
        .collect();
    let options = IngestOptions {
        image_fps: settings.image_fps,
    };
    let streams = rig::ingest::ingest(&cameras, &options, ctx.progress)?;
    streams.write_json(&ctx.output("streams.json"))?;
    Ok(())
}

/// The ingest stage's `streams.json`, for the stages that read it (sync, frames).
pub fn read_streams(ctx: &StageContext) -> anyhow::Result<Streams> {
    Ok(Streams::read_json(
        &ctx.stage_dir("ingest").join("streams.json"),
    )?)
}
