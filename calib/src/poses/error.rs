//! Errors of the poses stage: each says what was wrong and what to try.

use std::path::PathBuf;

use crate::colmap_runner::ColmapError;
use crate::colmap_runner::diagnose::Diagnosis;
use crate::convert::ConvertError;

/// Errors of the poses stage.
#[derive(Debug, thiserror::Error)]
pub enum PosesError {
    #[error(
        "no video frames were given to the poses stage (is work/frames/ empty? run the frames stage first)"
    )]
    NoVideoFrames,
    #[error("video camera name {0:?} appears twice")]
    DuplicateCamera(String),
    #[error(
        "only {got} stills in stills/, at least {min} are needed to connect the video cameras: take \
         more photos (8 recommended) walking in an arc between the cameras, or lower poses.min_stills"
    )]
    TooFewStills { got: usize, min: usize },
    #[error("cannot read image {path}: {reason}")]
    ImageUnreadable { path: PathBuf, reason: String },
    #[error(
        "image {path} is blank (pixel values vary by only {std_dev:.2} levels): COLMAP cannot find \
         features in it. Check the lens cap, exposure and that the right file was extracted"
    )]
    BlankImage { path: PathBuf, std_dev: f64 },
    #[error(
        "the stills share one camera but differ in size ({sizes}): set poses.colmap.stills_cameras = \
         \"per_image\" (different phones or zoom), or resize them to one size"
    )]
    StillSizesDiffer { sizes: String },
    #[error(
        "the video cameras share one camera (poses.colmap.video_cameras = \"shared\") but their \
         frames differ in size ({sizes}): use \"separate\" or \"auto\""
    )]
    VideoSizesDiffer { sizes: String },
    #[error(
        "COLMAP's solve looks degenerate in all {} attempts, so no poses were written:\n{}\n\
         This happens when the scene repeats itself (tiled floors, wallpaper, identical \
         objects) or the images overlap little. What to try: give the lens's focal length \
         (poses.colmap.video_focal_px) or import a calibration; add stills between the video \
         cameras; add non-repeating texture (posters, newspaper).\n{diagnosis}",
        attempts.len(),
        attempts.iter().enumerate().map(|(i, a)| format!("  attempt {}: {a}", i + 1)).collect::<Vec<_>>().join("\n")
    )]
    Degenerate {
        /// Per mapper attempt, what was wrong.
        attempts: Vec<String>,
        diagnosis: Diagnosis,
    },
    #[error("{0}")]
    Colmap(#[from] ColmapError),
    #[error(
        "COLMAP found no model: no good initial image pair (no two images share enough matched \
         features seen from different positions).\n{diagnosis}"
    )]
    NoInitialPair { diagnosis: Diagnosis },
    #[error("COLMAP did not register video camera(s) {}.\n{diagnosis}", missing.join(", "))]
    VideoNotRegistered {
        missing: Vec<String>,
        diagnosis: Diagnosis,
    },
    #[error(
        "COLMAP split the images into {} separate models and the video cameras are not all in one \
         ({}).\n{diagnosis}", groups.len(), groups.iter().enumerate().map(|(i, g)| format!("model {i}: {}", g.join(", "))).collect::<Vec<_>>().join("; ")
    )]
    SplitModels {
        groups: Vec<Vec<String>>,
        diagnosis: Diagnosis,
    },
    #[error(transparent)]
    Convert(#[from] ConvertError),
    #[error(
        "camera {camera} was calibrated at {}×{} but the working size is {}×{}: a different aspect \
         ratio means a crop, which cannot be handled by scaling; calibrate at the recording's \
         aspect ratio or set the working size to match",
        calibrated.0, calibrated.1, working.0, working.1
    )]
    AspectMismatch {
        camera: String,
        calibrated: (u32, u32),
        working: (u32, u32),
    },
    #[error(
        "camera {camera}: the calibration {} is for {}×{} images but its video is {}×{}: that is \
         neither a resize (same aspect ratio) nor codec padding (up to the next multiple of 8 or \
         16 pixels, right/bottom), so the lens cannot be fitted; calibrate at the recording's \
         size, or check that the calibration's camera belongs to this folder ([poses] names)",
        file.display(), calibrated.0, calibrated.1, video.0, video.1
    )]
    CalibrationSize {
        camera: String,
        file: PathBuf,
        calibrated: (u32, u32),
        video: (u32, u32),
    },
    #[error(
        "the calibration {} has no camera for the folder(s) {}. Its cameras: {}; the capture's \
         camera folders (training and held-out): {}. Map folders to calibration names in \
         capture.toml, under [poses]: {}",
        file.display(),
        missing.iter().map(|(f, c)| if f == c { format!("raw/{f}") } else { format!("raw/{f} (as {c:?})") }).collect::<Vec<_>>().join(", "),
        calibration.join(", "),
        folders.join(", "),
        suggestion.clone().unwrap_or_else(|| "names = { cam0 = \"<its name in the calibration>\", … }".into())
    )]
    CalibrationMissesCameras {
        file: PathBuf,
        /// (folder, the name looked for in the calibration).
        missing: Vec<(String, String)>,
        /// The calibration's camera names.
        calibration: Vec<String>,
        /// The capture's camera folders.
        folders: Vec<String>,
        /// A `names = { … }` line pairing folders and cameras by their numbers, if one fits.
        suggestion: Option<String>,
    },
    #[error(
        "[poses] names maps the folder {folder:?}, which is not a camera folder of the capture \
         ({}); fix the name in capture.toml",
        folders.join(", ")
    )]
    UnknownNamedFolder {
        folder: String,
        folders: Vec<String>,
    },
    #[error(
        "a known lens was given for camera {camera}, which is not a video camera of this solve"
    )]
    KnownLensWithoutCamera { camera: String },
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}
