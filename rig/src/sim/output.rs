//! Files of the capture directory other than videos: JSON, PNG/JPEG images and `.npy`
//! depth maps, each written to a temporary name and renamed when complete.

use std::path::Path;

use serde::Serialize;

use super::error::SimError;

/// Write `bytes` to `path` atomically (`shared_types::atomic`).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SimError> {
    shared_types::atomic::write_atomic(path, bytes).map_err(|e| SimError::write(path, e))
}

pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), SimError> {
    shared_types::atomic::write_json(path, value).map_err(|e| SimError::write(path, e))
}

/// An RGB8 image as PNG (lossless) or JPEG (`quality` 1–100), chosen by `jpeg_quality`.
pub fn write_rgb(
    path: &Path,
    width: u32,
    height: u32,
    rgb: &[u8],
    jpeg_quality: Option<u8>,
) -> Result<(), SimError> {
    let mut bytes = Vec::new();
    let img_err = |source| SimError::Image {
        path: path.to_path_buf(),
        source,
    };
    match jpeg_quality {
        Some(q) => {
            let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, q);
            image::ImageEncoder::write_image(
                enc,
                rgb,
                width,
                height,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(img_err)?;
        }
        None => {
            let enc = image::codecs::png::PngEncoder::new(&mut bytes);
            image::ImageEncoder::write_image(
                enc,
                rgb,
                width,
                height,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(img_err)?;
        }
    }
    write_atomic(path, &bytes)
}

/// A grey 8-bit PNG (masks).
pub fn write_gray_png(path: &Path, width: u32, height: u32, data: &[u8]) -> Result<(), SimError> {
    let mut bytes = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut bytes);
    image::ImageEncoder::write_image(enc, data, width, height, image::ExtendedColorType::L8)
        .map_err(|source| SimError::Image {
            path: path.to_path_buf(),
            source,
        })?;
    write_atomic(path, &bytes)
}

/// The bytes of a version-1.0 `.npy` file holding a little-endian float32 `height × width`
/// array in C order.
pub fn npy_f32(height: usize, width: usize, data: &[f32]) -> Vec<u8> {
    let mut header =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({height}, {width}), }}");
    // Magic (6) + version (2) + header length (2) + header + '\n' is a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + 4 * data.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Read back a float32 2-D `.npy` written by [`npy_f32`]: `(height, width, data)`.
pub fn read_npy_f32(bytes: &[u8]) -> Option<(usize, usize, Vec<f32>)> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return None;
    }
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(bytes.get(10..10 + hlen)?).ok()?;
    if !header.contains("'<f4'") || header.contains("'fortran_order': True") {
        return None;
    }
    let shape = header.split("'shape': (").nth(1)?.split(')').next()?;
    let dims: Vec<usize> = shape
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let [h, w] = dims[..] else { return None };
    let data: Vec<f32> = bytes[10 + hlen..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    (data.len() == h * w).then_some((h, w, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trips_with_an_aligned_header() {
        let data: Vec<f32> = (0..12).map(|v| v as f32 * 0.5).collect();
        let bytes = npy_f32(3, 4, &data);
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        assert_eq!(read_npy_f32(&bytes), Some((3, 4, data)));
    }
}
