//! Camera pixel formats to the recorder's [`Frame`](crate::source::Frame) pixels: MJPEG,
//! YUYV, NV12, grey and packed RGB/BGR, named by their V4L2 FourCC. Shared by every live
//! source (V4L2, nokhwa); it does not talk to devices.

use crate::source::PixelLayout;

/// Why a camera buffer could not be converted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PixelError {
    /// The pixel format is not one we convert.
    #[error("pixel format {0} is not supported (supported: MJPG, YUYV, NV12, RGB3, BGR3, GREY)")]
    Unsupported(String),
    /// The buffer is shorter than the frame size says.
    #[error("{fourcc} buffer of {got} bytes for a {width}x{height} frame (needs {needs})")]
    Short {
        /// The pixel format.
        fourcc: String,
        /// Bytes received.
        got: usize,
        /// Bytes needed.
        needs: usize,
        /// Frame width.
        width: u32,
        /// Frame height.
        height: u32,
    },
    /// A compressed frame did not decode (a corrupt MJPEG frame).
    #[error("corrupt {fourcc} frame: {message}")]
    Corrupt {
        /// The pixel format.
        fourcc: String,
        /// The decoder's message.
        message: String,
    },
}

/// The FourCC as text (`MJPG`).
pub fn fourcc_text(fourcc: &[u8; 4]) -> String {
    String::from_utf8_lossy(fourcc).into_owned()
}

/// One BT.601 limited-range YCbCr sample to RGB8.
fn ycbcr_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = 1.164 * (f32::from(y) - 16.0);
    let d = f32::from(u) - 128.0;
    let e = f32::from(v) - 128.0;
    [c + 1.596 * e, c - 0.392 * d - 0.813 * e, c + 2.017 * d]
        .map(|x| x.round().clamp(0.0, 255.0) as u8)
}

/// YUYV 4:2:2 (BT.601, limited range) to packed RGB8; a short buffer leaves black pixels.
pub fn yuyv_to_rgb(data: &[u8], width: u32, height: u32) -> Vec<u8> {
    let n = (width * height) as usize;
    let mut out = Vec::with_capacity(3 * n);
    for q in data.chunks_exact(4).take(n / 2) {
        out.extend_from_slice(&ycbcr_to_rgb(q[0], q[1], q[3]));
        out.extend_from_slice(&ycbcr_to_rgb(q[2], q[1], q[3]));
    }
    out.resize(3 * n, 0);
    out
}

/// NV12 (a full-size Y plane, then interleaved half-size Cb/Cr; BT.601 limited range) to
/// packed RGB8. `data` must hold `w·h + 2·⌈w/2⌉·⌈h/2⌉` bytes.
pub fn nv12_to_rgb(data: &[u8], width: u32, height: u32) -> Vec<u8> {
    let (w, h) = (width as usize, height as usize);
    let chroma_row = w.div_ceil(2) * 2;
    let (luma, chroma) = data.split_at((w * h).min(data.len()));
    let mut out = Vec::with_capacity(3 * w * h);
    for y in 0..h {
        for x in 0..w {
            let l = luma.get(y * w + x).copied().unwrap_or(16);
            let c = (y / 2) * chroma_row + (x / 2) * 2;
            let u = chroma.get(c).copied().unwrap_or(128);
            let v = chroma.get(c + 1).copied().unwrap_or(128);
            out.extend_from_slice(&ycbcr_to_rgb(l, u, v));
        }
    }
    out
}

/// Bytes a frame of this format and size needs (`None` for compressed formats).
pub fn frame_bytes(fourcc: &[u8; 4], width: u32, height: u32) -> Option<usize> {
    let (w, h) = (width as usize, height as usize);
    match fourcc {
        b"YUYV" => Some(w.div_ceil(2) * 4 * h),
        b"NV12" => Some(w * h + w.div_ceil(2) * 2 * h.div_ceil(2)),
        b"RGB3" | b"BGR3" => Some(3 * w * h),
        b"GREY" => Some(w * h),
        _ => None,
    }
}

