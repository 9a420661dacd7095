//! The capture directory: what a user hands to `pipeline`, validated before anything is
//! written.
//!
//! ```text
//! CAPTURE_DIR/
//!   capture.toml          optional settings (see `config`)
//!   raw/cam0/ … raw/camN/ video files per camera (GoPro chapters GX01xxxx.MP4, GX02xxxx.MP4, …)
//!   raw/<heldout>/        optional extra cameras listed in `[capture] heldout`: posed and
//!                         aligned like the others, never trained on, used by `eval`
//!   stills/               extra photos for pose solving (*.jpg, *.png)
//!   calibration.*         optional calibration to import instead of solving poses
//!                         (calibration.json|yaml|toml, camera_array.toml, Pose2Sim
//!                         Calib_scene.toml, calibration/ COLMAP)
//!   masks/<camera>/       optional moving-region masks for eval (`crate::masks`)
//!   groundtruth/          written by the simulator only
//!   work/<stage>/         outputs of each stage, with work/<stage>/stage.json
//! ```
//! This module only reads; it never creates or changes anything.

use std::fs;
use std::path::{Path, PathBuf};

use rig::media;
use thiserror::Error;

/// File name of the settings file inside a capture directory.
pub const CONFIG_FILE: &str = "capture.toml";
/// A validated capture directory.
#[derive(Clone, Debug)]
pub struct Capture {
    pub root: PathBuf,
    /// Training cameras (the `raw/camN/` folders not listed in `[capture] heldout`) in
    /// order of their number, each with its video files in recording order.
    pub cameras: Vec<CameraFolder>,
    /// Held-out cameras, in the order of `[capture] heldout` (empty when none are listed).
    pub heldout: Vec<CameraFolder>,
    /// Files in `stills/`, sorted by name (empty when the folder is absent).
    pub stills: Vec<PathBuf>,
    /// A calibration to import instead of solving poses (`calibration.json|yaml|toml`,
    /// `camera_array.toml`, Pose2Sim's `Calib_scene.toml` or a COLMAP model folder
    /// `calibration/`), if present.
    pub calibration: Option<PathBuf>,
}

/// One `raw/camN/` folder.
#[derive(Clone, Debug)]
pub struct CameraFolder {
    /// Folder name, e.g. `cam0`.
    pub name: String,
    pub dir: PathBuf,
    /// Video files sorted so that GoPro chapters come in recording order, or the images of
    /// an image-sequence camera.
    pub videos: Vec<PathBuf>,
}

impl Capture {
    pub fn work_dir(&self) -> PathBuf {
        self.root.join("work")
    }
    pub fn config_path(&self) -> PathBuf {
        self.root.join(CONFIG_FILE)
    }
    /// A path from `capture.toml`: relative paths are relative to the capture directory.
    pub fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.root.join(path)
        }
    }
    /// Every camera's video files (training and held-out cameras).
    pub fn all_videos(&self) -> Vec<PathBuf> {
        self.all_cameras()
            .flat_map(|c| c.videos.iter().cloned())
            .collect()
    }
    /// Training cameras, then held-out ones: every camera that is ingested, synchronised,
    /// aligned and posed (the first one is the sync reference by default).
    pub fn all_cameras(&self) -> impl Iterator<Item = &CameraFolder> {
        self.cameras.iter().chain(&self.heldout)
    }
}

