//! Fuzzed readers of the capture's own JSON files, which users open and edit:
//! `streams.json`, `sync.json` and `frames.json`, each read and then handed to the frames
//! planner, their first consumer. Damaged copies of valid files (`shared_types::fuzz`)
//! must give an error or a plan, never a panic, an abort or an allocation a damaged
//! number asked for. `PROPTEST_CASES` sets the number of cases.

use std::path::PathBuf;

use proptest::prelude::*;
use rig::frames::{FramesConfig, FramesIndex, plan};
use rig::ingest::{AudioInfo, CameraStream, Chapter, SourceKind, Streams, VideoInfo};
use rig::rotation::Rotation;
use rig::sync::{CameraSync, SyncMethod, SyncResult};
use shared_types::fuzz::{self, damaged_json, within_budget};

const CAMERAS: usize = 2;
const FRAMES: usize = 12;

fn streams() -> Streams {
    let camera = |i: usize| CameraStream {
        name: format!("cam{i}"),
        kind: SourceKind::File,
        chapters: vec![Chapter {
            path: PathBuf::from(format!("raw/cam{i}/GX010042.MP4")),
            offset_s: 0.0,
        }],
        video: VideoInfo {
            codec: "h264".into(),
            width: 1920,
            height: 1080,
            rotation: Rotation::None,
            fps: 29.97,
            variable_frame_rate: false,
            frame_count: FRAMES,
            gaps: 0,
            duration_s: FRAMES as f64 / 29.97,
        },
        audio: Some(AudioInfo {
            codec: "aac".into(),
            sample_rate: 48_000,
            channels: 2,
        }),
        timestamps: (0..FRAMES).map(|k| k as f64 / 29.97).collect(),
    };
    Streams {
        cameras: (0..CAMERAS).map(camera).collect(),
        warnings: vec!["cam1 has a variable frame rate".into()],
    }
}

fn sync() -> SyncResult {
    SyncResult {
        method: SyncMethod::Audio,
        reference: "cam0".into(),
        cameras: (0..CAMERAS)
            .map(|i| CameraSync {
                name: format!("cam{i}"),
                offset_s: 0.0123 * i as f64,
                confidence: (i > 0).then_some(14.5),
                timestamps: (0..FRAMES)
                    .map(|k| k as f64 / 29.97 + 0.0123 * i as f64)
                    .collect(),
            })
            .collect(),
        notes: vec![],
    }
}

/// `bytes` written to `name` in a fresh folder.
fn file(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    (dir, path)
}

proptest! {
    #![proptest_config(fuzz::config(4))]

    #[test]
    fn streams_json(bytes in damaged_json(serde_json::to_value(streams()).unwrap())) {
        let (_dir, path) = file("streams.json", &bytes);
        within_budget(|| {
            Streams::read_json(&path).map(|s| plan(&s, &sync(), &FramesConfig::default()))
        })?;
    }

    #[test]
    fn sync_json(bytes in damaged_json(serde_json::to_value(sync()).unwrap())) {
        let (_dir, path) = file("sync.json", &bytes);
        within_budget(|| {
            SyncResult::read_json(&path).map(|s| plan(&streams(), &s, &FramesConfig::default()))
        })?;
    }

    #[test]
    fn frames_json(bytes in damaged_json(
        serde_json::to_value(plan(&streams(), &sync(), &FramesConfig::default()).unwrap()).unwrap()
    )) {
        let (_dir, path) = file("frames.json", &bytes);
        within_budget(|| FramesIndex::read_json(&path))?;
    }
}
