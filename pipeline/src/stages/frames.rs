//! The `frames` stage: time-aligned frames of every camera at the working resolution
//! (`rig::frames`), indexed in `frames.json`. With held-out cameras (`[capture] heldout`)
//! the index is split: `frames.json` lists the training cameras, `heldout.json` the
//! held-out ones on the same timeline (see `crate::heldout`).

use rig::frames::FramesConfig;
use rig::sync::SyncResult;

use crate::heldout::{HELDOUT_FILE, split_frames};
use crate::stage_context::StageContext;
use crate::stages::ingest::read_streams;

/// `[frames]` settings: the frame extractor's own (working size, frame rate, time range, …).
pub type FramesSettings = FramesConfig;

#[cfg(not(feature = "ffmpeg"))]
pub fn run(_: &StageContext, _: &FramesSettings, _: &[String]) -> anyhow::Result<()> {
    Err(crate::without_ffmpeg("the frames stage"))
}

#[cfg(feature = "ffmpeg")]
/// The `frames` stage; `heldout` are the held-out camera names of `[capture] heldout`.
pub fn run(
    ctx: &StageContext,
    settings: &FramesSettings,
    heldout: &[String],
) -> anyhow::Result<()> {
    let streams = read_streams(ctx)?;
    let sync = SyncResult::read_json(&ctx.stage_dir("sync").join("sync.json"))?;
    let index = rig::frames::extract(&streams, &sync, settings, &ctx.out_dir, ctx.progress)?;
    tracing::info!(
        "{} aligned frames at {:.3} fps",
        index.frames.len(),
        index.fps
    );
    for w in &index.warnings {
        tracing::warn!("{w}");
    }
    if !heldout.is_empty() {
        let (train, held) = split_frames(&index, heldout)?;
        train.write_json(&ctx.output("frames.json"))?;
        held.write_json(&ctx.output(HELDOUT_FILE))?;
        tracing::info!("held out from training: {}", heldout.join(", "));
    }
    Ok(())
}