/// What is wrong with a capture directory. Each message names the path and the fix.
#[derive(Debug, Error)]
pub enum LayoutError {
    #[error("capture directory {0} does not exist (create it, or check the path)")]
    NoCaptureDir(PathBuf),
    #[error("{0} is not a directory: pass the capture directory that holds raw/ and stills/")]
    NotADirectory(PathBuf),
    #[error("{0} is missing: put each camera's videos in raw/cam0/ … raw/cam{last}/", last = .1 - 1)]
    NoRawDir(PathBuf, usize),
    #[error("{dir}: expected {expected} {kind}camera folders (cam0 … cam{last}), found {found}{list}; \
             add the missing camera's folder or set `cameras = {found}` under [capture] in capture.toml \
             (or list extra cameras that are only for evaluation as `heldout = [\"camN\", …]` there)",
            last = .expected - 1, list = if .names.is_empty() { String::new() } else { format!(" ({})", .names.join(", ")) },
            kind = if .heldout.is_empty() { String::new() } else { format!("training (besides held-out {}) ", .heldout.join(", ")) })]
    WrongCameraCount {
        dir: PathBuf,
        expected: usize,
        found: usize,
        names: Vec<String>,
        /// The held-out folders (not counted).
        heldout: Vec<String>,
    },
    #[error(
        "{dir} is missing (or not a folder): [capture] heldout in capture.toml lists {name}; \
             copy that camera's videos into it, or remove {name:?} from `heldout`"
    )]
    HeldoutMissing { dir: PathBuf, name: String },
    #[error(
        "{0} does not belong in raw/: only camera folders named camN (cam0, cam1, …) may be there, \
         and folders listed in `heldout = [...]` under [capture] in capture.toml"
    )]
    UnexpectedEntry(PathBuf),
    #[error(
        "{0} holds no video: copy that camera's recordings (e.g. GX010001.MP4) into it, or its numbered images (000000.jpg, …)"
    )]
    EmptyCameraDir(PathBuf),
    #[error("{path} is not a video{detail}; a camera folder holds videos (an FFmpeg-readable MP4/MOV, \
             Matroska/WebM, AVI or MPEG-TS/PS container, e.g. .{exts}) or images (.{images}); move it elsewhere",
            exts = media::VIDEO_EXTENSIONS.join("/."), images = media::IMAGE_EXTENSIONS.join("/."))]
    NotAVideo { path: PathBuf, detail: String },
    #[error("{0} is not a directory: stills/ must be a folder of photos")]
    StillsNotADirectory(PathBuf),
    #[error(
        "{0} is not an image: stills/ may only hold .{exts} photos (move it elsewhere)",
        exts = media::PHOTO_EXTENSIONS.join("/.")
    )]
    NotAnImage(PathBuf),
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> LayoutError + '_ {
    move |source| LayoutError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn is_hidden(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('.'))
}

/// Sorted entries of a directory, hidden files skipped.
fn list_dir(dir: &Path) -> Result<Vec<PathBuf>, LayoutError> {
    let mut entries = Vec::new();
    for entry in fs::read_dir(dir).map_err(io_err(dir))? {
        let path = entry.map_err(io_err(dir))?.path();
        if !is_hidden(&path) {
            entries.push(path);
        }
    }
    entries.sort();
    Ok(entries)
}

/// The camera number in a folder name `camN`.
fn camera_number(name: &str) -> Option<u32> {
    name.strip_prefix("cam")
        .filter(|n| !n.is_empty())
        .and_then(|n| n.parse().ok())
}

/// Check that the file's content is a video container ([`media::sniff`]).
pub fn sniff_video(path: &Path) -> Result<(), LayoutError> {
    match media::sniff_file(path).map_err(io_err(path))? {
        Some(_) => Ok(()),
        None if fs::metadata(path).map_err(io_err(path))?.len() == 0 => {
            Err(LayoutError::NotAVideo {
                path: path.to_path_buf(),
                detail: " (the file is empty)".into(),
            })
        }
        None => Err(LayoutError::NotAVideo {
            path: path.to_path_buf(),
            detail:
                " (its contents are not an MP4/MOV, Matroska/WebM, AVI or MPEG-TS/PS container)"
                    .into(),
        }),
    }
}

/// Validate a capture directory: exactly `expected_cameras` folders `raw/camN/`, each with
/// at least one video, nothing else in `raw/`, `stills/` (optional) holding only images.
pub fn validate(root: &Path, expected_cameras: usize) -> Result<Capture, LayoutError> {
    validate_rig(root, expected_cameras, &[])
}

