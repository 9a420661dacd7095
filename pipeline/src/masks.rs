//! Moving-region masks for `eval` (docs/render-eval.md): where moving or deforming objects
//! are in each evaluated view, so that eval can report PSNR and SSIM inside them. A mask
//! is an 8-bit grey PNG, inside where ≥ 128. They come from one of two folders:
//!
//! - `CAPTURE/masks/<camera>/NNNNNN.png`, a user's masks (used when `masks/` exists):
//!   numbered and sized like the aligned frames `work/frames/<camera>/NNNNNN.png` they
//!   apply to (training and `[capture] heldout` cameras alike).
//! - `CAPTURE/groundtruth/masks/<camera>/NNNNNN.png`, the simulator's: numbered by the
//!   camera's own video frame (frame `k` at `k / fps` on its clock), which is also the
//!   number of a simulated held-out image `groundtruth/heldout/<camera>/NNNNNN.png`.
//!
//! - Neither: with `[eval] plate_masks` (on by default), masks estimated from the aligned
//!   frames themselves ([`MaskSource::from_plates`]): every camera stands still, so the
//!   median of its frames is the static scene and what differs from it moves (the init's
//!   static plates, `pointinit::plates`), written to the eval stage's `plate_masks/`.
//!
//! A view without a mask file has no mask. A mask of another size with the image's aspect
//! ratio is scaled (nearest neighbour); where the camera has a lens it is undistorted like
//! its image, into the eval stage's output.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use calib::undistort::UndistortMap;
use image::GrayImage;
use pointinit::plates::{median_plate, moving_pixels};
use rayon::prelude::*;
use rig::frames::View;
use rig::sim::OffsetsFile;
use rig::sync::SyncResult;

/// The folder of a user's masks in a capture directory.
pub const CAPTURE_MASKS_DIR: &str = "masks";
/// The simulator's masks, in a capture directory.
const SIMULATOR_MASKS_DIR: &str = "groundtruth/masks";
/// Estimated masks, in the eval stage's output.
pub const PLATE_MASKS_DIR: &str = "plate_masks";
/// Largest relative difference of aspect ratios for a mask to be scaled to its image.
const ASPECT_TOLERANCE: f64 = 0.01;

/// How the files of a masks folder are numbered.
#[derive(Clone, Debug, PartialEq)]
enum Numbering {
    /// Like the aligned frames (`masks/` + the view's `work/frames` file name).
    Aligned,
    /// By the camera's video frame: `round((timestamp − sync offset) · fps)`.
    Simulator {
        fps: f64,
        /// Sync offsets (`t_common = t_camera + offset_s`) by camera name.
        offsets: Vec<(String, f64)>,
    },
}

/// Where a capture's masks are and how they are numbered.
#[derive(Clone, Debug, PartialEq)]
pub struct MaskSource {
    dir: PathBuf,
    numbering: Numbering,
    /// Estimated from the static plates ([`MaskSource::from_plates`]), not given.
    estimated: bool,
}

/// How [`MaskSource::from_plates`] estimates masks: the init's `[init] plates` and
/// `[init] motion_threshold`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlateMasks {
    /// Frames per camera, spread over the clip, whose median is its static plate.
    pub frames: usize,
    /// Least channel difference from the plate that counts as moving.
    pub threshold: u8,
}

impl MaskSource {
    /// The masks of the capture at `root`: its `masks/` folder if there is one, else the
    /// simulator's `groundtruth/masks/` (with the offsets of `sync_path`, the sync stage's
    /// `sync.json`); `None` with neither.
    pub fn find(root: &Path, sync_path: &Path) -> anyhow::Result<Option<Self>> {
        let user = root.join(CAPTURE_MASKS_DIR);
        if user.is_dir() {
            return Ok(Some(Self {
                dir: user,
                numbering: Numbering::Aligned,
                estimated: false,
            }));
        }
        let dir = root.join(SIMULATOR_MASKS_DIR);
        if !dir.is_dir() {
            return Ok(None);
        }
        let offsets_path = root.join("groundtruth/offsets.json");
        let text = std::fs::read_to_string(&offsets_path)
            .with_context(|| format!("cannot read {}", offsets_path.display()))?;
        let truth: OffsetsFile = serde_json::from_str(&text).with_context(|| {
            format!(
                "{} is not the simulator's offsets file",
                offsets_path.display()
            )
        })?;
        let sync = SyncResult::read_json(sync_path)?;
        Ok(Some(Self {
            dir,
            numbering: Numbering::Simulator {
                fps: truth.fps,
                offsets: sync
                    .cameras
                    .iter()
                    .map(|c| (c.name.clone(), c.offset_s))
                    .collect(),
            },
            estimated: false,
        }))
    }

