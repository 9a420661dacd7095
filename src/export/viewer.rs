//! The browser viewer of an export: the prebuilt web bundle (`viewer/dist`, built from
//! the `viewer/` npm project by `scripts/setup.sh`) copied next to per-timestep `.splat`
//! frames and a `scene.json` that lists them. The page (gsplat.js) switches frames with
//! a time slider and orbits with the mouse.
//!
//! `.splat` rows (antimatter15's format, 32 bytes): position `3×f32`, linear scale
//! `3×f32`, RGBA8, rotation `(w, x, y, z)` as `u8` (`q·128 + 128`). Viewer frames are put
//! in a "viewer space": centred on the scene and rotated so that the cameras' mean up
//! direction is −y, the convention of gsplat's orbit controls. The PLY and `.splatv`
//! exports stay in world coordinates.

use super::bake::Frame3d;
use super::{ExportError, write_atomic};
use crate::CameraSet;
use glam::{DMat3, DQuat, DVec3};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Environment variable that points at a built viewer bundle (a folder with `index.html`).
pub const VIEWER_DIST_ENV: &str = "SPLAT4D_VIEWER_DIST";

/// Find the built viewer bundle: `$SPLAT4D_VIEWER_DIST`, then `viewer/dist` beside the
/// executable or in one of its ancestor folders (a checkout's `target/…/` binaries), then
/// `viewer/dist` in this crate's source tree (tests, `cargo run`).
pub fn find_viewer_bundle() -> Result<PathBuf, ExportError> {
    let mut tried = Vec::new();
    if let Some(p) = std::env::var_os(VIEWER_DIST_ENV) {
        tried.push(PathBuf::from(p));
    }
    if let Ok(exe) = std::env::current_exe() {
        for dir in exe.ancestors().skip(1) {
            tried.push(dir.join("viewer").join("dist"));
        }
    }
    tried.push(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("viewer")
            .join("dist"),
    );
    tried
        .iter()
        .find(|d| d.join("index.html").is_file())
        .cloned()
        .ok_or_else(|| ExportError::ViewerBundleMissing {
            looked_in: tried.last().cloned().unwrap_or_default(),
        })
}

/// Rigid transform from world to viewer space: `p_v = rotation · (p − centre)`.
#[derive(Clone, Copy, Debug)]
pub struct ViewerSpace {
    pub centre: DVec3,
    pub rotation: DQuat,
}

impl ViewerSpace {
    /// Centre = point closest to all camera optical axes (or `fallback_centre`); up = the
    /// cameras' mean up vector (−y of each camera), mapped to −y.
    pub fn from_cameras(cameras: &CameraSet, fallback_centre: DVec3) -> Self {
        let mut up = DVec3::ZERO;
        let mut a = DMat3::ZERO;
        let mut b = DVec3::ZERO;
        for c in &cameras.cameras {
            let r = c.world_to_camera.rotation();
            let row = |k: usize| DVec3::new(r.col(0)[k], r.col(1)[k], r.col(2)[k]);
            up -= row(1);
            // Least squares point nearest to the optical axis lines.
            let d = row(2);
            let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            a += p;
            b += p * c.world_to_camera.centre();
        }
        let centre = if cameras.cameras.len() >= 2 && a.determinant().abs() > 1e-9 {
            a.inverse() * b
        } else {
            fallback_centre
        };
        let rotation = match up.try_normalize() {
            Some(u) => DQuat::from_rotation_arc(u, DVec3::NEG_Y),
            None => DQuat::IDENTITY,
        };
        Self { centre, rotation }
    }

    pub fn point(&self, p: DVec3) -> DVec3 {
        self.rotation * (p - self.centre)
    }
}

