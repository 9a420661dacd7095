//! Cameras shared by every crate: OpenCV/COLMAP convention (x right, y down, z forward),
//! world-to-camera poses, intrinsics in pixels of the image they apply to, and the
//! lens-distortion models the capture side meets (OpenCV radial-tangential, fisheye).
//!
//! This module is plain geometry in `f64`; the rasteriser converts to `f32` itself.
//! It must not know about files other than its own JSON layout (`CameraSet`).

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics in pixels of an image of `width × height`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    /// Intrinsics for a horizontal field of view in degrees, principal point at the centre.
    pub fn from_hfov(width: u32, height: u32, hfov_deg: f64) -> Self {
        let fx = 0.5 * width as f64 / (0.5 * hfov_deg.to_radians()).tan();
        Self {
            width,
            height,
            fx,
            fy: fx,
            cx: 0.5 * width as f64,
            cy: 0.5 * height as f64,
        }
    }

    /// The same camera for an image resized to `width × height` (pixel-centre convention:
    /// a pixel's centre is at integer + 0.5).
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
        }
    }

    /// Normalised image coordinates (x/z, y/z) to pixels.
    pub fn to_pixels(&self, n: DVec2) -> DVec2 {
        DVec2::new(self.fx * n.x + self.cx, self.fy * n.y + self.cy)
    }

    /// Pixels to normalised image coordinates.
    pub fn to_normalised(&self, p: DVec2) -> DVec2 {
        DVec2::new((p.x - self.cx) / self.fx, (p.y - self.cy) / self.fy)
    }
}

/// Lens distortion, applied to normalised image coordinates.
///
/// In `cameras.json` a lens is `{"model": "opencv", "k1": …}`: the coefficients of the
/// rational / thin-prism / tilted-sensor terms are written only when they are not zero, and
/// read as zero when absent, so files of plain radial-tangential lenses look as they always
/// did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Distortion {
    /// An ideal pinhole: what the engine renders.
    #[default]
    None,
    /// OpenCV's full lens model (`cv::projectPoints` with 4, 5, 8, 12 or 14 coefficients
    /// `k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [τx τy]]]]`): radial with the rational
    /// denominator `1 + k4 r² + k5 r⁴ + k6 r⁶`, tangential `p1 p2`, thin prism `s1..s4`, and
    /// a tilted sensor `τx τy` (radians). COLMAP's `OPENCV` is `k1 k2 p1 p2`, its
    /// `FULL_OPENCV` `k1..k6 p1 p2`.
    Opencv {
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        #[serde(default)]
        k3: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        k4: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        k5: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        k6: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        s1: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        s2: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        s3: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        s4: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        tau_x: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        tau_y: f64,
    },
    /// OpenCV fisheye / COLMAP `OPENCV_FISHEYE` (equidistant with polynomial θ).
    Fisheye { k1: f64, k2: f64, k3: f64, k4: f64 },
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// OpenCV's tilted-sensor projection (`computeTiltProjectionMatrix`): the sensor rotated
/// by `tau_x` about x, then `tau_y` about y, and the point projected back along the
/// optical axis.
pub fn tilt_matrix(tau_x: f64, tau_y: f64) -> DMat3 {
    let (sx, cx) = tau_x.sin_cos();
    let (sy, cy) = tau_y.sin_cos();
    // Row-major as OpenCV writes them; glam takes columns, hence the transposes.
    let rot_x = DMat3::from_cols_array(&[1.0, 0.0, 0.0, 0.0, cx, sx, 0.0, -sx, cx]).transpose();
    let rot_y = DMat3::from_cols_array(&[cy, 0.0, -sy, 0.0, 1.0, 0.0, sy, 0.0, cy]).transpose();
    let rot_xy = rot_y * rot_x;
    let (r02, r12, r22) = (rot_xy.z_axis.x, rot_xy.z_axis.y, rot_xy.z_axis.z);
    let proj_z =
        DMat3::from_cols_array(&[r22, 0.0, -r02, 0.0, r22, -r12, 0.0, 0.0, 1.0]).transpose();
    proj_z * rot_xy
}

/// Number of OpenCV coefficients a distortion vector may have (`cv::projectPoints`).
pub const OPENCV_COEFFICIENT_COUNTS: [usize; 5] = [4, 5, 8, 12, 14];

impl Distortion {
    pub fn is_none(&self) -> bool {
        matches!(self, Distortion::None)
    }

    /// OpenCV radial-tangential with `k1 k2 p1 p2 k3` (no rational, thin-prism or tilt terms).
    pub fn radial_tangential(k1: f64, k2: f64, p1: f64, p2: f64, k3: f64) -> Self {
        Self::from_opencv_coefficients(&[k1, k2, p1, p2, k3]).expect("five coefficients")
    }

