//! Undistortion: a distorted camera + image → a pinhole camera + image, so the engine only
//! ever sees pinhole cameras. Happens exactly once, after the poses stage (see
//! `docs/poses.md`): build one [`UndistortMap`] per video camera and apply it to every frame.
//!
//! Written in Rust after OpenCV 4.6, which the tests hold it to (`undistort_opencv`): the
//! pinhole camera is `getOptimalNewCameraMatrix`'s (radial-tangential: the rectangles of a
//! 9×9 grid of border points undistorted with OpenCV's five fixed-point iterations) or
//! `fisheye::estimateNewCameraMatrixForUndistortRectify`'s (fisheye), the map is
//! `initUndistortRectifyMap`'s (float maps, from `shared_types::Distortion::distort`) and
//! the resampling is `remap`'s bilinear one (coordinates rounded to 1/32 px, 15-bit
//! fixed-point weights for 8-bit images; black outside the lens's view, edge pixels
//! replicated for [`Fit::ValidPixels`], whose rectangle overshoots the source by up to
//! ~0.2 px). No OpenCV is linked, so the engine's stages run where it is not installed.
//!
//! Pixel convention: our cameras put a pixel's centre at integer + 0.5 (COLMAP's and the
//! engine's); OpenCV puts it at the integer. The principal point is shifted by 0.5 on the way
//! into OpenCV's formulas and back on the way out; the tests pin this to < 0.05 px.

use glam::{DVec2, DVec3};
use image::{ImageBuffer, Pixel};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared_types::{Camera, Distortion, Intrinsics};

/// How the pinhole camera's field of view is chosen (OpenCV's `alpha` / `balance` 0 / 1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fit {
    /// Only pixels the lens saw: no black borders, the corners are cropped (`alpha = 0`).
    #[default]
    ValidPixels,
    /// Every source pixel kept: black borders where the lens saw nothing (`alpha = 1`).
    AllPixels,
    /// Same focal length and principal point as the distorted camera.
    KeepFocal,
}

#[derive(Clone, Debug, thiserror::Error)]
pub enum UndistortError {
    #[error(
        "image is {got_w}×{got_h} but camera {camera} is calibrated for {want_w}×{want_h}: resize the \
         frames to the working size first, or scale the camera with Intrinsics::scaled_to"
    )]
    SizeMismatch {
        camera: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    /// Intrinsics or coefficients no lens has (zero size, non-positive focal, NaN, …), or a
    /// lens so strong that no pinhole camera fits it.
    #[error(
        "cannot undistort camera {camera}: {reason}; check its intrinsics and distortion \
         coefficients in the poses stage's cameras.json"
    )]
    InvalidCamera { camera: String, reason: String },
}

/// A precomputed remap from one distorted camera to its pinhole twin (same size).
#[derive(Clone, Debug)]
pub struct UndistortMap {
    source: Camera,
    pinhole: Camera,
    /// Source x and y (OpenCV's pixel convention) of each output pixel, row-major, or why
    /// they could not be built (reported by [`UndistortMap::apply`]).
    maps: Result<Maps, UndistortError>,
}

#[derive(Clone, Debug)]
struct Maps {
    x: Vec<f32>,
    y: Vec<f32>,
    /// Edge pixels replicated for [`Fit::ValidPixels`] (its rectangle, from a 9×9 grid of
    /// border points, overshoots the source by a fraction of a pixel at a few edge pixels,
    /// which black would darken), else black outside.
    replicate: bool,
}

/// Refuse cameras no lens has before any formula sees them (they would give NaN maps).
fn check_camera(camera: &Camera) -> Result<(), UndistortError> {
    let k = &camera.intrinsics;
    let coefficients = camera.distortion.coefficients();
    let reason = if k.width < 2 || k.height < 2 {
        format!("its image is {}×{} pixels", k.width, k.height)
    } else if !(k.fx.is_finite() && k.fy.is_finite() && k.fx > 0.0 && k.fy > 0.0) {
        format!("its focal length ({}, {}) is not positive", k.fx, k.fy)
    } else if !(k.cx.is_finite() && k.cy.is_finite()) {
        format!("its principal point ({}, {}) is not finite", k.cx, k.cy)
    } else if !coefficients.iter().all(|c| c.is_finite()) {
        format!("its distortion coefficients {coefficients:?} are not finite")
    } else {
        return Ok(());
    };
    Err(invalid(camera, reason))
}