/// Validate a capture directory with held-out cameras: the folders `raw/<name>/` of
/// `heldout` (each must exist) plus exactly `expected_cameras` training folders `raw/camN/`
/// (every other folder), each with at least one video; `stills/` holding only images.
/// `heldout` comes from a parsed `capture.toml` (no duplicates, plain names).
pub fn validate_rig(
    root: &Path,
    expected_cameras: usize,
    heldout: &[String],
) -> Result<Capture, LayoutError> {
    if !root.exists() {
        return Err(LayoutError::NoCaptureDir(root.to_path_buf()));
    }
    if !root.is_dir() {
        return Err(LayoutError::NotADirectory(root.to_path_buf()));
    }
    let raw = root.join("raw");
    if !raw.is_dir() {
        return Err(LayoutError::NoRawDir(raw, expected_cameras.max(1)));
    }
    for name in heldout {
        let dir = raw.join(name);
        if !dir.is_dir() {
            return Err(LayoutError::HeldoutMissing {
                dir,
                name: name.clone(),
            });
        }
    }
    let mut cameras: Vec<(u32, PathBuf)> = Vec::new();
    for entry in list_dir(&raw)? {
        let name = entry.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if heldout.iter().any(|h| h == name) {
            continue;
        }
        match camera_number(name) {
            Some(n) if entry.is_dir() => cameras.push((n, entry.clone())),
            _ => return Err(LayoutError::UnexpectedEntry(entry)),
        }
    }
    cameras.sort();
    if cameras.len() != expected_cameras {
        return Err(LayoutError::WrongCameraCount {
            dir: raw,
            expected: expected_cameras,
            found: cameras.len(),
            names: cameras.iter().map(|(n, _)| format!("cam{n}")).collect(),
            heldout: heldout.to_vec(),
        });
    }
    let folders = cameras
        .into_iter()
        .map(|(_, dir)| camera_folder(dir))
        .collect::<Result<Vec<_>, _>>()?;
    let heldout = heldout
        .iter()
        .map(|name| camera_folder(raw.join(name)))
        .collect::<Result<Vec<_>, _>>()?;
    let stills_dir = root.join("stills");
    let mut stills = Vec::new();
    if stills_dir.exists() {
        if !stills_dir.is_dir() {
            return Err(LayoutError::StillsNotADirectory(stills_dir));
        }
        for file in list_dir(&stills_dir)? {
            if file.is_dir() || !media::is_photo(&file) {
                return Err(LayoutError::NotAnImage(file));
            }
            stills.push(file);
        }
    }
    let calibration = calib::import::find_calibration(root);
    Ok(Capture {
        root: root.to_path_buf(),
        cameras: folders,
        heldout,
        stills,
        calibration,
    })
}

