//! The stages of the 4C4D pipeline, declared once, in order. Each stage's parameters are
//! its own `capture.toml` section; its inputs are the capture files it reads plus the
//! outputs of the stages named in `after`.

use crate::layout::Capture;
use crate::runner::Pipeline;
use crate::stage::StageDef;

/// Every camera's video files.
fn raw_videos(capture: &Capture) -> Vec<std::path::PathBuf> {
    capture
        .cameras
        .iter()
        .flat_map(|c| c.videos.iter().cloned())
        .collect()
}

/// The pipeline as `pipeline run` executes it.
pub fn pipeline() -> Pipeline {
    Pipeline {
        stages: vec![
            StageDef::new(
                "ingest",
                "probe every camera's videos: fps, size, per-frame timestamps, audio",
            )
            .inputs(raw_videos)
            .outputs(&["streams.json"]),
            StageDef::new(
                "sync",
                "find each camera's time offset from audio (clap) or a flash",
            )
            .after(&["ingest"])
            .inputs(raw_videos)
            .outputs(&["sync.json"]),
            StageDef::new(
                "frames",
                "extract time-aligned frames at the working resolution",
            )
            .after(&["ingest", "sync"])
            .inputs(raw_videos)
            .outputs(&["frames.json"]),
            StageDef::new(
                "poses",
                "solve camera poses with COLMAP (4 views + stills) or import a calibration",
            )
            .after(&["frames"])
            .inputs(|c| {
                let mut inputs = c.stills.clone();
                inputs.extend(c.calibration.clone());
                inputs
            })
            .outputs(&["cameras.json"]),
            StageDef::new(
                "init",
                "initial point cloud from MASt3R-style point maps or COLMAP points",
            )
            .after(&["frames", "poses"])
            .outputs(&["points.ply"]),
            StageDef::new("train", "train the 4C4D Gaussian model")
                .after(&["frames", "poses", "init"])
                .resumable(),
            StageDef::new("render", "render videos along camera paths").after(&["poses", "train"]),
            StageDef::new(
                "eval",
                "metrics on held-out views (PSNR, SSIM, DSSIM, LPIPS)",
            )
            .after(&["frames", "poses", "train"])
            .inputs(|c| vec![c.root.join("groundtruth")]),
            StageDef::new("export", "PLY / .splatv exports and a browser viewer").after(&["train"]),
        ],
    }
}

/// Names of all stages, in order.
pub const STAGE_NAMES: &[&str] = &[
    "ingest", "sync", "frames", "poses", "init", "train", "render", "eval", "export",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_names_match_the_declarations() {
        assert_eq!(pipeline().stage_names(), STAGE_NAMES);
    }

    #[test]
    fn upstream_stages_come_first() {
        let p = pipeline();
        for (i, stage) in p.stages.iter().enumerate() {
            for up in &stage.after {
                let j = p
                    .stages
                    .iter()
                    .position(|s| s.name == *up)
                    .expect("known upstream");
                assert!(j < i, "{} reads {} which comes later", stage.name, up);
            }
        }
    }
}