fn invalid(camera: &Camera, reason: String) -> UndistortError {
    UndistortError::InvalidCamera {
        camera: camera.name.clone(),
        reason,
    }
}

/// OpenCV's `undistortPoints` for its full lens model with the default criteria (five
/// fixed-point iterations, not run to convergence: the rectangles below depend on it):
/// pixel `p` (OpenCV's convention) of a camera with intrinsics `k` → normalised coordinates.
fn undistort_point_opencv(k: &Intrinsics, d: &Distortion, p: DVec2) -> DVec2 {
    let (x, y) = ((p.x - (k.cx - 0.5)) / k.fx, (p.y - (k.cy - 0.5)) / k.fy);
    if !matches!(d, Distortion::Opencv { .. }) {
        return d.undistort(DVec2::new(x, y));
    }
    // OpenCV's order, zeros for the terms the lens does not use.
    let mut c = [0.0; 14];
    let given = d.coefficients();
    c[..given.len()].copy_from_slice(&given);
    let [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y] = c;
    let start = if tau_x == 0.0 && tau_y == 0.0 {
        DVec2::new(x, y)
    } else {
        let v = shared_types::camera::tilt_matrix(tau_x, tau_y).inverse() * DVec3::new(x, y, 1.0);
        let inv = if v.z != 0.0 { 1.0 / v.z } else { 1.0 };
        DVec2::new(v.x * inv, v.y * inv)
    };
    let mut n = start;
    for _ in 0..5 {
        let r2 = n.x * n.x + n.y * n.y;
        let icdist =
            (1.0 + ((k6 * r2 + k5) * r2 + k4) * r2) / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2);
        if icdist < 0.0 {
            return DVec2::new(x, y);
        }
        let dx = 2.0 * p1 * n.x * n.y + p2 * (r2 + 2.0 * n.x * n.x) + s1 * r2 + s2 * r2 * r2;
        let dy = p1 * (r2 + 2.0 * n.y * n.y) + 2.0 * p2 * n.x * n.y + s3 * r2 + s4 * r2 * r2;
        n = DVec2::new((start.x - dx) * icdist, (start.y - dy) * icdist);
    }
    n
}

