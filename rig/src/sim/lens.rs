//! From the rasteriser's pinhole canvas to the camera's pixels: supersampling and lens
//! distortion by inverse mapping (for each output sample: undistort → sample the canvas),
//! using `shared_types::Distortion` so the ground-truth cameras describe the images exactly.
//! Without distortion and supersampling the canvas *is* the image (no resampling at all).

use glam::{DVec2, Mat3, Vec3};
use rayon::prelude::*;
use shared_types::Camera;

use super::raster::{Rendered, View};

/// Largest canvas side relative to the image side (strong distortion needs a wider canvas).
const MAX_CANVAS_RATIO: f64 = 4.0;

/// Points along the border of a `width × height` image (pixel edges, `n` per side).
pub fn border_pixels(width: u32, height: u32, n: u32) -> Vec<DVec2> {
    let (w, h) = (width as f64, height as f64);
    let mut out = Vec::new();
    for k in 0..=n {
        let s = k as f64 / n as f64;
        out.extend([
            DVec2::new(s * w, 0.0),
            DVec2::new(s * w, h),
            DVec2::new(0.0, s * h),
            DVec2::new(w, s * h),
        ]);
    }
    out
}

/// Canvas coordinates of every sub-sample and of every pixel centre.
type SampleMap = (Vec<[f32; 2]>, Vec<[f32; 2]>);

/// How one camera's image is made from a pinhole canvas.
#[derive(Clone, Debug)]
pub struct LensPlan {
    pub view: View,
    width: usize,
    height: usize,
    ss: usize,
    /// For distorted cameras: canvas coordinates (continuous, pixel-centre at +0.5) of every
    /// sub-sample (`ss²` per pixel) and of every pixel centre.
    map: Option<SampleMap>,
}

impl LensPlan {
    /// The canvas for `camera` at `ss × ss` samples per pixel; `Err` names the problem.
    pub fn new(camera: &Camera, ss: u32) -> Result<LensPlan, String> {
        let k = &camera.intrinsics;
        let ssf = ss as f64;
        let (width, height) = (k.width as usize, k.height as usize);
        let r = camera.world_to_camera.rotation();
        let rotation = Mat3::from_cols_array(&r.to_cols_array().map(|v| v as f32));
        let translation = camera.world_to_camera.translation().as_vec3();
        if camera.distortion.is_none() {
            let view = View {
                rotation,
                translation,
                fx: (k.fx * ssf) as f32,
                fy: (k.fy * ssf) as f32,
                cx: (k.cx * ssf) as f32,
                cy: (k.cy * ssf) as f32,
                width: width * ss as usize,
                height: height * ss as usize,
            };
            return Ok(LensPlan {
                view,
                width,
                height,
                ss: ss as usize,
                map: None,
            });
        }
        // Bounding box of the undistorted border, in pinhole pixels of the same focal length.
        let d = camera.distortion;
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for p in border_pixels(k.width, k.height, 64) {
            let q = k.to_pixels(d.undistort(k.to_normalised(p)));
            if !q.is_finite() {
                return Err(format!(
                    "distortion cannot be inverted at pixel ({:.0}, {:.0})",
                    p.x, p.y
                ));
            }
            lo = lo.min(q);
            hi = hi.max(q);
        }
        lo -= DVec2::splat(2.0);
        hi += DVec2::splat(2.0);
        let size = (hi - lo) * ssf;
        if size.x > MAX_CANVAS_RATIO * width as f64 * ssf
            || size.y > MAX_CANVAS_RATIO * height as f64 * ssf
        {
            return Err(format!(
                "distortion widens the view to {:.0}×{:.0} pinhole pixels (over {MAX_CANVAS_RATIO}× the image); \
                 use a narrower field of view or weaker distortion",
                hi.x - lo.x,
                hi.y - lo.y
            ));
        }
        let view = View {
            rotation,
            translation,
            fx: (k.fx * ssf) as f32,
            fy: (k.fy * ssf) as f32,
            cx: ((k.cx - lo.x) * ssf) as f32,
            cy: ((k.cy - lo.y) * ssf) as f32,
            width: size.x.ceil() as usize,
            height: size.y.ceil() as usize,
        };
        Ok(LensPlan {
            view,
            width,
            height,
            ss: ss as usize,
            map: None,
        })
    }