    /// The OpenCV model of a coefficient vector in OpenCV's order (`k1 k2 p1 p2 [k3 [k4 k5
    /// k6 [s1 s2 s3 s4 [τx τy]]]]`, 4, 5, 8, 12 or 14 numbers); `Err` names the accepted
    /// lengths. All-zero coefficients still give `Opencv` (callers decide if that is `None`).
    pub fn from_opencv_coefficients(c: &[f64]) -> Result<Self, String> {
        if !OPENCV_COEFFICIENT_COUNTS.contains(&c.len()) {
            return Err(format!(
                "{} distortion coefficients; OpenCV's model takes 4, 5, 8, 12 or 14 \
                 (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [τx τy]]]])",
                c.len()
            ));
        }
        let at = |i: usize| c.get(i).copied().unwrap_or(0.0);
        Ok(Distortion::Opencv {
            k1: at(0),
            k2: at(1),
            p1: at(2),
            p2: at(3),
            k3: at(4),
            k4: at(5),
            k5: at(6),
            k6: at(7),
            s1: at(8),
            s2: at(9),
            s3: at(10),
            s4: at(11),
            tau_x: at(12),
            tau_y: at(13),
        })
    }

    /// The coefficients as OpenCV takes them: `Opencv` in OpenCV's order, as short as the
    /// non-zero terms allow (5, 8, 12 or 14), `Fisheye` as `k1..k4`, none for a pinhole.
    pub fn coefficients(&self) -> Vec<f64> {
        match *self {
            Distortion::None => Vec::new(),
            Distortion::Opencv {
                k1,
                k2,
                p1,
                p2,
                k3,
                k4,
                k5,
                k6,
                s1,
                s2,
                s3,
                s4,
                tau_x,
                tau_y,
            } => {
                let all = [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y];
                let used = all.iter().rposition(|&c| c != 0.0).map_or(0, |i| i + 1);
                let len = [5, 8, 12, 14]
                    .into_iter()
                    .find(|&n| n >= used)
                    .unwrap_or(14);
                all[..len].to_vec()
            }
            Distortion::Fisheye { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
        }
    }

    /// Undistorted normalised coordinates (x/z, y/z) → distorted normalised coordinates,
    /// as `cv::projectPoints` / `cv::fisheye::projectPoints` compute them.
    pub fn distort(&self, n: DVec2) -> DVec2 {
        match *self {
            Distortion::None => n,
            Distortion::Opencv {
                k1,
                k2,
                p1,
                p2,
                k3,
                k4,
                k5,
                k6,
                s1,
                s2,
                s3,
                s4,
                tau_x,
                tau_y,
            } => {
                let (x, y) = (n.x, n.y);
                let r2 = x * x + y * y;
                let r4 = r2 * r2;
                let numerator = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let denominator = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6));
                let radial = numerator / denominator;
                let d = DVec2::new(
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4,
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r4,
                );
                if tau_x == 0.0 && tau_y == 0.0 {
                    return d;
                }
                let v = tilt_matrix(tau_x, tau_y) * DVec3::new(d.x, d.y, 1.0);
                let inv = if v.z != 0.0 { 1.0 / v.z } else { 1.0 };
                DVec2::new(v.x * inv, v.y * inv)
            }
            Distortion::Fisheye { k1, k2, k3, k4 } => {
                let r = n.length();
                if r < 1e-12 {
                    return n;
                }
                let th = r.atan();
                let th2 = th * th;
                let thd = th * (1.0 + th2 * (k1 + th2 * (k2 + th2 * (k3 + th2 * k4))));
                n * (thd / r)
            }
        }
    }

    /// Inverse of [`Distortion::distort`] by Newton iterations (Gauss–Newton on the 2D map
    /// with a numerical Jacobian); exact to ~1e-12 inside the lens's valid field.
    pub fn undistort(&self, d: DVec2) -> DVec2 {
        if self.is_none() {
            return d;
        }
        let mut n = d;
        for _ in 0..50 {
            let f = self.distort(n) - d;
            if f.length() < 1e-14 {
                break;
            }
            let h = 1e-7;
            let jx = (self.distort(n + DVec2::new(h, 0.0)) - self.distort(n - DVec2::new(h, 0.0)))
                / (2.0 * h);
            let jy = (self.distort(n + DVec2::new(0.0, h)) - self.distort(n - DVec2::new(0.0, h)))
                / (2.0 * h);
            let det = jx.x * jy.y - jy.x * jx.y;
            if det.abs() < 1e-18 {
                break;
            }
            let step = DVec2::new(
                (jy.y * f.x - jy.x * f.y) / det,
                (-jx.y * f.x + jx.x * f.y) / det,
            );
            n -= step;
        }
        n
    }
}

/// A rigid world-to-camera transform `x_cam = R · x_world + t`. `rotation` is row-major.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldToCamera {
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
}

impl WorldToCamera {
    pub const IDENTITY: Self = Self {
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
    };

    pub fn from_parts(rotation: DMat3, translation: DVec3) -> Self {
        let r = rotation.transpose(); // columns of the transpose are the rows
        Self {
            rotation: [
                r.x_axis.to_array(),
                r.y_axis.to_array(),
                r.z_axis.to_array(),
            ],
            translation: translation.to_array(),
        }
    }

