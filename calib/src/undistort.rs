//! Undistortion: a distorted camera + image → a pinhole camera + image, so the engine only
//! ever sees pinhole cameras. Happens exactly once, after the poses stage (see
//! `docs/poses.md`): build one [`UndistortMap`] per video camera and apply it to every frame.
//!
//! Implemented in Rust (exact distortion models from `splat4d::Distortion`, bilinear
//! sampling, rayon over rows) rather than with OpenCV's `initUndistortRectifyMap`/`remap`:
//! the `opencv` crate's bindings add minutes of cold build time on a 2-core machine for two
//! functions; the maths is the same (OpenCV's `getOptimalNewCameraMatrix` rectangles).
//!
//! Pixel convention: a pixel's centre is at integer + 0.5 (COLMAP's and the engine's).

use glam::DVec2;
use image::{ImageBuffer, Pixel};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use splat4d::{Camera, Distortion, Intrinsics};

/// How the pinhole camera's field of view is chosen (OpenCV's `alpha` 0 / 1).
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

#[derive(Debug, thiserror::Error)]
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
}

/// A precomputed remap from one distorted camera to its pinhole twin (same size).
#[derive(Clone, Debug)]
pub struct UndistortMap {
    source: Camera,
    pinhole: Camera,
    /// For each output pixel, row-major: where and how to sample the source.
    map: Vec<Tap>,
}

/// A bilinear tap: the top-left source pixel index, the steps to its right and lower
/// neighbours (0 at the image edge), and the weights of those neighbours.
#[derive(Clone, Copy, Debug)]
struct Tap {
    /// `u32::MAX`: outside the source image.
    index: u32,
    right: u32,
    down: u32,
    wx: f32,
    wy: f32,
}

impl Tap {
    const OUTSIDE: Tap = Tap {
        index: u32::MAX,
        right: 0,
        down: 0,
        wx: 0.0,
        wy: 0.0,
    };

    /// The tap for source position `(sx, sy)` in index space (pixel centre at integer).
    fn at(sx: f64, sy: f64, w: u32, h: u32) -> Tap {
        let inside = sx >= -0.5 && sy >= -0.5 && sx <= w as f64 - 0.5 && sy <= h as f64 - 0.5;
        if !inside || !sx.is_finite() || !sy.is_finite() {
            return Tap::OUTSIDE;
        }
        let (xc, yc) = (sx.clamp(0.0, (w - 1) as f64), sy.clamp(0.0, (h - 1) as f64));
        let (x0, y0) = (xc.floor() as u32, yc.floor() as u32);
        Tap {
            index: y0 * w + x0,
            right: u32::from(x0 + 1 < w),
            down: if y0 + 1 < h { w } else { 0 },
            wx: (xc - x0 as f64) as f32,
            wy: (yc - y0 as f64) as f32,
        }
    }
}

/// The pinhole camera [`UndistortMap::new`] would produce, without building the map.
pub fn pinhole_for(camera: &Camera, fit: Fit) -> Camera {
    let intr = camera.intrinsics;
    let new_intr = match (fit, camera.distortion) {
        (_, Distortion::None) | (Fit::KeepFocal, _) => intr,
        (Fit::ValidPixels | Fit::AllPixels, d) => {
            let (inner, outer) = undistorted_bounds(&intr, &d);
            let [x0, y0, x1, y1] = if fit == Fit::ValidPixels {
                inner
            } else {
                outer
            };
            let (w, h) = (intr.width as f64, intr.height as f64);
            let fx = w / (x1 - x0);
            let fy = h / (y1 - y0);
            if fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0 {
                Intrinsics {
                    fx,
                    fy,
                    cx: -x0 * fx,
                    cy: -y0 * fy,
                    ..intr
                }
            } else {
                intr
            }
        }
    };
    Camera {
        intrinsics: new_intr,
        distortion: Distortion::None,
        ..camera.clone()
    }
}

/// Inner and outer rectangles `[x0, y0, x1, y1]` (normalised coordinates) of the image
/// border after removing distortion.
fn undistorted_bounds(intr: &Intrinsics, d: &Distortion) -> ([f64; 4], [f64; 4]) {
    let (w, h) = (intr.width as f64, intr.height as f64);
    let n = 64;
    let undist = |x: f64, y: f64| d.undistort(intr.to_normalised(DVec2::new(x, y)));
    let mut inner = [
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::INFINITY,
    ];
    let mut outer = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let (left, right) = (undist(0.0, t * h), undist(w, t * h));
        let (top, bottom) = (undist(t * w, 0.0), undist(t * w, h));
        inner[0] = inner[0].max(left.x);
        inner[2] = inner[2].min(right.x);
        inner[1] = inner[1].max(top.y);
        inner[3] = inner[3].min(bottom.y);
        for p in [left, right, top, bottom] {
            outer[0] = outer[0].min(p.x);
            outer[1] = outer[1].min(p.y);
            outer[2] = outer[2].max(p.x);
            outer[3] = outer[3].max(p.y);
        }
    }
    (inner, outer)
}