/// Encode a baked frame as `.splat` rows in viewer space, colour seen from `view_from`.
///
/// Rows are sorted front to back as seen from `sort_from` (viewer space), the order
/// gsplat draws before its sort worker first answers; the frame is padded with
/// transparent splats to `pad_to` rows, because gsplat's sort worker keeps the buffers
/// of the first frame it saw and cannot take a larger one later.
pub fn encode_splat(
    frame: &Frame3d,
    space: &ViewerSpace,
    view_from: Option<[f64; 3]>,
    sort_from: DVec3,
    pad_to: usize,
) -> Vec<u8> {
    let mut out = Vec::with_capacity(frame.splats.len().max(pad_to) * 32);
    let c0 = crate::math::sh::SH_C0;
    let mut order: Vec<(f64, usize)> = frame
        .splats
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let p = space.point(DVec3::from_array(s.position.map(|v| v as f64)));
            (p.distance_squared(sort_from), i)
        })
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    for s in order.iter().map(|&(_, i)| &frame.splats[i]) {
        let p = space.point(DVec3::from_array(s.position.map(|v| v as f64)));
        let rgb = match view_from {
            Some(eye) => splat_colour(s, frame, eye),
            None => s.sh[0].map(|v| 0.5 + c0 * v as f64),
        };
        let q = DQuat::from_xyzw(
            s.rotation[1] as f64,
            s.rotation[2] as f64,
            s.rotation[3] as f64,
            s.rotation[0] as f64,
        );
        let q = (space.rotation * q).normalize();
        for v in p.to_array() {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
        for v in s.log_scale {
            out.extend_from_slice(&v.exp().to_le_bytes());
        }
        let alpha = crate::math::numerics::sigmoid(s.opacity_logit as f64);
        for v in [rgb[0], rgb[1], rgb[2], alpha] {
            out.push((v.clamp(0.0, 1.0) * 255.0).round() as u8);
        }
        for v in [q.w, q.x, q.y, q.z] {
            out.push((v * 128.0 + 128.0).round().clamp(0.0, 255.0) as u8);
        }
    }
    // Transparent, tiny padding rows at the origin.
    let mut pad = [0u8; 32];
    for k in 0..3 {
        pad[12 + 4 * k..16 + 4 * k].copy_from_slice(&1e-6f32.to_le_bytes());
    }
    pad[28] = 255;
    pad[29..32].fill(128);
    while out.len() < pad_to * 32 {
        out.extend_from_slice(&pad);
    }
    out
}

fn splat_colour(s: &super::bake::Splat3d, frame: &Frame3d, eye: [f64; 3]) -> [f64; 3] {
    use crate::model::ColourDegrees;
    let flat: Vec<f64> = s.sh.iter().flat_map(|c| c.map(|v| v as f64)).collect();
    let m = s.position.map(|v| v as f64);
    let rgb = crate::math::sh::colour(&crate::math::sh::ColourInput {
        mean: [m[0], m[1], m[2], frame.t],
        coeffs: &flat,
        capacity: ColourDegrees {
            spatial: 3,
            temporal: 0,
        },
        active: ColourDegrees {
            spatial: frame.sh_degree.min(3),
            temporal: 0,
        },
        camera_centre: eye,
        t: frame.t,
        period: 1.0,
    });
    rgb.map(|v| v.clamp(0.0, 1.0))
}

/// One frame entry of `scene.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerFrame {
    /// File name relative to the viewer folder.
    pub file: String,
    /// Model time.
    pub t: f64,
    /// Capture time in seconds.
    pub seconds: f64,
    pub splats: usize,
}

/// `scene.json`: what the page loads.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerScene {
    pub frames: Vec<ViewerFrame>,
    /// Initial camera position in viewer space (orbit target is the origin).
    pub camera_position: [f64; 3],
    /// Vertical field of view of the first camera in degrees (for the initial zoom).
    pub fov_y_deg: f64,
    /// Frames per second of playback.
    pub fps: f64,
}

/// Copy the bundle's files (not recursive beyond one level of folders) into `dest`.
pub fn copy_bundle(bundle: &Path, dest: &Path) -> Result<usize, ExportError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ExportError::Io { path, source }
    };
    std::fs::create_dir_all(dest).map_err(io(dest))?;
    let mut n = 0;
    for entry in std::fs::read_dir(bundle).map_err(io(bundle))? {
        let entry = entry.map_err(io(bundle))?;
        let from = entry.path();
        let to = dest.join(entry.file_name());
        if from.is_dir() {
            n += copy_bundle(&from, &to)?;
        } else {
            let bytes = std::fs::read(&from).map_err(io(&from))?;
            write_atomic(&to, &bytes)?;
            n += 1;
        }
    }
    Ok(n)
}