    /// A camera at `eye` looking at `target`, with `up` pointing up in the image
    /// (image y points down, so the camera's y axis is −up projected).
    pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> Option<Self> {
        let z = (target - eye).try_normalize()?;
        let x = z.cross(up).try_normalize()?;
        let y = z.cross(x);
        let r = DMat3::from_cols(x, y, z).transpose();
        Some(Self::from_parts(r, -(r * eye)))
    }

    pub fn rotation(&self) -> DMat3 {
        DMat3::from_cols_array_2d(&self.rotation).transpose()
    }

    pub fn translation(&self) -> DVec3 {
        DVec3::from_array(self.translation)
    }

    pub fn apply(&self, p_world: DVec3) -> DVec3 {
        self.rotation() * p_world + self.translation()
    }

    /// Camera centre in world coordinates, `−Rᵀ t`.
    pub fn centre(&self) -> DVec3 {
        -(self.rotation().transpose() * self.translation())
    }

    pub fn inverse_apply(&self, p_cam: DVec3) -> DVec3 {
        self.rotation().transpose() * (p_cam - self.translation())
    }
}

/// One calibrated camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub name: String,
    pub intrinsics: Intrinsics,
    #[serde(default)]
    pub distortion: Distortion,
    pub world_to_camera: WorldToCamera,
}

impl Camera {
    /// Project a world point to pixel coordinates (with distortion) and its depth z.
    /// `None` when the point is not in front of the camera.
    pub fn project(&self, p_world: DVec3) -> Option<(DVec2, f64)> {
        let pc = self.world_to_camera.apply(p_world);
        if pc.z <= 1e-9 {
            return None;
        }
        let n = DVec2::new(pc.x / pc.z, pc.y / pc.z);
        Some((self.intrinsics.to_pixels(self.distortion.distort(n)), pc.z))
    }

    /// World-space ray direction (unit) through a pixel (distortion removed).
    pub fn pixel_ray(&self, pixel: DVec2) -> DVec3 {
        let n = self
            .distortion
            .undistort(self.intrinsics.to_normalised(pixel));
        (self.world_to_camera.rotation().transpose() * DVec3::new(n.x, n.y, 1.0)).normalize()
    }
}

/// A set of cameras as stored in `cameras.json` files (`groundtruth/cameras.json`,
/// `work/poses/cameras.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraSet {
    /// Format version of this file.
    pub version: u32,
    pub cameras: Vec<Camera>,
}

impl CameraSet {
    pub const VERSION: u32 = 1;

    pub fn new(cameras: Vec<Camera>) -> Self {
        Self {
            version: Self::VERSION,
            cameras,
        }
    }

    pub fn get(&self, name: &str) -> Option<&Camera> {
        self.cameras.iter().find(|c| c.name == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_puts_target_on_the_optical_axis() {
        let eye = DVec3::new(3.0, -1.0, 2.0);
        let target = DVec3::new(0.0, 0.5, 0.0);
        let w2c = WorldToCamera::look_at(eye, target, DVec3::Z).unwrap();
        let pc = w2c.apply(target);
        assert!(pc.x.abs() < 1e-12 && pc.y.abs() < 1e-12 && pc.z > 0.0);
        assert!((w2c.centre() - eye).length() < 1e-12);
        // "up" in the world is "up" (negative y) in the image.
        assert!(w2c.apply(target + DVec3::Z).y < 0.0);
        let r = w2c.rotation();
        assert!((r * r.transpose() - DMat3::IDENTITY).abs_diff_eq(DMat3::ZERO, 1e-12));
        assert!((r.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn distortion_round_trips() {
        let models = [
            Distortion::radial_tangential(-0.2, 0.05, 0.001, -0.002, 0.0),
            Distortion::from_opencv_coefficients(&[
                -0.2, 0.05, 0.001, -0.002, 0.01, 0.1, -0.02, 0.03, 1e-3, -2e-4, 5e-4, 1e-4, 0.02,
                -0.01,
            ])
            .unwrap(),
            Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: 0.0,
            },
        ];
        for d in models {
            for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4), (0.01, 0.6)] {
                let n = DVec2::new(x, y);
                let back = d.undistort(d.distort(n));
                assert!((back - n).length() < 1e-10, "{d:?} {n} -> {back}");
            }
        }
    }

    #[test]
    fn camera_set_json_round_trips() {
        let cam = Camera {
            name: "cam0".into(),
            intrinsics: Intrinsics::from_hfov(640, 480, 60.0),
            distortion: Distortion::radial_tangential(0.1, 0.0, 0.0, 0.0, 0.0),
            world_to_camera: WorldToCamera::look_at(
                DVec3::new(0.0, -3.0, 1.0),
                DVec3::ZERO,
                DVec3::Z,
            )
            .unwrap(),
        };
        let set = CameraSet::new(vec![cam]);
        let text = serde_json::to_string_pretty(&set).unwrap();
        let back: CameraSet = serde_json::from_str(&text).unwrap();
        assert_eq!(set, back);
    }
}