    /// Build the inverse-distortion sample map (done once per camera; cameras are static).
    pub fn prepare(&mut self, camera: &Camera) {
        if camera.distortion.is_none() || self.map.is_some() {
            return;
        }
        let k = camera.intrinsics;
        let d = camera.distortion;
        let (fx, fy, cx, cy) = (
            self.view.fx as f64,
            self.view.fy as f64,
            self.view.cx as f64,
            self.view.cy as f64,
        );
        let ss = self.ss;
        let to_canvas = |p: DVec2| {
            let n = d.undistort(k.to_normalised(p));
            [(fx * n.x + cx) as f32, (fy * n.y + cy) as f32]
        };
        let w = self.width;
        let samples: Vec<[f32; 2]> = (0..self.height)
            .into_par_iter()
            .flat_map_iter(|j| {
                (0..w).flat_map(move |i| {
                    (0..ss * ss).map(move |s| {
                        let (a, b) = ((s % ss) as f64, (s / ss) as f64);
                        to_canvas(DVec2::new(
                            i as f64 + (a + 0.5) / ss as f64,
                            j as f64 + (b + 0.5) / ss as f64,
                        ))
                    })
                })
            })
            .collect();
        let centres: Vec<[f32; 2]> = (0..self.height)
            .into_par_iter()
            .flat_map_iter(|j| {
                (0..w).map(move |i| to_canvas(DVec2::new(i as f64 + 0.5, j as f64 + 0.5)))
            })
            .collect();
        self.map = Some((samples, centres));
    }

    /// The camera image (colour, depth, id) from a canvas rendered with `self.view`.
    pub fn resolve(&self, canvas: Rendered) -> Rendered {
        let (w, h, ss) = (self.width, self.height, self.ss);
        match &self.map {
            None if ss == 1 => canvas,
            None => {
                // Box filter over ss × ss samples; depth and id from the sample nearest the centre.
                let cw = canvas.width;
                let mid = ss / 2;
                let norm = 1.0 / (ss * ss) as f32;
                image_by_rows(w, h, |j, color, depth, id| {
                    for i in 0..w {
                        let mut acc = [0.0f32; 3];
                        for b in 0..ss {
                            for a in 0..ss {
                                let c = canvas.color[(j * ss + b) * cw + i * ss + a];
                                acc = [acc[0] + c[0], acc[1] + c[1], acc[2] + c[2]];
                            }
                        }
                        color[i] = acc.map(|v| v * norm);
                        let k = (j * ss + mid) * cw + i * ss + mid;
                        depth[i] = canvas.depth[k];
                        id[i] = canvas.id[k];
                    }
                })
            }
            Some((samples, centres)) => {
                let n = ss * ss;
                let norm = 1.0 / n as f32;
                image_by_rows(w, h, |j, color, depth, id| {
                    for i in 0..w {
                        let k = j * w + i;
                        let mut acc = [0.0f32; 3];
                        for s in &samples[k * n..(k + 1) * n] {
                            let c = bilinear(&canvas, s[0], s[1]);
                            acc = [acc[0] + c[0], acc[1] + c[1], acc[2] + c[2]];
                        }
                        color[i] = acc.map(|v| v * norm);
                        let [x, y] = centres[k];
                        let (ci, cj) = (x.floor() as isize, y.floor() as isize);
                        if ci >= 0
                            && cj >= 0
                            && (ci as usize) < canvas.width
                            && (cj as usize) < canvas.height
                        {
                            let c = cj as usize * canvas.width + ci as usize;
                            depth[i] = canvas.depth[c];
                            id[i] = canvas.id[c];
                        } else {
                            depth[i] = f32::INFINITY;
                        }
                    }
                })
            }
        }
    }
}