    /// Masks estimated for every camera folder of `frames_dir` (the aligned frames,
    /// `<camera>/NNNNNN.png`): its static plate, the median of `settings.frames` of its
    /// frames spread over the clip, and each frame's moving pixels against it
    /// (`pointinit::plates::moving_pixels`), written to `out/<camera>/NNNNNN.png`. `None`
    /// when `settings.frames` is 0 or no camera has frames.
    pub fn from_plates(
        frames_dir: &Path,
        settings: PlateMasks,
        out: &Path,
    ) -> anyhow::Result<Option<Self>> {
        if settings.frames == 0 {
            return Ok(None);
        }
        let mut any = false;
        for camera in camera_folders(frames_dir)? {
            let files = frame_files(&frames_dir.join(&camera))?;
            if files.is_empty() {
                continue;
            }
            let read = |path: &PathBuf| -> anyhow::Result<image::RgbImage> {
                Ok(image::open(path)
                    .with_context(|| format!("cannot read the aligned frame {}", path.display()))?
                    .to_rgb8())
            };
            let picks = crate::stages::init::moment_frames(files.len(), settings.frames);
            let frames = picks
                .par_iter()
                .map(|&i| read(&files[i]))
                .collect::<anyhow::Result<Vec<_>>>()?;
            if let Some(f) = frames
                .iter()
                .find(|f| f.dimensions() != frames[0].dimensions())
            {
                bail!(
                    "the aligned frames of {camera} differ in size ({:?} and {:?}); rerun the frames stage",
                    frames[0].dimensions(),
                    f.dimensions()
                );
            }
            let plate = median_plate(&frames);
            let dir = out.join(&camera);
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            files.par_iter().try_for_each(|path| -> anyhow::Result<()> {
                let frame = read(path)?;
                if frame.dimensions() != plate.dimensions() {
                    bail!(
                        "{} is {:?} but the other frames of {camera} are {:?}; rerun the frames stage",
                        path.display(),
                        frame.dimensions(),
                        plate.dimensions()
                    );
                }
                let mask = moving_pixels(&frame, &plate, settings.threshold).to_grey();
                let file = dir.join(path.file_name().expect("a listed file"));
                mask.save(&file)
                    .with_context(|| format!("cannot write {}", file.display()))
            })?;
            any = true;
        }
        Ok(any.then(|| Self {
            dir: out.to_path_buf(),
            numbering: Numbering::Aligned,
            estimated: true,
        }))
    }

    /// Whether the masks were estimated from the static plates rather than given.
    pub fn estimated(&self) -> bool {
        self.estimated
    }

    /// The folder the masks come from.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The mask of an aligned frame's `view` of `camera`, if its file exists.
    pub fn for_view(&self, camera: &str, view: &View) -> Option<PathBuf> {
        let path = match &self.numbering {
            Numbering::Aligned => self.dir.join(&view.file),
            Numbering::Simulator { fps, offsets } => {
                let offset = offsets.iter().find(|(name, _)| name == camera)?.1;
                let frame = ((view.timestamp_s - offset) * fps).round();
                if frame < 0.0 {
                    return None;
                }
                self.dir
                    .join(camera)
                    .join(format!("{:06}.png", frame as u64))
            }
        };
        path.is_file().then_some(path)
    }

    /// The mask of the simulator's held-out image `k` of `camera`, if its file exists
    /// (never with a user's masks, which are numbered by aligned frame).
    pub fn for_simulated_image(&self, camera: &str, k: usize) -> Option<PathBuf> {
        if self.numbering == Numbering::Aligned {
            return None;
        }
        let path = self.dir.join(camera).join(format!("{k:06}.png"));
        path.is_file().then_some(path)
    }
}

/// The camera folders of an aligned frames folder, sorted.
fn camera_folders(frames_dir: &Path) -> anyhow::Result<Vec<String>> {
    let entries = std::fs::read_dir(frames_dir).with_context(|| {
        format!(
            "cannot list {}; rerun the frames stage",
            frames_dir.display()
        )
    })?;
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.with_context(|| format!("cannot list {}", frames_dir.display()))?;
        if entry.path().is_dir() {
            names.push(entry.file_name().to_string_lossy().into_owned());
        }
    }
    names.sort();
    Ok(names)
}

