//! The browser viewer of an export: the prebuilt web bundle (`viewer/dist`, built from
//! the `viewer/` npm project by `scripts/setup.sh`) copied next to per-timestep `.splat`
//! frames, per-camera colours and a `scene.json` that lists them with the training
//! cameras. The page (gsplat.js) opens at the first training camera, switches frames with
//! a time slider and cameras with buttons, and orbits with the mouse (docs/export.md).
//!
//! `.splat` rows (antimatter15's format, 32 bytes): position `3×f32`, linear scale
//! `3×f32`, RGBA8 (opacity = the slice's `sigmoid(o)·ω(t)`), rotation `(w, x, y, z)` as
//! `u8` (`q·128 + 128`). Every frame has the same rows in the same order, one per Gaussian
//! drawn at any viewer time ([`row_order`]), transparent where the frame does not draw it.
//! Viewer frames are put in a "viewer space": centred on the scene and rotated so that
//! the cameras' mean up direction is −y, the convention of gsplat's orbit controls; the
//! cameras in `scene.json` are given in it too. The PLY and `.splatv` exports stay in
//! world coordinates. Colours are the engine's ([`baked_rgb`]): the `.splat`'s seen from
//! the mean camera centre, the `NNNN.camK.rgb` files from each training camera.

use super::bake::Splat3d;
use super::splatv::baked_rgb;
use super::{ExportError, write_atomic};
use crate::CameraSet;
use crate::model::Gaussians;
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

/// Bytes of one `.splat` row.
pub const ROW_BYTES: usize = 32;

/// A row that draws nothing: at the origin, tiny, fully transparent, identity rotation.
pub const TRANSPARENT_ROW: [u8; ROW_BYTES] = {
    let mut row = [0u8; ROW_BYTES];
    let tiny = 1e-6f32.to_le_bytes();
    let mut k = 0;
    while k < 12 {
        row[12 + k] = tiny[k % 4];
        k += 1;
    }
    // RGBA (24..28) stays 0: transparent. Rotation (w, x, y, z) = (1, 0, 0, 0).
    row[28] = 255;
    row[29] = 128;
    row[30] = 128;
    row[31] = 128;
    row
};

/// Append one `.splat` row for `s` (world coordinates) in viewer space with colour `rgb`
/// (each in `[0, 1]`) and opacity `sigmoid(s.opacity_logit)` — the opacity of the slice,
/// which already carries the temporal weight `ω(t)`.
pub fn push_row(out: &mut Vec<u8>, s: &Splat3d, space: &ViewerSpace, rgb: [f64; 3]) {
    let p = space.point(DVec3::from_array(s.position.map(|v| v as f64)));
    let q = DQuat::from_xyzw(
        s.rotation[1] as f64,
        s.rotation[2] as f64,
        s.rotation[3] as f64,
        s.rotation[0] as f64,
    );
    let mut q = (space.rotation * q).normalize();
    if q.w < 0.0 {
        q = -q;
    }
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

/// The row order shared by every viewer frame: the Gaussians that appear in at least one
/// frame (`first_seen[i]`: where Gaussian `i` is in the first frame that draws it, `None`
/// if none does), sorted front to back as seen from `sort_from` (viewer space).
///
/// One order for all frames makes a frame switch a change of row contents only: the
/// page's depth order of the previous frame stays almost right until its sort worker has
/// sorted the new one, so playback does not flicker.
pub fn row_order(
    first_seen: &[Option<[f32; 3]>],
    space: &ViewerSpace,
    sort_from: DVec3,
) -> Vec<usize> {
    let mut order: Vec<(f64, usize)> = first_seen
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let p = space.point(DVec3::from_array(p.as_ref()?.map(|v| v as f64)));
            Some((p.distance_squared(sort_from), i))
        })
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    order.into_iter().map(|(_, i)| i).collect()
}