/// A camera folder's videos in recording order (at least one; sidecar files skipped), or
/// its numbered images when it holds images and no video (an image-sequence camera).
fn camera_folder(dir: PathBuf) -> Result<CameraFolder, LayoutError> {
    let mut videos = Vec::new();
    let mut images = Vec::new();
    for file in list_dir(&dir)? {
        if media::is_sidecar(&file) {
            continue;
        }
        if !file.is_dir() && media::is_image(&file) {
            images.push(file);
            continue;
        }
        if file.is_dir() {
            return Err(LayoutError::NotAVideo {
                path: file,
                detail: " (a folder)".into(),
            });
        }
        // By content, whatever the name: FFmpeg demuxes by content too.
        sniff_video(&file)?;
        videos.push(file);
    }
    if let (Some(image), false) = (images.first(), videos.is_empty()) {
        return Err(LayoutError::NotAVideo {
            path: image.clone(),
            detail: " (a camera folder holds videos or an image sequence, not both)".into(),
        });
    }
    if videos.is_empty() && images.is_empty() {
        return Err(LayoutError::EmptyCameraDir(dir));
    }
    let files = if videos.is_empty() {
        // Ingest orders and times them (`rig::ingest::camera_files`).
        images
    } else {
        media::sort_recordings(&mut videos);
        videos
    };
    let name = dir
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("")
        .to_string();
    Ok(CameraFolder {
        name,
        dir,
        videos: files,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_folder_names() {
        assert_eq!(camera_number("cam3"), Some(3));
        assert_eq!(camera_number("cam12"), Some(12));
        assert_eq!(camera_number("cam"), None);
        assert_eq!(camera_number("camera1"), None);
        assert_eq!(camera_number("cam-1"), None);
    }

    /// `raw/<name>/` folders with one (MP4-signed) video each.
    fn capture_with(names: &[&str]) -> tempfile::TempDir {
        let tmp = tempfile::tempdir().unwrap();
        for name in names {
            let dir = tmp.path().join("raw").join(name);
            fs::create_dir_all(&dir).unwrap();
            fs::write(
                dir.join("GX010001.MP4"),
                b"\x00\x00\x00\x18ftypmp42\x00\x00\x00\x00mp42isom",
            )
            .unwrap();
        }
        tmp
    }

    fn heldout(names: &[&str]) -> Vec<String> {
        names.iter().map(|n| n.to_string()).collect()
    }

    #[test]
    fn heldout_folders_are_separated_from_the_training_cameras() {
        let tmp = capture_with(&["cam0", "cam1", "cam2", "cam3", "cam4", "cam5"]);
        let capture = validate_rig(tmp.path(), 4, &heldout(&["cam5", "cam4"])).unwrap();
        let names = |c: &[CameraFolder]| c.iter().map(|c| c.name.clone()).collect::<Vec<_>>();
        assert_eq!(names(&capture.cameras), ["cam0", "cam1", "cam2", "cam3"]);
        assert_eq!(names(&capture.heldout), ["cam5", "cam4"]);
        assert_eq!(capture.all_cameras().count(), 6);
        // Any camera may be held out; the others train. A held-out name need not be camN.
        let capture = validate_rig(tmp.path(), 5, &heldout(&["cam2"])).unwrap();
        assert_eq!(
            names(&capture.cameras),
            ["cam0", "cam1", "cam3", "cam4", "cam5"]
        );
        let tmp = capture_with(&["cam0", "cam1", "cam2", "cam3", "judge"]);
        let capture = validate_rig(tmp.path(), 4, &heldout(&["judge"])).unwrap();
        assert_eq!(names(&capture.heldout), ["judge"]);
    }

    #[test]
    fn heldout_layout_errors_name_the_key_to_set() {
        let tmp = capture_with(&["cam0", "cam1", "cam2", "cam3", "cam4", "cam5"]);
        // Extra folders that are not listed: set `cameras` or `heldout`.
        let err = validate_rig(tmp.path(), 4, &[]).unwrap_err().to_string();
        assert!(
            err.contains("found 6") && err.contains("cameras = 6") && err.contains("heldout"),
            "{err}"
        );
        let err = validate_rig(tmp.path(), 4, &heldout(&["cam4"]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("found 5") && err.contains("held-out cam4") && err.contains("cam5"),
            "{err}"
        );
        // A listed folder that is missing.
        let err = validate_rig(tmp.path(), 4, &heldout(&["cam4", "cam5", "cam6"]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("cam6") && err.contains("is missing") && err.contains("heldout"),
            "{err}"
        );
        // An unlisted folder that is not camN.
        let tmp = capture_with(&["cam0", "cam1", "cam2", "cam3", "judge"]);
        let err = validate_rig(tmp.path(), 4, &[]).unwrap_err().to_string();
        assert!(
            err.contains("judge") && err.contains("does not belong") && err.contains("heldout"),
            "{err}"
        );
        // A held-out folder without videos.
        let tmp = capture_with(&["cam0", "cam1", "cam2", "cam3"]);
        fs::create_dir_all(tmp.path().join("raw/cam4")).unwrap();
        let err = validate_rig(tmp.path(), 4, &heldout(&["cam4"]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("cam4") && err.contains("holds no video"),
            "{err}"
        );
    }
}
