//! Point maps at several moments of the clip. Exported maps of aligned frame `N` live in
//! `<pointmaps>/NNNNNN/` (six digits, the frames stage's numbering), each holding pairs in
//! the layout of [`super::npy`]; an ONNX model runs on the frames of each `[init] moments`
//! moment. Points of every moment are then told static or moving
//! ([`super::statics::split_static`]): static points live over the clip, moving points
//! around their moment. Without per-moment folders (or with one moment) the maps are the
//! first frame's, as before.

use std::path::{Path, PathBuf};

use super::config::InitConfig;
use super::fuse::FusedPoint;
use super::inputs::{InitInputs, ViewImage};
use super::report::UsedSource;
use super::statics::TimedPoint;

/// One moment's point maps: where they are, the frames they belong to.
pub struct MomentSet<'a> {
    /// Aligned frame (`None`: the first frames, flat layout).
    pub frame: Option<usize>,
    /// Model time of the moment.
    pub time: f64,
    /// The folder of exported maps (the model file for ONNX).
    pub dir: PathBuf,
    pub views: &'a [ViewImage],
}

/// The folder of aligned frame `frame`'s exported point maps inside `root`.
pub fn frame_dir(root: &Path, frame: usize) -> PathBuf {
    root.join(format!("{frame:06}"))
}

/// Aligned frames that have a point-map folder (`NNNNNN/`) in `root`, ascending; empty
/// when `root` is not a folder or holds only the flat layout.
pub fn exported_frames(root: &Path) -> Vec<usize> {
    let Ok(entries) = std::fs::read_dir(root) else {
        return Vec::new();
    };
    let mut frames: Vec<usize> = entries
        .flatten()
        .filter(|e| e.path().is_dir())
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            (name.len() == 6 && name.bytes().all(|b| b.is_ascii_digit()))
                .then(|| name.parse().ok())
                .flatten()
        })
        .collect();
    frames.sort_unstable();
    frames
}

/// The moments whose point maps are used: for exported maps, every moment of `inputs`
/// with a folder (the flat layout and the first frames when none has); for a model, the
/// first `[init] moments` moments (the first frames when fewer than two).
pub fn sets<'a>(
    kind: UsedSource,
    path: &Path,
    inputs: &'a InitInputs,
    config: &InitConfig,
) -> Vec<MomentSet<'a>> {
    let timed: Vec<MomentSet<'a>> = match kind {
        UsedSource::Npy => inputs
            .moments
            .iter()
            .filter(|m| frame_dir(path, m.frame).is_dir())
            .map(|m| MomentSet {
                frame: Some(m.frame),
                time: m.time,
                dir: frame_dir(path, m.frame),
                views: &m.views,
            })
            .collect(),
        _ if config.moments >= 2 => inputs
            .moments
            .iter()
            .take(config.moments)
            .map(|m| MomentSet {
                frame: Some(m.frame),
                time: m.time,
                dir: path.to_path_buf(),
                views: &m.views,
            })
            .collect(),
        _ => Vec::new(),
    };
    if timed.len() >= 2 || (kind == UsedSource::Npy && timed.len() == 1) {
        return timed;
    }
    let time = inputs
        .images
        .iter()
        .map(|i| i.time)
        .fold(f64::NAN, f64::min);
    vec![MomentSet {
        frame: None,
        time,
        dir: path.to_path_buf(),
        views: &inputs.images,
    }]
}

/// The model times of the first and last moment of `sets`.
pub fn clip(sets: &[MomentSet<'_>]) -> (f64, f64) {
    sets.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
            (a.min(s.time), b.max(s.time))
        })
}

/// `points` of moment `moment` as [`TimedPoint`]s.
pub fn timed(points: &[FusedPoint], moment: usize) -> impl Iterator<Item = TimedPoint> + '_ {
    points.iter().map(move |p| TimedPoint {
        xyz: p.xyz,
        rgb: p.rgb,
        moment,
        time: p.time,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_folders_are_found_and_other_entries_ignored() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["000007", "000000", "000035", "00001", "notes", "cam0__cam1"] {
            std::fs::create_dir(dir.path().join(name)).unwrap();
        }
        std::fs::write(dir.path().join("000014"), b"a file, not a folder").unwrap();
        assert_eq!(exported_frames(dir.path()), [0, 7, 35]);
        assert_eq!(frame_dir(dir.path(), 7), dir.path().join("000007"));
        assert!(exported_frames(&dir.path().join("missing")).is_empty());
    }
}
