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
//!   static plates, `pointinit::plates`). Each evaluated view's mask is estimated when
//!   eval asks for it and written to the eval stage's `plate_masks/`.
//!
//! A view without a mask file has no mask. A mask of another size with the image's aspect
//! ratio is scaled (nearest neighbour); where the camera has a lens it is undistorted like
//! its image, into the eval stage's output.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use calib::undistort::UndistortMap;
use image::{GrayImage, RgbImage};
use pointinit::plates::{median_plate, moving_pixels};
use rayon::prelude::*;
use rig::frames::{FramesIndex, View};
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
    /// Estimated on demand like the aligned frames (`plate_masks/` + the view's file name)
    /// from the frame in `frames_dir` and its camera's static plate.
    Plates {
        frames_dir: PathBuf,
        /// Each camera's static plate, by camera name.
        plates: Vec<(String, RgbImage)>,
        /// Least channel difference from the plate that counts as moving.
        threshold: u8,
    },
}

/// One camera's aligned frames, in order: file names relative to the frames folder.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraFrames {
    pub name: String,
    pub files: Vec<String>,
}

impl CameraFrames {
    /// Every camera of a frames index (`frames.json` or `heldout.json`) with its frames.
    pub fn of_index(index: &FramesIndex) -> Vec<Self> {
        index
            .cameras
            .iter()
            .enumerate()
            .map(|(c, camera)| Self {
                name: camera.name.clone(),
                files: index
                    .frames
                    .iter()
                    .map(|f| f.views[c].file.clone())
                    .collect(),
            })
            .collect()
    }
}