impl UndistortMap {
    /// Build the map for `camera` (its intrinsics must match the frames' size).
    pub fn new(camera: &Camera, fit: Fit) -> Self {
        let pinhole = pinhole_for(camera, fit);
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let src = camera.intrinsics;
        let dst = pinhole.intrinsics;
        let d = camera.distortion;
        let mut map = vec![Tap::OUTSIDE; w as usize * h as usize];
        map.par_chunks_mut(w.max(1) as usize)
            .enumerate()
            .for_each(|(y, row)| {
                for (x, m) in row.iter_mut().enumerate() {
                    let n = dst.to_normalised(DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
                    let p = src.to_pixels(d.distort(n)) - DVec2::splat(0.5);
                    *m = Tap::at(p.x, p.y, w, h);
                }
            });
        Self {
            source: camera.clone(),
            pinhole,
            map,
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

    /// Source position (pixel-centre convention) of output pixel position `p`.
    pub fn source_position(&self, p: DVec2) -> DVec2 {
        let n = self.pinhole.intrinsics.to_normalised(p);
        self.source
            .intrinsics
            .to_pixels(self.source.distortion.distort(n))
    }

    /// Undistort one image (any `u8` or `f32` pixel type) by bilinear sampling; pixels the
    /// lens did not see are 0.
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
        let c = P::CHANNEL_COUNT as usize;
        let src = image.as_raw();
        let mut out = vec![S::from_f32(0.0); src.len()];
        let row_len = w as usize * c;
        out.par_chunks_mut(row_len.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                let taps = &self.map[y * w as usize..(y + 1) * w as usize];
                for (out_px, tap) in row.chunks_exact_mut(c).zip(taps) {
                    if tap.index == u32::MAX {
                        continue;
                    }
                    let i00 = tap.index as usize * c;
                    let i01 = i00 + tap.right as usize * c;
                    let i10 = i00 + tap.down as usize * c;
                    let i11 = i10 + tap.right as usize * c;
                    let (wx, wy) = (tap.wx, tap.wy);
                    let (p00, p01) = (&src[i00..i00 + c], &src[i01..i01 + c]);
                    let (p10, p11) = (&src[i10..i10 + c], &src[i11..i11 + c]);
                    for k in 0..c {
                        let top = p00[k].to_f32() + (p01[k].to_f32() - p00[k].to_f32()) * wx;
                        let bottom = p10[k].to_f32() + (p11[k].to_f32() - p10[k].to_f32()) * wx;
                        out_px[k] = S::from_f32(top + (bottom - top) * wy);
                    }
                }
            });
        Ok(ImageBuffer::from_raw(w, h, out).expect("same size as the input"))
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

/// Pixel sample types [`UndistortMap::apply`] handles: `u8` (rounded, clamped) and `f32`.
pub trait Sample: image::Primitive + Send + Sync {
    fn to_f32(self) -> f32;
    fn from_f32(v: f32) -> Self;
}

impl Sample for u8 {
    fn to_f32(self) -> f32 {
        self as f32
    }
    fn from_f32(v: f32) -> Self {
        v.round().clamp(0.0, 255.0) as u8
    }
}

impl Sample for u16 {
    fn to_f32(self) -> f32 {
        self as f32
    }
    fn from_f32(v: f32) -> Self {
        v.round().clamp(0.0, 65535.0) as u16
    }
}

impl Sample for f32 {
    fn to_f32(self) -> f32 {
        self
    }
    fn from_f32(v: f32) -> Self {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use splat4d::WorldToCamera;

    fn cam(d: Distortion) -> Camera {
        Camera {
            name: "c".into(),
            intrinsics: Intrinsics::from_hfov(320, 240, 80.0),
            distortion: d,
            world_to_camera: WorldToCamera::look_at(
                DVec3::new(0.0, -3.0, 1.0),
                DVec3::ZERO,
                DVec3::Z,
            )
            .unwrap(),
        }
    }

    #[test]
    fn pinhole_and_distorted_cameras_see_world_points_where_the_map_says() {
        for d in [
            Distortion::Opencv {
                k1: -0.25,
                k2: 0.07,
                p1: 1e-3,
                p2: -5e-4,
                k3: 0.0,
            },
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
        let c = cam(Distortion::Opencv {
            k1: -0.3,
            k2: 0.08,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        });
        let img = image::RgbImage::from_pixel(320, 240, image::Rgb([200, 100, 50]));
        let (_, inner) = undistort_image(&c, &img, Fit::ValidPixels).unwrap();
        let holes = inner.pixels().filter(|p| p.0 == [0, 0, 0]).count();
        assert!(holes <= 320 * 240 / 500, "{holes} black pixels");
        let (pin, outer) = undistort_image(&c, &img, Fit::AllPixels).unwrap();
        assert!(outer.pixels().filter(|p| p.0 == [0, 0, 0]).count() > 1000);
        // Barrel distortion: the "all pixels" pinhole is wider (shorter focal length).
        assert!(pin.intrinsics.fx < c.intrinsics.fx);
        let wrong = image::RgbImage::new(100, 100);
        assert!(
            UndistortMap::new(&c, Fit::ValidPixels)
                .apply(&wrong)
                .is_err()
        );
    }
}