/// Encode one viewer frame as `.splat` rows in viewer space: row `r` is Gaussian
/// `order[r]` of `model` at model time `t` (`rows[i]`: Gaussian `i` baked at `t`),
/// [`TRANSPARENT_ROW`] where it is dropped at this time. The colour is the engine's colour
/// of the Gaussian at `t` seen from `view_from` (the DC colour when `None`). Every frame of
/// an export has the same number of rows (gsplat's sort worker keeps the buffer size it
/// first saw).
pub fn encode_frame(
    model: &Gaussians<f32>,
    rows: &[Option<Splat3d>],
    order: &[usize],
    t: f64,
    space: &ViewerSpace,
    view_from: Option<[f64; 3]>,
) -> Vec<u8> {
    let mut out = Vec::with_capacity(order.len() * ROW_BYTES);
    for &i in order {
        match rows.get(i).copied().flatten() {
            Some(s) => push_row(&mut out, &s, space, baked_rgb(model, i, t, view_from)),
            None => out.extend_from_slice(&TRANSPARENT_ROW),
        }
    }
    out
}

/// The colours of one viewer frame seen from one camera centre `eye`: RGB8 per row of
/// `order` (zero where the Gaussian is dropped). The page puts them in place of the
/// `.splat`'s colours while it shows that camera, so that a training camera shows the
/// engine's view-dependent colour rather than the colour seen from the mean camera.
pub fn encode_colours(
    model: &Gaussians<f32>,
    rows: &[Option<Splat3d>],
    order: &[usize],
    t: f64,
    eye: [f64; 3],
) -> Vec<u8> {
    let mut out = Vec::with_capacity(order.len() * 3);
    for &i in order {
        match rows.get(i).copied().flatten() {
            Some(_) => {
                let rgb = baked_rgb(model, i, t, Some(eye));
                out.extend(rgb.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8));
            }
            None => out.extend([0u8; 3]),
        }
    }
    out
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
    /// Gaussians drawn in this frame (the file has [`ViewerScene::rows`] rows).
    pub splats: usize,
    /// Per training camera (in [`ViewerScene::cameras`] order): the frame's colours seen
    /// from that camera, RGB8 per row ([`encode_colours`]).
    pub colours: Vec<String>,
}

/// A training camera in `scene.json`: the page opens at the first and can switch to any.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerCamera {
    pub name: String,
    /// Image size and pinhole intrinsics (the page fits the image into its canvas);
    /// written as the flat keys `width, height, fx, fy, cx, cy`.
    #[serde(flatten)]
    pub intrinsics: crate::Intrinsics,
    /// Camera centre in viewer space.
    pub position: [f64; 3],
    /// Camera-to-viewer-space rotation as a quaternion `(x, y, z, w)`; camera axes x
    /// right, y down, z forward (OpenCV, as gsplat's camera).
    pub rotation: [f64; 4],
}

impl ViewerCamera {
    /// An engine camera seen in viewer space.
    pub fn from_camera(cam: &crate::Camera, space: &ViewerSpace) -> Self {
        let c2w = cam.world_to_camera.rotation().transpose();
        let q = (space.rotation * DQuat::from_mat3(&c2w)).normalize();
        Self {
            name: cam.name.clone(),
            intrinsics: cam.intrinsics,
            position: space.point(cam.world_to_camera.centre()).to_array(),
            rotation: [q.x, q.y, q.z, q.w],
        }
    }
}

/// The rigid map of world coordinates into viewer space, `p_v = rotation · (p − centre)`,
/// in `scene.json` (the page needs it to show the world-space `.splatv`).
#[derive(Clone, Debug, Serialize)]
pub struct ViewerSpaceJson {
    pub centre: [f64; 3],
    /// `(x, y, z, w)`.
    pub rotation: [f64; 4],
}

/// `scene.json`: what the page loads.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerScene {
    /// Layout version of this file (2: training cameras, one row order for all frames;
    /// 3: the background).
    pub version: u32,
    pub frames: Vec<ViewerFrame>,
    /// Rows (32 bytes each) of every frame file.
    pub rows: usize,
    /// The training cameras, in the cameras' order; the page opens at `start_camera`.
    pub cameras: Vec<ViewerCamera>,
    pub start_camera: usize,
    /// Frames per second of playback.
    pub fps: f64,
    /// Model time span of the sequence, `[0, duration]` (the `.splatv` plays it as
    /// `[0, 1]`).
    pub duration: f64,
    /// RGB in `[0, 1]` the page draws behind the splats: the training background.
    pub background: [f32; 3],
    /// World → viewer space.
    pub space: ViewerSpaceJson,
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
