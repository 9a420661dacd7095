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
        Self { width, height, fx, fy: fx, cx: 0.5 * width as f64, cy: 0.5 * height as f64 }
    }

    /// The same camera for an image resized to `width × height` (pixel-centre convention:
    /// a pixel's centre is at integer + 0.5).
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self { width, height, fx: self.fx * sx, fy: self.fy * sy, cx: self.cx * sx, cy: self.cy * sy }
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Distortion {
    /// An ideal pinhole: what the engine renders.
    #[default]
    None,
    /// OpenCV / COLMAP `OPENCV` (+ `k3` of FULL_OPENCV): radial-tangential.
    Opencv { k1: f64, k2: f64, p1: f64, p2: f64, #[serde(default)] k3: f64 },
    /// OpenCV fisheye / COLMAP `OPENCV_FISHEYE` (equidistant with polynomial θ).
    Fisheye { k1: f64, k2: f64, k3: f64, k4: f64 },
}

impl Distortion {
    pub fn is_none(&self) -> bool {
        matches!(self, Distortion::None)
    }

    /// Undistorted normalised coordinates (x/z, y/z) → distorted normalised coordinates.
    pub fn distort(&self, n: DVec2) -> DVec2 {
        match *self {
            Distortion::None => n,
            Distortion::Opencv { k1, k2, p1, p2, k3 } => {
                let (x, y) = (n.x, n.y);
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                DVec2::new(
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
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
            let jx = (self.distort(n + DVec2::new(h, 0.0)) - self.distort(n - DVec2::new(h, 0.0))) / (2.0 * h);
            let jy = (self.distort(n + DVec2::new(0.0, h)) - self.distort(n - DVec2::new(0.0, h))) / (2.0 * h);
            let det = jx.x * jy.y - jy.x * jx.y;
            if det.abs() < 1e-18 {
                break;
            }
            let step = DVec2::new((jy.y * f.x - jy.x * f.y) / det, (-jx.y * f.x + jx.x * f.y) / det);
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
    pub const IDENTITY: Self =
        Self { rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0; 3] };

    pub fn from_parts(rotation: DMat3, translation: DVec3) -> Self {
        let r = rotation.transpose(); // columns of the transpose are the rows
        Self {
            rotation: [r.x_axis.to_array(), r.y_axis.to_array(), r.z_axis.to_array()],
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
        let n = self.distortion.undistort(self.intrinsics.to_normalised(pixel));
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
        Self { version: Self::VERSION, cameras }
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
            Distortion::Opencv { k1: -0.2, k2: 0.05, p1: 0.001, p2: -0.002, k3: 0.0 },
            Distortion::Fisheye { k1: 0.05, k2: -0.01, k3: 0.002, k4: 0.0 },
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
            distortion: Distortion::Opencv { k1: 0.1, k2: 0.0, p1: 0.0, p2: 0.0, k3: 0.0 },
            world_to_camera: WorldToCamera::look_at(DVec3::new(0.0, -3.0, 1.0), DVec3::ZERO, DVec3::Z)
                .unwrap(),
        };
        let set = CameraSet::new(vec![cam]);
        let text = serde_json::to_string_pretty(&set).unwrap();
        let back: CameraSet = serde_json::from_str(&text).unwrap();
        assert_eq!(set, back);
    }
}