/// `getOptimalNewCameraMatrix` (no principal-point centring) for `alpha` 0 or 1: the
/// rectangle inside (alpha 0) or around (alpha 1) a 9×9 grid of the image's points
/// undistorted, in normalised coordinates, mapped onto the image. In `f32` where OpenCV
/// 4.6 is (its grid points and rectangles), so the result is OpenCV's to the last bits.
fn optimal_pinhole(k: &Intrinsics, d: &Distortion, alpha: f64) -> Intrinsics {
    const N: u32 = 9;
    let (mut ix0, mut ix1, mut iy0, mut iy1) = (f32::MIN, f32::MAX, f32::MIN, f32::MAX);
    let (mut ox0, mut ox1, mut oy0, mut oy1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
    for y in 0..N {
        for x in 0..N {
            let p = DVec2::new(
                f64::from(x as f32 * k.width as f32 / (N - 1) as f32),
                f64::from(y as f32 * k.height as f32 / (N - 1) as f32),
            );
            let n = undistort_point_opencv(k, d, p);
            let (nx, ny) = (n.x as f32, n.y as f32);
            ox0 = ox0.min(nx);
            ox1 = ox1.max(nx);
            oy0 = oy0.min(ny);
            oy1 = oy1.max(ny);
            if x == 0 {
                ix0 = ix0.max(nx);
            }
            if x == N - 1 {
                ix1 = ix1.min(nx);
            }
            if y == 0 {
                iy0 = iy0.max(ny);
            }
            if y == N - 1 {
                iy1 = iy1.min(ny);
            }
        }
    }
    let (w, h) = (f64::from(k.width), f64::from(k.height));
    let onto = |x0: f32, x1: f32, y0: f32, y1: f32| {
        // `int / float`: the focal lengths are divided in f32.
        let fx = f64::from((w - 1.0) as f32 / (x1 - x0));
        let fy = f64::from((h - 1.0) as f32 / (y1 - y0));
        [fx, fy, -fx * f64::from(x0), -fy * f64::from(y0)]
    };
    let inner = onto(ix0, ix1, iy0, iy1);
    let outer = onto(ox0, ox1, oy0, oy1);
    let m: Vec<f64> = (0..4)
        .map(|i| inner[i] * (1.0 - alpha) + outer[i] * alpha)
        .collect();
    Intrinsics {
        fx: m[0],
        fy: m[1],
        cx: m[2] + 0.5,
        cy: m[3] + 0.5,
        ..*k
    }
}

/// `fisheye::estimateNewCameraMatrixForUndistortRectify` with `R = I`: the edges' midpoints
/// undistorted, and the focal length between the one that fits all four inside (`balance`
/// 1) and the one that fills the image (`balance` 0), divided by `fov_scale`.
fn fisheye_pinhole(k: &Intrinsics, d: &Distortion, balance: f64, fov_scale: f64) -> Intrinsics {
    let (w, h) = (k.width as f64, k.height as f64);
    let aspect = k.fx / k.fy;
    let mut points: Vec<DVec2> = [(w / 2.0, 0.0), (w, h / 2.0), (w / 2.0, h), (0.0, h / 2.0)]
        .into_iter()
        .map(|(x, y)| {
            d.undistort(DVec2::new(
                (x - (k.cx - 0.5)) / k.fx,
                (y - (k.cy - 0.5)) / k.fy,
            ))
        })
        .collect();
    let mut centre = points.iter().copied().sum::<DVec2>() / 4.0;
    // As OpenCV does: x of the centre and y of the points scaled to an identity aspect.
    centre.x *= aspect;
    for p in &mut points {
        p.y *= aspect;
    }
    let (min, max) = points.iter().fold(
        (DVec2::splat(f64::MAX), DVec2::splat(f64::MIN)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let fs = [
        w * 0.5 / (centre.x - min.x),
        w * 0.5 / (max.x - centre.x),
        h * 0.5 * aspect / (centre.y - min.y),
        h * 0.5 * aspect / (max.y - centre.y),
    ];
    let fmin = fs.iter().copied().fold(f64::MAX, f64::min);
    let fmax = fs.iter().copied().fold(f64::MIN, f64::max);
    let mut f = balance * fmin + (1.0 - balance) * fmax;
    if fov_scale > 0.0 {
        f /= fov_scale;
    }
    let c = DVec2::new(w, h * aspect) * 0.5 - centre * f;
    Intrinsics {
        fx: f,
        fy: f / aspect,
        cx: c.x + 0.5,
        cy: c.y / aspect + 0.5,
        ..*k
    }
}

/// How far (as a factor ≥ 0 of the half-size) the source's corner pixels land from the
/// centre of the pinhole image `p`: > 1 means some corner is outside.
fn fisheye_corner_overflow(k: &Intrinsics, d: &Distortion, p: &Intrinsics) -> f64 {
    let (w, h) = (k.width as f64, k.height as f64);
    // OpenCV's estimate centres the pinhole image at (w/2, h/2) and fov_scale scales about it.
    let (hw, hh) = (0.5 * w, 0.5 * h);
    [
        (0.0, 0.0),
        (w - 1.0, 0.0),
        (0.0, h - 1.0),
        (w - 1.0, h - 1.0),
    ]
    .into_iter()
    .map(|(x, y)| {
        let n = d.undistort(k.to_normalised(DVec2::new(x + 0.5, y + 0.5)));
        p.to_pixels(n) - DVec2::splat(0.5)
    })
    .fold(0.0f64, |m, q| {
        m.max((q.x - hw).abs() / (hw - 0.5))
            .max((q.y - hh).abs() / (hh - 0.5))
    })
}

/// The pinhole intrinsics for `camera` and `fit`.
fn new_intrinsics(camera: &Camera, fit: Fit) -> Result<Intrinsics, UndistortError> {
    check_camera(camera)?;
    let k = &camera.intrinsics;
    let d = &camera.distortion;
    let new = match (fit, d) {
        (_, Distortion::None) | (Fit::KeepFocal, _) => *k,
        (_, Distortion::Opencv { .. }) => {
            optimal_pinhole(k, d, if fit == Fit::ValidPixels { 0.0 } else { 1.0 })
        }
        (Fit::ValidPixels, Distortion::Fisheye { .. }) => {
            // balance 0 maps the edges' midpoints onto the output's edges: no black border.
            fisheye_pinhole(k, d, 0.0, 1.0)
        }
        (_, Distortion::Fisheye { .. }) => {
            // balance 1 only looks at the edges' midpoints; widen it (fov_scale, which
            // scales about the image centre) until the source's corners are inside too.
            let p = fisheye_pinhole(k, d, 1.0, 1.0);
            let scale = fisheye_corner_overflow(k, d, &p);
            if scale > 1.0 {
                fisheye_pinhole(k, d, 1.0, scale)
            } else {
                p
            }
        }
    };
    let finite = [new.fx, new.fy, new.cx, new.cy]
        .iter()
        .all(|v| v.is_finite());
    if !(finite && new.fx > 0.0 && new.fy > 0.0) {
        return Err(invalid(
            camera,
            format!(
                "no pinhole camera fits its lens (focal length {:.4} / {:.4}, principal \
                 point {:.4} / {:.4})",
                new.fx, new.fy, new.cx, new.cy
            ),
        ));
    }
    Ok(new)
}

/// The pinhole camera [`UndistortMap::new`] would produce, without building the map
/// (the distorted camera's own intrinsics if its lens is refused).
pub fn pinhole_for(camera: &Camera, fit: Fit) -> Camera {
    pinhole_with(camera, new_intrinsics(camera, fit).ok())
}

/// `camera` made pinhole with intrinsics `new` (its own without).
fn pinhole_with(camera: &Camera, new: Option<Intrinsics>) -> Camera {
    Camera {
        intrinsics: new.unwrap_or(camera.intrinsics),
        distortion: Distortion::None,
        ..camera.clone()
    }
}

impl UndistortMap {
    /// Build the map for `camera` (its intrinsics must match the frames' size). A refused
    /// lens is kept as the error [`UndistortMap::apply`] returns.
    pub fn new(camera: &Camera, fit: Fit) -> Self {
        let new = new_intrinsics(camera, fit);
        let pinhole = pinhole_with(camera, new.as_ref().ok().copied());
        let maps = new.map(|_| {
            let (w, h) = (
                camera.intrinsics.width as usize,
                camera.intrinsics.height as usize,
            );
            let (mut x, mut y) = (vec![0f32; w * h], vec![0f32; w * h]);
            x.par_chunks_mut(w)
                .zip(y.par_chunks_mut(w))
                .enumerate()
                .for_each(|(row, (xs, ys))| {
                    for col in 0..w {
                        let p = DVec2::new(col as f64 + 0.5, row as f64 + 0.5);
                        let s = source_position(camera, &pinhole, p);
                        xs[col] = (s.x - 0.5) as f32;
                        ys[col] = (s.y - 0.5) as f32;
                    }
                });
            Maps {
                x,
                y,
                replicate: fit == Fit::ValidPixels,
            }
        });
        Self {
            source: camera.clone(),
            pinhole,
            maps,
        }
    }

    /// The distorted camera this map starts from.
    pub fn source(&self) -> &Camera {
        &self.source
    }

    /// The pinhole camera of the undistorted images (same name, pose and size).
    pub fn pinhole(&self) -> &Camera {
        &self.pinhole
    }

    /// Source position (pixel-centre convention) of output pixel position `p`, from the
    /// camera models (`shared_types::Distortion::distort`); the map stores it as `f32`.
    pub fn source_position(&self, p: DVec2) -> DVec2 {
        source_position(&self.source, &self.pinhole, p)
    }

    /// Undistort one image (`u8`, `u16` or `f32` samples, 1–4 channels) with OpenCV's
    /// bilinear `remap`; pixels the lens did not see are 0 (none with [`Fit::ValidPixels`]).
    pub fn apply<P, S>(
        &self,
        image: &ImageBuffer<P, Vec<S>>,
    ) -> Result<ImageBuffer<P, Vec<S>>, UndistortError>
    where
        P: Pixel<Subpixel = S> + Send + Sync,
        S: Sample,
    {
        let (w, h) = (self.source.intrinsics.width, self.source.intrinsics.height);
        if image.dimensions() != (w, h) {
            return Err(UndistortError::SizeMismatch {
                camera: self.source.name.clone(),
                got_w: image.width(),
                got_h: image.height(),
                want_w: w,
                want_h: h,
            });
        }
        let maps = self.maps.as_ref().map_err(Clone::clone)?;
        let channels = P::CHANNEL_COUNT as usize;
        let mut out = vec![S::ZERO; image.as_raw().len()];
        if !out.is_empty() {
            remap(
                image.as_raw(),
                &mut out,
                (w as usize, h as usize),
                channels,
                maps,
            );
        }
        Ok(ImageBuffer::from_raw(w, h, out).expect("same size as the input"))
    }
}

/// Where output pixel position `p` of `pinhole` is in `source`'s image (pixel-centre
/// convention).
fn source_position(source: &Camera, pinhole: &Camera, p: DVec2) -> DVec2 {
    let n = pinhole.intrinsics.to_normalised(p);
    source.intrinsics.to_pixels(source.distortion.distort(n))
}

/// Fraction bits of a remap coordinate (OpenCV's `INTER_BITS`: 1/32 px).
const INTER_BITS: u32 = 5;
const INTER_TAB_SIZE: i32 = 1 << INTER_BITS;

/// OpenCV's bilinear `remap` of the `channels`-channel `size` image `src` into `dst`.
fn remap<S: Sample>(src: &[S], dst: &mut [S], size: (usize, usize), channels: usize, maps: &Maps) {
    let (w, h) = (size.0 as i64, size.1 as i64);
    let row_len = size.0 * channels;
    dst.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(row, out)| {
            for (col, pixel) in out.chunks_exact_mut(channels).enumerate() {
                let i = row * size.0 + col;
                // OpenCV rounds each coordinate to 1/32 px (cvRound: ties to even).
                let qx = (maps.x[i] * INTER_TAB_SIZE as f32).round_ties_even() as i64;
                let qy = (maps.y[i] * INTER_TAB_SIZE as f32).round_ties_even() as i64;
                let (sx, sy) = (qx >> INTER_BITS, qy >> INTER_BITS);
                let mask = INTER_TAB_SIZE as i64 - 1;
                let weights = S::weights((qx & mask) as u32, (qy & mask) as u32);
                if sx >= 0 && sx + 1 < w && sy >= 0 && sy + 1 < h {
                    let o = (sy * w + sx) as usize * channels;
                    for (c, value) in pixel.iter_mut().enumerate() {
                        let at = o + c;
                        let v = [
                            src[at],
                            src[at + channels],
                            src[at + row_len],
                            src[at + row_len + channels],
                        ];
                        *value = S::blend(v, &weights);
                    }
                    continue;
                }
                if !maps.replicate && (sx >= w || sx + 1 < 0 || sy >= h || sy + 1 < 0) {
                    pixel.fill(S::ZERO);
                    continue;
                }
                // At the border: neighbours outside are the edge pixel (replicate) or black.
                let at = |x: i64, y: i64| -> Option<usize> {
                    if maps.replicate {
                        let (x, y) = (x.clamp(0, w - 1), y.clamp(0, h - 1));
                        Some((y * w + x) as usize * channels)
                    } else {
                        ((0..w).contains(&x) && (0..h).contains(&y))
                            .then(|| (y * w + x) as usize * channels)
                    }
                };
                let corners = [
                    at(sx, sy),
                    at(sx + 1, sy),
                    at(sx, sy + 1),
                    at(sx + 1, sy + 1),
                ];
                for (c, value) in pixel.iter_mut().enumerate() {
                    let v = corners.map(|o| o.map_or(S::ZERO, |o| src[o + c]));
                    *value = S::blend(v, &weights);
                }
            }
        });
}

/// Pixel sample types [`UndistortMap::apply`] handles (`u8`, `u16`, `f32`), blended as
/// OpenCV's `remap` blends them.
pub trait Sample: image::Primitive + Send + Sync {
    /// Black.
    const ZERO: Self;
    /// Bilinear weights of the fractions `fx / 32`, `fy / 32`, in this type's arithmetic.
    type Weights: Copy;
    fn weights(fx: u32, fy: u32) -> Self::Weights;
    /// The neighbours `v` (top left, top right, bottom left, bottom right) blended.
    fn blend(v: [Self; 4], w: &Self::Weights) -> Self;
}

/// OpenCV's bilinear weights of fractions `fx / 32`, `fy / 32` (`initInterTab2D`), as `f32`.
fn float_weights(fx: u32, fy: u32) -> [f32; 4] {
    let (x, y) = (fx as f32 / 32.0, fy as f32 / 32.0);
    [(1.0 - y) * (1.0 - x), (1.0 - y) * x, y * (1.0 - x), y * x]
}

impl Sample for u8 {
    const ZERO: Self = 0;
    /// 15-bit fixed point (`INTER_REMAP_COEF_BITS`): `(a/32)·(b/32)·2¹⁵ = 32·a·b`, exact.
    type Weights = [i32; 4];
    fn weights(fx: u32, fy: u32) -> [i32; 4] {
        let (x, y) = (fx as i32, fy as i32);
        [
            32 * (32 - x) * (32 - y),
            32 * x * (32 - y),
            32 * (32 - x) * y,
            32 * x * y,
        ]
    }
    fn blend(v: [Self; 4], w: &[i32; 4]) -> Self {
        let sum = i32::from(v[0]) * w[0]
            + i32::from(v[1]) * w[1]
            + i32::from(v[2]) * w[2]
            + i32::from(v[3]) * w[3];
        ((sum + (1 << 14)) >> 15).clamp(0, 255) as u8
    }
}

impl Sample for u16 {
    const ZERO: Self = 0;
    type Weights = [f32; 4];
    fn weights(fx: u32, fy: u32) -> [f32; 4] {
        float_weights(fx, fy)
    }
    fn blend(v: [Self; 4], w: &[f32; 4]) -> Self {
        let sum = f32::from(v[0]) * w[0]
            + f32::from(v[1]) * w[1]
            + f32::from(v[2]) * w[2]
            + f32::from(v[3]) * w[3];
        sum.round_ties_even().clamp(0.0, 65535.0) as u16
    }
}

impl Sample for f32 {
    const ZERO: Self = 0.0;
    type Weights = [f32; 4];
    fn weights(fx: u32, fy: u32) -> [f32; 4] {
        float_weights(fx, fy)
    }
    fn blend(v: [Self; 4], w: &[f32; 4]) -> Self {
        v[0] * w[0] + v[1] * w[1] + v[2] * w[2] + v[3] * w[3]
    }
}

/// Undistort one image of `camera`: the pinhole camera and the undistorted image.
pub fn undistort_image<P, S>(
    camera: &Camera,
    image: &ImageBuffer<P, Vec<S>>,
    fit: Fit,
) -> Result<(Camera, ImageBuffer<P, Vec<S>>), UndistortError>
where
    P: Pixel<Subpixel = S> + Send + Sync,
    S: Sample,
{
    let map = UndistortMap::new(camera, fit);
    let out = map.apply(image)?;
    Ok((map.pinhole, out))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::looking_at;
    use glam::DVec3;

    fn cam(d: Distortion) -> Camera {
        let intrinsics = Intrinsics::from_hfov(320, 240, 80.0);
        Camera {
            distortion: d,
            ..looking_at("c", intrinsics, DVec3::new(0.0, -3.0, 1.0), DVec3::ZERO)
        }
    }

    #[test]
    fn pinhole_and_distorted_cameras_see_world_points_where_the_map_says() {
        for d in [
            Distortion::radial_tangential(-0.25, 0.07, 1e-3, -5e-4, 0.0),
            Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: 0.0,
            },
        ] {
            for fit in [Fit::ValidPixels, Fit::AllPixels, Fit::KeepFocal] {
                let c = cam(d);
                let map = UndistortMap::new(&c, fit);
                assert!(map.pinhole().distortion.is_none());
                assert_eq!(map.pinhole(), &pinhole_for(&c, fit));
                for p in [
                    DVec3::new(0.3, 0.2, 0.5),
                    DVec3::new(-0.8, 0.5, 1.2),
                    DVec3::ZERO,
                ] {
                    let (out, _) = map.pinhole().project(p).unwrap();
                    let (src, _) = c.project(p).unwrap();
                    assert!(
                        (map.source_position(out) - src).length() < 1e-9,
                        "{d:?} {fit:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn valid_pixels_fit_leaves_no_holes_and_all_pixels_keeps_the_corners() {
        let c = cam(Distortion::radial_tangential(-0.3, 0.08, 0.0, 0.0, 0.0));
        let img = image::RgbImage::from_pixel(320, 240, image::Rgb([200, 100, 50]));
        let (_, inner) = undistort_image(&c, &img, Fit::ValidPixels).unwrap();
        let holes = inner.pixels().filter(|p| p.0 == [0, 0, 0]).count();
        assert!(holes <= 320 * 240 / 500, "{holes} black pixels");
        let (pin, outer) = undistort_image(&c, &img, Fit::AllPixels).unwrap();
        assert!(outer.pixels().filter(|p| p.0 == [0, 0, 0]).count() > 1000);
        // Barrel distortion: the "all pixels" pinhole is wider (shorter focal length).
        assert!(pin.intrinsics.fx < c.intrinsics.fx);
        let wrong = image::RgbImage::new(100, 100);
        assert!(matches!(
            UndistortMap::new(&c, Fit::ValidPixels).apply(&wrong),
            Err(UndistortError::SizeMismatch { .. })
        ));
    }
}