/// Converts one camera buffer of `fourcc` at `width × height` into the recorder's pixels
/// (RGB8, or Gray8 for a grey camera).
pub fn to_frame_pixels(
    fourcc: &[u8; 4],
    data: &[u8],
    width: u32,
    height: u32,
) -> Result<(PixelLayout, Vec<u8>), PixelError> {
    if let Some(needs) = frame_bytes(fourcc, width, height)
        && data.len() < needs
    {
        return Err(PixelError::Short {
            fourcc: fourcc_text(fourcc),
            got: data.len(),
            needs,
            width,
            height,
        });
    }
    let n = (width * height) as usize;
    match fourcc {
        b"MJPG" => {
            let img = image::load_from_memory_with_format(data, image::ImageFormat::Jpeg).map_err(
                |e| PixelError::Corrupt {
                    fourcc: fourcc_text(fourcc),
                    message: e.to_string(),
                },
            )?;
            if (img.width(), img.height()) != (width, height) {
                return Err(PixelError::Corrupt {
                    fourcc: fourcc_text(fourcc),
                    message: format!(
                        "decoded {}x{}, the camera announced {width}x{height}",
                        img.width(),
                        img.height()
                    ),
                });
            }
            Ok((PixelLayout::Rgb8, img.to_rgb8().into_raw()))
        }
        b"YUYV" => Ok((PixelLayout::Rgb8, yuyv_to_rgb(data, width, height))),
        b"NV12" => Ok((PixelLayout::Rgb8, nv12_to_rgb(data, width, height))),
        b"RGB3" => Ok((PixelLayout::Rgb8, data[..3 * n].to_vec())),
        b"BGR3" => Ok((
            PixelLayout::Rgb8,
            data[..3 * n]
                .chunks_exact(3)
                .flat_map(|p| [p[2], p[1], p[0]])
                .collect(),
        )),
        b"GREY" => Ok((PixelLayout::Gray8, data[..n].to_vec())),
        other => Err(PixelError::Unsupported(fourcc_text(other))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_converts_white_and_black() {
        assert_eq!(
            yuyv_to_rgb(&[235, 128, 16, 128], 2, 1),
            vec![255, 255, 255, 0, 0, 0]
        );
    }

    #[test]
    fn nv12_shares_chroma_between_four_pixels() {
        // 2×2 luma (white, black / black, white), one chroma pair: neutral.
        let data = [235, 16, 16, 235, 128, 128];
        assert_eq!(
            nv12_to_rgb(&data, 2, 2),
            vec![255, 255, 255, 0, 0, 0, 0, 0, 0, 255, 255, 255]
        );
        // A saturated red pixel: Y 81, Cb 90, Cr 240 (BT.601).
        let red = nv12_to_rgb(&[81, 90, 240], 1, 1);
        assert!(red[0] > 250 && red[1] < 5 && red[2] < 5, "{red:?}");
    }

    #[test]
    fn packed_and_grey_formats_keep_their_bytes() {
        let (layout, rgb) = to_frame_pixels(b"BGR3", &[1, 2, 3, 4, 5, 6], 2, 1).unwrap();
        assert_eq!((layout, rgb), (PixelLayout::Rgb8, vec![3, 2, 1, 6, 5, 4]));
        let (layout, grey) = to_frame_pixels(b"GREY", &[7, 8, 9], 3, 1).unwrap();
        assert_eq!((layout, grey), (PixelLayout::Gray8, vec![7, 8, 9]));
    }

    #[test]
    fn mjpeg_decodes_and_checks_its_size() {
        let img = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 40, 40]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&img)
            .unwrap();
        let (layout, rgb) = to_frame_pixels(b"MJPG", &jpeg, 16, 8).unwrap();
        assert_eq!((layout, rgb.len()), (PixelLayout::Rgb8, 16 * 8 * 3));
        assert!(rgb[0].abs_diff(200) < 6 && rgb[1].abs_diff(40) < 6);
        let err = to_frame_pixels(b"MJPG", &jpeg, 32, 8).unwrap_err();
        assert!(err.to_string().contains("announced 32x8"), "{err}");
        let err = to_frame_pixels(b"MJPG", &jpeg[..20], 16, 8).unwrap_err();
        assert!(matches!(err, PixelError::Corrupt { .. }), "{err}");
    }

    #[test]
    fn short_buffers_and_unknown_formats_are_errors() {
        let err = to_frame_pixels(b"YUYV", &[0; 6], 2, 2).unwrap_err();
        assert_eq!(
            err.to_string(),
            "YUYV buffer of 6 bytes for a 2x2 frame (needs 8)"
        );
        let err = to_frame_pixels(b"H264", &[0; 6], 2, 2).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("pixel format H264 is not supported")
        );
    }
}
