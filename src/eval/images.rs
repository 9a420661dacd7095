//! Turning renders into images people look at: 8-bit RGB, alpha as grey, expected depth
//! through a colour map, error heat maps, side-by-side grids; PNG files written under a
//! temporary name and renamed.

use std::path::Path;

use image::codecs::png::PngEncoder;
use image::{GrayImage, ImageBuffer, ImageEncoder, Pixel, PixelWithColorType, Rgb, RgbImage};

use super::EvalError;
use crate::render::Rendered;

/// Absolute error (mean over channels) shown at the top of the heat-map colour scale.
pub const ERROR_SCALE: f32 = 0.25;

/// Alpha below which a pixel has no depth to show (drawn black).
pub const DEPTH_MIN_ALPHA: f32 = 0.5;

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Interleaved RGB floats in `[0, 1]` (clamped) to an 8-bit image.
pub fn rgb8_from(rgb: &[f32], width: u32, height: u32) -> RgbImage {
    let data: Vec<u8> = rgb.iter().map(|&v| to_u8(v)).collect();
    RgbImage::from_raw(width, height, data).unwrap_or_else(|| RgbImage::new(width, height))
}

/// The colour of a render as an 8-bit image.
pub fn rgb8(r: &Rendered) -> RgbImage {
    rgb8_from(&r.rgb, r.width, r.height)
}

/// Accumulated opacity as a grey image (white = opaque).
pub fn alpha8(r: &Rendered) -> GrayImage {
    let data: Vec<u8> = r.alpha.iter().map(|&v| to_u8(v)).collect();
    GrayImage::from_raw(r.width, r.height, data)
        .unwrap_or_else(|| GrayImage::new(r.width, r.height))
}

/// Expected depth `Σwz / α` of the pixels with `α ≥ DEPTH_MIN_ALPHA`.
fn expected_depths(r: &Rendered) -> impl Iterator<Item = Option<f32>> + '_ {
    r.depth.iter().zip(&r.alpha).map(|(&d, &a)| {
        let z = d / a;
        (a >= DEPTH_MIN_ALPHA && z.is_finite() && z > 0.0).then_some(z)
    })
}

/// The 2nd–98th percentile of the expected depth of covered pixels, or `None` when
/// nothing is covered. Used once per path so a colour means one depth in every frame.
pub fn depth_range(r: &Rendered) -> Option<(f32, f32)> {
    let mut z: Vec<f32> = expected_depths(r).flatten().collect();
    if z.is_empty() {
        return None;
    }
    z.sort_by(f32::total_cmp);
    let at = |q: f64| z[((z.len() - 1) as f64 * q).round() as usize];
    let (near, far) = (at(0.02), at(0.98));
    Some(if far > near {
        (near, far)
    } else {
        (near * 0.9, near * 1.1 + 1e-6)
    })
}

/// Expected depth through the turbo colour map: near is red, far is blue, uncovered
/// pixels black. Depths outside `range` are clamped.
pub fn depth_colour(r: &Rendered, range: (f32, f32)) -> RgbImage {
    let (near, far) = range;
    let span = (far - near).max(1e-12);
    let mut img = RgbImage::new(r.width, r.height);
    for (px, z) in img.pixels_mut().zip(expected_depths(r)) {
        if let Some(z) = z {
            let u = 1.0 - ((z - near) / span).clamp(0.0, 1.0);
            let c = colorous::TURBO.eval_continuous(u as f64);
            *px = Rgb([c.r, c.g, c.b]);
        }
    }
    img
}

/// Per-pixel mean absolute error through the inferno colour map, `[0, ERROR_SCALE]`.
pub fn error_heat_map(a: &[f32], b: &[f32], width: u32, height: u32) -> RgbImage {
    let mut img = RgbImage::new(width, height);
    for (px, (pa, pb)) in img
        .pixels_mut()
        .zip(a.chunks_exact(3).zip(b.chunks_exact(3)))
    {
        let e = (0..3).map(|c| (pa[c] - pb[c]).abs()).sum::<f32>() / 3.0;
        let c = colorous::INFERNO.eval_continuous((e / ERROR_SCALE).clamp(0.0, 1.0) as f64);
        *px = Rgb([c.r, c.g, c.b]);
    }
    img
}

/// Images of one height side by side.
pub fn side_by_side(parts: &[&RgbImage]) -> RgbImage {
    let height = parts.iter().map(|p| p.height()).max().unwrap_or(0);
    let width = parts.iter().map(|p| p.width()).sum();
    let mut out = RgbImage::new(width, height);
    let mut x0 = 0;
    for p in parts {
        for (x, y, px) in p.enumerate_pixels() {
            out.put_pixel(x0 + x, y, *px);
        }
        x0 += p.width();
    }
    out
}

/// Write bytes to `path` atomically (a temporary name beside it, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), EvalError> {
    let write_err = |source| EvalError::Write {
        path: path.to_path_buf(),
        source,
    };
    crate::atomic::write_atomic(path, bytes).map_err(write_err)
}

/// Encode an 8-bit image (RGB or grey) as PNG and write it atomically.
pub fn write_png<P>(path: &Path, img: &ImageBuffer<P, Vec<u8>>) -> Result<(), EvalError>
where
    P: Pixel<Subpixel = u8> + PixelWithColorType,
{
    let mut bytes = Vec::new();
    PngEncoder::new(&mut bytes)
        .write_image(img.as_raw(), img.width(), img.height(), P::COLOR_TYPE)
        .map_err(|source| EvalError::EncodeImage {
            path: path.to_path_buf(),
            source,
        })?;
    write_atomic(path, &bytes)
}