/// Where a capture's masks are and how they are numbered.
#[derive(Clone, Debug, PartialEq)]
pub struct MaskSource {
    dir: PathBuf,
    numbering: Numbering,
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
        }))
    }

    /// Masks estimated from the static plates of `cameras` (their aligned frames in
    /// `frames_dir`): each camera's plate is the median of `settings.frames` of its frames
    /// spread over the clip; a view's mask, its moving pixels against the plate
    /// (`pointinit::plates::moving_pixels`), is made when [`Self::for_view`] asks for it
    /// and written to `out/<camera>/NNNNNN.png`. `None` when `settings.frames` is 0 or no
    /// camera has frames.
    pub fn from_plates(
        frames_dir: &Path,
        cameras: &[CameraFrames],
        settings: PlateMasks,
        out: &Path,
    ) -> anyhow::Result<Option<Self>> {
        if settings.frames == 0 {
            return Ok(None);
        }
        let plates = cameras
            .par_iter()
            .filter(|camera| !camera.files.is_empty())
            .map(|camera| -> anyhow::Result<(String, RgbImage)> {
                let picks = crate::stages::init::moment_frames(camera.files.len(), settings.frames);
                let frames = picks
                    .par_iter()
                    .map(|&i| read_frame(&frames_dir.join(&camera.files[i])))
                    .collect::<anyhow::Result<Vec<_>>>()?;
                if let Some(f) = frames
                    .iter()
                    .find(|f| f.dimensions() != frames[0].dimensions())
                {
                    bail!(
                        "the aligned frames of {} differ in size ({:?} and {:?}); rerun the frames stage",
                        camera.name,
                        frames[0].dimensions(),
                        f.dimensions()
                    );
                }
                Ok((camera.name.clone(), median_plate(&frames)))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok((!plates.is_empty()).then(|| Self {
            dir: out.to_path_buf(),
            numbering: Numbering::Plates {
                frames_dir: frames_dir.to_path_buf(),
                plates,
                threshold: settings.threshold,
            },
        }))
    }

    /// Whether the masks were estimated from the static plates rather than given.
    pub fn estimated(&self) -> bool {
        matches!(self.numbering, Numbering::Plates { .. })
    }

    /// The folder the masks come from.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The mask of an aligned frame's `view` of `camera`, if its file exists (estimated
    /// masks: made now, where the camera has a plate).
    pub fn for_view(&self, camera: &str, view: &View) -> anyhow::Result<Option<PathBuf>> {
        let path = match &self.numbering {
            Numbering::Aligned => self.dir.join(&view.file),
            Numbering::Simulator { fps, offsets } => {
                let Some(&(_, offset)) = offsets.iter().find(|(name, _)| name == camera) else {
                    return Ok(None);
                };
                let frame = ((view.timestamp_s - offset) * fps).round();
                if frame < 0.0 {
                    return Ok(None);
                }
                self.dir
                    .join(camera)
                    .join(format!("{:06}.png", frame as u64))
            }
            Numbering::Plates {
                frames_dir,
                plates,
                threshold,
            } => {
                let Some((_, plate)) = plates.iter().find(|(name, _)| name == camera) else {
                    return Ok(None);
                };
                let source = frames_dir.join(&view.file);
                let frame = read_frame(&source)?;
                if frame.dimensions() != plate.dimensions() {
                    bail!(
                        "{} is {:?} but the other frames of {camera} are {:?}; rerun the frames stage",
                        source.display(),
                        frame.dimensions(),
                        plate.dimensions()
                    );
                }
                let path = self.dir.join(&view.file);
                if let Some(dir) = path.parent() {
                    std::fs::create_dir_all(dir)
                        .with_context(|| format!("cannot create {}", dir.display()))?;
                }
                moving_pixels(&frame, plate, *threshold)
                    .to_grey()
                    .save(&path)
                    .with_context(|| format!("cannot write {}", path.display()))?;
                return Ok(Some(path));
            }
        };
        Ok(path.is_file().then_some(path))
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

/// An aligned frame, read for a plate or a mask.
fn read_frame(path: &Path) -> anyhow::Result<RgbImage> {
    Ok(image::open(path)
        .with_context(|| format!("cannot read the aligned frame {}", path.display()))?
        .to_rgb8())
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
            sim.for_view("cam1", &v).unwrap(),
            Some(sim.dir.join("cam1/000007.png"))
        );
        assert_eq!(sim.for_view("cam2", &v).unwrap(), None, "no sync offset");
        assert_eq!(
            sim.for_view("cam1", &view("cam1/000004.png", 0.9)).unwrap(),
            None,
            "no file"
        );
        touch(&sim.dir.join("heldout0/000002.png"));
        assert!(sim.for_simulated_image("heldout0", 2).is_some());

        let user = MaskSource {
            dir: tmp.path().join("masks"),
            numbering: Numbering::Aligned,
        };
        touch(&user.dir.join("cam1/000003.png"));
        assert_eq!(
            user.for_view("cam1", &v).unwrap(),
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
        let mut cameras = Vec::new();
        for cam in ["cam0", "cam1"] {
            let mut files = Vec::new();
            for k in 0..7u32 {
                let mut f = image::RgbImage::from_pixel(24, 10, image::Rgb([120, 120, 120]));
                if cam == "cam0" {
                    for y in 4..7 {
                        for x in 3 * k..3 * k + 3 {
                            f.put_pixel(x, y, image::Rgb([200, 30, 30]));
                        }
                    }
                }
                let file = format!("{cam}/{k:06}.png");
                let path = frames.join(&file);
                std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                f.save(&path).unwrap();
                files.push(file);
            }
            cameras.push(CameraFrames {
                name: cam.into(),
                files,
            });
        }
        let settings = PlateMasks {
            frames: 5,
            threshold: pointinit::plates::MOTION_THRESHOLD,
        };
        let out = tmp.path().join("plate_masks");
        let source = MaskSource::from_plates(&frames, &cameras, settings, &out)
            .unwrap()
            .unwrap();
        assert!(source.estimated());
        // Only the views asked for are estimated.
        assert!(!out.exists());
        let path = source
            .for_view("cam0", &view("cam0/000003.png", 0.0))
            .unwrap()
            .unwrap();
        assert_eq!(path, out.join("cam0/000003.png"));
        let mask = image::open(path).unwrap().to_luma8();
        // The square covers x 9..12, y 4..7; the mask is that grown by two pixels.
        for (x, y) in [(9, 4), (11, 6), (7, 2), (13, 8)] {
            assert_eq!(mask.get_pixel(x, y).0[0], 255, "({x}, {y})");
        }
        for (x, y) in [(6, 5), (14, 5), (10, 1), (2, 5), (20, 5)] {
            assert_eq!(mask.get_pixel(x, y).0[0], 0, "({x}, {y})");
        }
        assert_eq!(std::fs::read_dir(out.join("cam0")).unwrap().count(), 1);
        let still = source
            .for_view("cam1", &view("cam1/000003.png", 0.0))
            .unwrap()
            .unwrap();
        let still = image::open(still).unwrap().to_luma8();
        assert!(still.pixels().all(|p| p.0[0] == 0));
        // A camera without a plate has no masks.
        let other = view("cam2/000003.png", 0.0);
        assert_eq!(source.for_view("cam2", &other).unwrap(), None);
        // No plate frames, or no camera with frames: no estimate.
        let none = PlateMasks {
            frames: 0,
            ..settings
        };
        assert!(
            MaskSource::from_plates(&frames, &cameras, none, &out)
                .unwrap()
                .is_none()
        );
        let empty = [CameraFrames {
            name: "cam0".into(),
            files: Vec::new(),
        }];
        assert!(
            MaskSource::from_plates(&frames, &empty, settings, &out)
                .unwrap()
                .is_none()
        );
        // A frame of another size is named, in the plate and in a view.
        image::RgbImage::new(8, 8)
            .save(frames.join("cam1/000003.png"))
            .unwrap();
        let err = format!(
            "{:#}",
            source
                .for_view("cam1", &view("cam1/000003.png", 0.0))
                .unwrap_err()
        );
        assert!(
            err.contains("cam1/000003.png") && err.contains("rerun the frames stage"),
            "{err}"
        );
        let err = format!(
            "{:#}",
            MaskSource::from_plates(&frames, &cameras, settings, &out).unwrap_err()
        );
        assert!(
            err.contains("cam1") && err.contains("rerun the frames stage"),
            "{err}"
        );
    }
}
