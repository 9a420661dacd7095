//! Image sizes of an imported calibration against the capture's: the intrinsics of a
//! calibration made at one size, for the video it must describe and then for the working
//! size of that camera's aligned frames. Each camera has its own sizes.
//!
//! - Same size: unchanged.
//! - Codec padding: a calibration a few pixels larger than the video, up to the next
//!   multiple of 8 or 16 on the right and/or bottom (H.264/HEVC code 1080 rows as 1088, and
//!   a tool that reads the coded size calibrates at 1088). The extra pixels are a crop: the
//!   principal point and focal lengths are unchanged, only the size shrinks. Logged.
//! - Same aspect ratio (up to one pixel of rounding): a resize, intrinsics scaled.
//! - Anything else is an error naming both sizes and the calibration file: scaling a
//!   different aspect ratio would silently stretch the lens.

use std::path::Path;

use shared_types::Intrinsics;

use super::error::PosesError;

/// How a calibration's size relates to a video's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SizeRelation {
    /// The same size.
    Same,
    /// The calibration is the video plus codec padding at the right/bottom: crop it.
    CodecPadding,
    /// The same aspect ratio at another resolution: scale it.
    Resized,
    /// Neither: the calibration does not describe this video.
    Different,
}

/// `n` rounded up to a multiple of `m`.
fn round_up(n: u32, m: u32) -> u32 {
    n.div_ceil(m) * m
}

/// How a calibration made at `calibrated` (width, height) relates to a video of `video`.
pub fn size_relation(calibrated: (u32, u32), video: (u32, u32)) -> SizeRelation {
    if calibrated == video {
        return SizeRelation::Same;
    }
    let padded = |c: u32, v: u32| c == v || c == round_up(v, 8) || c == round_up(v, 16);
    if padded(calibrated.0, video.0) && padded(calibrated.1, video.1) {
        return SizeRelation::CodecPadding;
    }
    let (cw, ch) = (f64::from(calibrated.0), f64::from(calibrated.1));
    let (vw, vh) = (f64::from(video.0), f64::from(video.1));
    // Scaling by either side's ratio must land on the other side within a pixel.
    if (ch * vw / cw - vh).abs() <= 1.0 && (cw * vh / ch - vw).abs() <= 1.0 {
        SizeRelation::Resized
    } else {
        SizeRelation::Different
    }
}

/// The intrinsics of `camera`'s calibration (`calibrated`, from the file `file`) for its
/// video of size `video`, then scaled to the frames' `working` size.
pub fn fit_intrinsics(
    camera: &str,
    calibrated: &Intrinsics,
    file: &Path,
    video: (u32, u32),
    working: (u32, u32),
) -> Result<Intrinsics, PosesError> {
    let size = (calibrated.width, calibrated.height);
    let at_video = match size_relation(size, video) {
        SizeRelation::Same => *calibrated,
        SizeRelation::CodecPadding => {
            tracing::info!(
                "camera {camera}: the calibration {} is for {}×{}, the video is {}×{}: the extra \
                 {} column(s) and {} row(s) are codec padding, cropped (principal point unchanged)",
                file.display(),
                size.0,
                size.1,
                video.0,
                video.1,
                size.0 - video.0,
                size.1 - video.1
            );
            Intrinsics {
                width: video.0,
                height: video.1,
                ..*calibrated
            }
        }
        SizeRelation::Resized => calibrated.scaled_to(video.0, video.1),
        SizeRelation::Different => {
            return Err(PosesError::CalibrationSize {
                camera: camera.to_string(),
                file: file.to_path_buf(),
                calibrated: size,
                video,
            });
        }
    };
    Ok(at_video.scaled_to(working.0, working.1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_are_the_same_padded_resized_or_different() {
        use SizeRelation::*;
        assert_eq!(size_relation((1920, 1080), (1920, 1080)), Same);
        // H.264 codes 1080 rows (or columns) as 1088 (a multiple of 16).
        assert_eq!(size_relation((1088, 1920), (1080, 1920)), CodecPadding);
        assert_eq!(size_relation((1920, 1088), (1920, 1080)), CodecPadding);
        // A multiple of 8: 852 → 856.
        assert_eq!(size_relation((856, 480), (852, 480)), CodecPadding);
        assert_eq!(size_relation((3840, 2160), (1920, 1080)), Resized);
        // Rounded working sizes stay a resize.
        assert_eq!(size_relation((1280, 720), (853, 480)), Resized);
        // 1088×1920 is not a resize of 1080×1920 (0.7 % off), nor padding of a smaller video.
        assert_eq!(size_relation((1088, 1920), (540, 960)), Different);
        assert_eq!(size_relation((1280, 720), (1080, 1920)), Different);
        assert_eq!(size_relation((1920, 1104), (1920, 1080)), Different);
        // Padding is added, never removed.
        assert_eq!(size_relation((1080, 1920), (1088, 1920)), Different);
    }

    #[test]
    fn padding_is_a_crop_and_a_resize_scales() {
        let k = Intrinsics {
            width: 1088,
            height: 1920,
            fx: 1676.4,
            fy: 1674.8,
            cx: 543.5,
            cy: 960.9,
        };
        let file = Path::new("Calib_scene.toml");
        let at_video = fit_intrinsics("cam0", &k, file, (1080, 1920), (1080, 1920)).unwrap();
        assert_eq!(at_video, Intrinsics { width: 1080, ..k });
        // Then to the working size: isotropic (540/1080 = 960/1920).
        let working = fit_intrinsics("cam0", &k, file, (1080, 1920), (540, 960)).unwrap();
        assert_eq!((working.width, working.height), (540, 960));
        assert!((working.fx - k.fx * 0.5).abs() < 1e-12 && (working.fy - k.fy * 0.5).abs() < 1e-12);
        assert!((working.cx - k.cx * 0.5).abs() < 1e-12 && (working.cy - k.cy * 0.5).abs() < 1e-12);
        let e = fit_intrinsics("cam2", &k, file, (1280, 720), (960, 540)).unwrap_err();
        let text = e.to_string();
        for part in ["cam2", "1088×1920", "1280×720", "Calib_scene.toml"] {
            assert!(text.contains(part), "{part}: {text}");
        }
    }
}