/// A `w × h` image (colour, depth, id all zero) whose rows `row(j, colour, depth, id)`
/// fills in parallel.
fn image_by_rows(
    w: usize,
    h: usize,
    row: impl Fn(usize, &mut [[f32; 3]], &mut [f32], &mut [u16]) + Sync + Send,
) -> Rendered {
    let mut out = Rendered {
        width: w,
        height: h,
        color: vec![[0.0; 3]; w * h],
        depth: vec![0.0; w * h],
        id: vec![0; w * h],
    };
    out.color
        .par_chunks_mut(w)
        .zip(out.depth.par_chunks_mut(w))
        .zip(out.id.par_chunks_mut(w))
        .enumerate()
        .for_each(|(j, ((color, depth), id))| row(j, color, depth, id));
    out
}

/// Bilinear sample of the canvas colour at continuous coordinates (centres at +0.5).
fn bilinear(c: &Rendered, x: f32, y: f32) -> [f32; 3] {
    let (x, y) = (x - 0.5, y - 0.5);
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (x - fx, y - fy);
    let at = |i: f32, j: f32| {
        let i = (i.max(0.0) as usize).min(c.width - 1);
        let j = (j.max(0.0) as usize).min(c.height - 1);
        Vec3::from_array(c.color[j * c.width + i])
    };
    let top = at(fx, fy).lerp(at(fx + 1.0, fy), tx);
    let bottom = at(fx, fy + 1.0).lerp(at(fx + 1.0, fy + 1.0), tx);
    top.lerp(bottom, ty).to_array()
}

#[cfg(test)]
mod tests {

    use glam::DVec2;
    use shared_types::Distortion;

    /// OpenCV's `projectPoints` radial-tangential model written out independently
    /// (docs.opencv.org, calib3d): x'' = x'(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x'y' + p2 (r² + 2x'²).
    fn opencv_reference(k1: f64, k2: f64, p1: f64, p2: f64, k3: f64, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        let radial = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// OpenCV fisheye (cv::fisheye::projectPoints): θ = atan(r),
    /// θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), x' = (θ_d / r) x.
    fn fisheye_reference(k: [f64; 4], x: f64, y: f64) -> (f64, f64) {
        let r = (x * x + y * y).sqrt();
        let th = r.atan();
        let t2 = th * th;
        let thd = th * (1.0 + k[0] * t2 + k[1] * t2 * t2 + k[2] * t2.powi(3) + k[3] * t2.powi(4));
        (x * thd / r, y * thd / r)
    }

    #[test]
    fn distortion_agrees_with_the_opencv_formulas_and_round_trips() {
        let (k1, k2, p1, p2, k3) = (-0.28, 0.09, 0.0012, -0.0008, -0.01);
        let d = Distortion::radial_tangential(k1, k2, p1, p2, k3);
        let f = Distortion::Fisheye {
            k1: 0.03,
            k2: -0.01,
            k3: 0.004,
            k4: -0.001,
        };
        for &(x, y) in &[(0.1, 0.05), (-0.4, 0.3), (0.55, -0.35), (-0.2, -0.6)] {
            let got = d.distort(DVec2::new(x, y));
            let want = opencv_reference(k1, k2, p1, p2, k3, x, y);
            assert!((got.x - want.0).abs() < 1e-14 && (got.y - want.1).abs() < 1e-14);
            let back = d.undistort(got);
            assert!((back - DVec2::new(x, y)).length() < 1e-10);
            let got = f.distort(DVec2::new(x, y));
            let want = fisheye_reference([0.03, -0.01, 0.004, -0.001], x, y);
            assert!((got.x - want.0).abs() < 1e-14 && (got.y - want.1).abs() < 1e-14);
            assert!((f.undistort(got) - DVec2::new(x, y)).length() < 1e-10);
        }
    }
}