/// The `.png` files of a camera's aligned frames, sorted by name (= frame number).
fn frame_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))? {
        let path = entry
            .with_context(|| format!("cannot list {}", dir.display()))?
            .path();
        if path.extension().is_some_and(|e| e == "png") {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// The mask `mask` made ready for the ground-truth image `image` (before undistortion):
/// the file itself when it fits as is, else a copy scaled to the image's size and
/// undistorted with `map`, written to `out`. Errors name both files when the aspect
/// ratios differ.
pub fn prepare(
    mask: &Path,
    image: &Path,
    map: Option<&UndistortMap>,
    out: &Path,
) -> anyhow::Result<PathBuf> {
    let (width, height) = image::image_dimensions(image)
        .with_context(|| format!("cannot read the size of {}", image.display()))?;
    let grey = image::open(mask)
        .with_context(|| {
            format!(
                "cannot read the moving-region mask {}; give an 8-bit grey PNG",
                mask.display()
            )
        })?
        .to_luma8();
    if grey.dimensions() == (width, height) && map.is_none() {
        return Ok(mask.to_path_buf());
    }
    let (w, h) = grey.dimensions();
    let Some(scaled) = scale_to(grey, width, height) else {
        bail!(
            "the moving-region mask {} is {w}×{h} but its image {} is {width}×{height}; give masks of the image's size",
            mask.display(),
            image.display()
        );
    };
    let fitted = match map {
        Some(map) => threshold(
            map.apply(&scaled)
                .with_context(|| format!("cannot undistort {}", mask.display()))?,
        ),
        None => scaled,
    };
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    fitted
        .save(out)
        .with_context(|| format!("cannot write {}", out.display()))?;
    Ok(out.to_path_buf())
}

/// `mask` at `width × height`: itself, or scaled by nearest neighbour when its aspect
/// ratio is the same (within [`ASPECT_TOLERANCE`]); `None` for another aspect ratio.
fn scale_to(mask: GrayImage, width: u32, height: u32) -> Option<GrayImage> {
    let (w, h) = mask.dimensions();
    if (w, h) == (width, height) {
        return Some(mask);
    }
    let aspect = |w: u32, h: u32| f64::from(w) / f64::from(h.max(1));
    if w == 0 || h == 0 || (aspect(w, h) / aspect(width, height) - 1.0).abs() > ASPECT_TOLERANCE {
        return None;
    }
    Some(image::imageops::resize(
        &mask,
        width,
        height,
        image::imageops::FilterType::Nearest,
    ))
}

/// Back to 0/255 after bilinear resampling (inside where ≥ 128).
fn threshold(mut mask: GrayImage) -> GrayImage {
    for p in mask.pixels_mut() {
        p.0[0] = if p.0[0] >= 128 { 255 } else { 0 };
    }
    mask
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(file: &str, timestamp_s: f64) -> View {
        View {
            source_frame: 0,
            timestamp_s,
            residual_s: 0.0,
            file: file.into(),
        }
    }

    fn touch(path: &Path) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        GrayImage::new(4, 3).save(path).unwrap();
    }

    #[test]
    fn simulator_masks_are_found_by_video_frame_and_user_masks_by_aligned_frame() {
        let source = MaskSource {
            dir: PathBuf::from("/m"),
            numbering: Numbering::Simulator {
                fps: 15.0,
                offsets: vec![("cam1".into(), 0.2)],
            },
            estimated: false,
        };
        let tmp = tempfile::tempdir().unwrap();
        let sim = MaskSource {
            dir: tmp.path().join("sim"),
            ..source
        };
        // cam1's frame at 0.2 + 7/15 s on the common timeline is its video frame 7.
        touch(&sim.dir.join("cam1/000007.png"));
        let v = view("cam1/000003.png", 0.2 + 7.0 / 15.0 + 0.003);
        assert_eq!(
            sim.for_view("cam1", &v),
            Some(sim.dir.join("cam1/000007.png"))
        );
        assert_eq!(sim.for_view("cam2", &v), None, "no sync offset");
        assert_eq!(
            sim.for_view("cam1", &view("cam1/000004.png", 0.9)),
            None,
            "no file"
        );
        touch(&sim.dir.join("heldout0/000002.png"));
        assert!(sim.for_simulated_image("heldout0", 2).is_some());

        let user = MaskSource {
            dir: tmp.path().join("masks"),
            numbering: Numbering::Aligned,
            estimated: false,
        };
        touch(&user.dir.join("cam1/000003.png"));
        assert_eq!(
            user.for_view("cam1", &v),
            Some(user.dir.join("cam1/000003.png"))
        );
        assert_eq!(user.for_simulated_image("cam1", 3), None);
    }

    #[test]
    fn masks_are_scaled_to_their_image_or_refused_naming_both_files() {
        let tmp = tempfile::tempdir().unwrap();
        let image = tmp.path().join("frame.png");
        image::RgbImage::new(8, 6).save(&image).unwrap();
        // The right size: used as is.
        let same = tmp.path().join("same.png");
        GrayImage::new(8, 6).save(&same).unwrap();
        let out = tmp.path().join("out/mask.png");
        assert_eq!(prepare(&same, &image, None, &out).unwrap(), same);
        // Twice the size, same aspect: scaled.
        let big = tmp.path().join("big.png");
        GrayImage::from_fn(16, 12, |x, _| image::Luma([if x < 8 { 255 } else { 0 }]))
            .save(&big)
            .unwrap();
        let got = prepare(&big, &image, None, &out).unwrap();
        assert_eq!(got, out);
        let scaled = image::open(&got).unwrap().to_luma8();
        assert_eq!(scaled.dimensions(), (8, 6));
        assert_eq!(
            (scaled.get_pixel(3, 2).0[0], scaled.get_pixel(4, 2).0[0]),
            (255, 0)
        );
        // Another aspect ratio: an error naming the mask, the image and its size.
        let wide = tmp.path().join("wide.png");
        GrayImage::new(10, 6).save(&wide).unwrap();
        let err = format!("{:#}", prepare(&wide, &image, None, &out).unwrap_err());
        assert!(
            err.contains("wide.png")
                && err.contains("frame.png")
                && err.contains("8×6")
                && err.contains("10×6"),
            "{err}"
        );
    }

    #[test]
    fn plate_masks_mark_what_moves_in_each_frame_of_each_camera() {
        let tmp = tempfile::tempdir().unwrap();
        let frames = tmp.path().join("frames");
        // cam0: a grey room where a red 3×3 square walks along a row, one column per frame;
        // cam1: nothing moves.
        for k in 0..7u32 {
            for cam in ["cam0", "cam1"] {
                let mut f = image::RgbImage::from_pixel(24, 10, image::Rgb([120, 120, 120]));
                if cam == "cam0" {
                    for y in 4..7 {
                        for x in 3 * k..3 * k + 3 {
                            f.put_pixel(x, y, image::Rgb([200, 30, 30]));
                        }
                    }
                }
                let path = frames.join(cam).join(format!("{k:06}.png"));
                std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                f.save(&path).unwrap();
            }
        }
        let settings = PlateMasks {
            frames: 5,
            threshold: pointinit::plates::MOTION_THRESHOLD,
        };
        let out = tmp.path().join("plate_masks");
        let source = MaskSource::from_plates(&frames, settings, &out)
            .unwrap()
            .unwrap();
        assert!(source.estimated());
        let path = source
            .for_view("cam0", &view("cam0/000003.png", 0.0))
            .unwrap();
        let mask = image::open(path).unwrap().to_luma8();
        // The square covers x 9..12, y 4..7; the mask is that grown by two pixels.
        for (x, y) in [(9, 4), (11, 6), (7, 2), (13, 8)] {
            assert_eq!(mask.get_pixel(x, y).0[0], 255, "({x}, {y})");
        }
        for (x, y) in [(6, 5), (14, 5), (10, 1), (2, 5), (20, 5)] {
            assert_eq!(mask.get_pixel(x, y).0[0], 0, "({x}, {y})");
        }
        let still = source
            .for_view("cam1", &view("cam1/000003.png", 0.0))
            .unwrap();
        let still = image::open(still).unwrap().to_luma8();
        assert!(still.pixels().all(|p| p.0[0] == 0));
        // No plate frames: no estimate.
        let none = PlateMasks {
            frames: 0,
            ..settings
        };
        assert!(
            MaskSource::from_plates(&frames, none, &out)
                .unwrap()
                .is_none()
        );
        // A frame of another size is named.
        image::RgbImage::new(8, 8)
            .save(frames.join("cam1/000002.png"))
            .unwrap();
        let err = format!(
            "{:#}",
            MaskSource::from_plates(&frames, settings, &out).unwrap_err()
        );
        assert!(
            err.contains("cam1") && err.contains("rerun the frames stage"),
            "{err}"
        );
    }
}
