//! The `sync` stage: each camera's time offset on a common timeline, from the audio (a
//! clap), a flash, or recorded timestamps (`rig::sync`), into `sync.json`.

use rig::sync::SyncConfig;

use crate::stage_context::StageContext;

/// `[sync]` settings: the synchroniser's own (method, reference camera, search window,
/// manual offsets, …).
pub type SyncSettings = SyncConfig;

/// The `sync` stage.
#[cfg(not(feature = "ffmpeg"))]
pub fn run(_: &StageContext, _: &SyncSettings) -> anyhow::Result<()> {
    Err(crate::without_ffmpeg("the sync stage"))
}

#[cfg(feature = "ffmpeg")]
pub fn run(ctx: &StageContext, settings: &SyncSettings) -> anyhow::Result<()> {
    let streams = crate::stages::ingest::read_streams(ctx)?;
    let result = rig::sync::synchronise(&streams, settings, ctx.progress)?;
    for cam in &result.cameras {
        match cam.confidence {
            Some(c) => tracing::info!(
                "{}: offset {:+.4} s (confidence {c:.1})",
                cam.name,
                cam.offset_s
            ),
            None => tracing::info!("{}: offset {:+.4} s", cam.name, cam.offset_s),
        }
    }
    result.write_json(&ctx.output("sync.json"))?;
    Ok(())
}
