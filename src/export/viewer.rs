//! The browser viewer of an export: the prebuilt web bundle (`viewer/dist`, built from
//! the `viewer/` npm project by `scripts/setup.sh`) copied next to the whole 4D model in
//! one compact file (`model.4dgs`, [`super::web4d`]) and a `scene.json` that describes
//! the clip and the training cameras. The page slices every Gaussian at the playback time
//! on the GPU with the engine's formulas and evaluates its colour from the harmonics for
//! the viewpoint shown: nothing is baked per frame or per camera (docs/export.md).
//!
//! Everything is in the capture's world coordinates; cameras are OpenCV (x right, y
//! down, z forward). `splatv.html` in the same bundle plays the export's `.splatv` with
//! gsplat.js, a third-party player (a check that the file plays there).

use super::web4d::{Segment, encode_segments};
use super::{ExportError, write_atomic};
use crate::CameraSet;
use crate::model::{ColourDegrees, Gaussians, TimeMapping};
use crate::render::backdrop::Backdrop;
use glam::{DMat3, DVec3};
use image::ImageEncoder;
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

/// The point nearest to every camera's optical axis (least squares), or `fallback` when
/// the axes do not pin one down (fewer than two cameras, parallel axes).
pub fn look_centre(cameras: &CameraSet, fallback: DVec3) -> DVec3 {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for c in &cameras.cameras {
        let r = c.world_to_camera.rotation();
        let d = DVec3::new(r.col(0)[2], r.col(1)[2], r.col(2)[2]);
        let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * c.world_to_camera.centre();
    }
    if cameras.cameras.len() >= 2 && a.determinant().abs() > 1e-9 {
        a.inverse() * b
    } else {
        fallback
    }
}

/// The cameras' mean up direction (their −y axes), unit; `−z` when they give none.
pub fn mean_up(cameras: &CameraSet) -> DVec3 {
    let up: DVec3 = cameras
        .cameras
        .iter()
        .map(|c| {
            let r = c.world_to_camera.rotation();
            -DVec3::new(r.col(0)[1], r.col(1)[1], r.col(2)[1])
        })
        .sum();
    up.try_normalize().unwrap_or(DVec3::NEG_Z)
}

/// A training camera in `scene.json`: the page opens at the first and can switch to any.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerCamera {
    pub name: String,
    /// Image size and pinhole intrinsics (the page fits the image into its canvas);
    /// written as the flat keys `width, height, fx, fy, cx, cy`.
    #[serde(flatten)]
    pub intrinsics: crate::Intrinsics,
    /// World to camera, `x_cam = rotation · x + translation` (rows; OpenCV axes).
    #[serde(flatten)]
    pub pose: crate::WorldToCamera,
}

/// The model file entry of `scene.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerModel {
    /// File name relative to the viewer folder.
    pub file: String,
    /// Its size in bytes (the page shows loading progress against it).
    pub bytes: usize,
    /// Gaussians in it.
    pub gaussians: usize,
    /// Colour degrees it carries.
    pub degrees: ColourDegrees,
}

/// A time segment's model file in `scene.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerSegment {
    /// File name relative to the viewer folder.
    pub file: String,
    pub bytes: usize,
    pub gaussians: usize,
    /// The model times at which any of its Gaussians can be drawn: the page has it
    /// loaded whenever the playhead is inside.
    pub reach: [f64; 2],
}

/// `scene.json`: what the page loads.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerScene {
    /// Layout version of this file (5: the native 4D model, in time segments).
    pub version: u32,
    /// The Gaussians drawn throughout (the whole model when there are no segments).
    pub model: ViewerModel,
    /// The rest of the model in time segments, in time order (empty for a short clip).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub segments: Vec<ViewerSegment>,
    /// The export's model times: the page steps through them (`,` / `.`, `?frame=N`).
    pub times: Vec<f64>,
    /// Seconds ↔ model time (playback runs at the capture's pace).
    pub time: TimeMapping,
    /// The training cameras, in the cameras' order; the page opens at `start_camera`.
    pub cameras: Vec<ViewerCamera>,
    pub start_camera: usize,
    /// The point the cameras look at (orbiting turns about it) and the world's up.
    pub centre: [f64; 3],
    pub up: [f64; 3],
    /// RGB in `[0, 1]` the page draws behind the splats: the training background.
    pub background: [f32; 3],
    /// The learned backdrop, drawn instead of `background` when the model has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub backdrop: Option<ViewerBackdrop>,
}

/// `scene.json`'s backdrop: a sphere and its texture (`file`, equirectangular, longitude
/// along x from `axes[0]` towards `axes[1]`, the top row along `axes[2]`; see
/// `render::backdrop`).
#[derive(Clone, Debug, Serialize)]
pub struct ViewerBackdrop {
    pub file: String,
    pub centre: [f64; 3],
    pub radius: f64,
    pub axes: [[f64; 3]; 3],
}

/// Write the backdrop's texture (its pyramid summed, 8 bits) as `dir/backdrop.png`.
fn write_backdrop(backdrop: &Backdrop, dir: &Path) -> Result<ViewerBackdrop, ExportError> {
    let baked = backdrop.baked();
    let (w, h) = (baked.width as u32, baked.width as u32 / 2);
    let bytes: Vec<u8> = baked
        .texels
        .as_flattened()
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let file = "backdrop.png";
    let path = dir.join(file);
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&bytes, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| ExportError::Io {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
    write_atomic(&path, &png)?;
    Ok(ViewerBackdrop {
        file: file.into(),
        centre: backdrop.centre.to_array(),
        radius: backdrop.radius,
        axes: backdrop.axes.map(|a| a.to_array()),
    })
}

/// Write `dir` (the viewer folder): the bundle, `model.4dgs` for the span of `times`
/// (splats below `opts.min_opacity` left out; for a clip longer than 1.5 ×
/// `opts.segment_seconds`, the static scene, and `model-NNN.4dgs` per time segment), `backdrop.png` when `opts` has a learned
/// backdrop, and `scene.json` (with `opts.background`). Returns the path of `index.html`.
pub fn write_viewer(
    model: &Gaussians<f32>,
    cameras: &CameraSet,
    times: &[f64],
    bundle: &Path,
    opts: &super::ExportOptions,
    dir: &Path,
) -> Result<PathBuf, ExportError> {
    copy_bundle(bundle, dir)?;
    let backdrop = opts
        .backdrop
        .as_ref()
        .map(|b| write_backdrop(b, dir))
        .transpose()?;
    let lo = times.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = times.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let segment = opts.segment_seconds * model.time.units_per_second;
    let mut files = encode_segments(model, [lo, hi], opts.min_opacity, segment).into_iter();
    let always = files
        .next()
        .expect("encode_segments makes at least one file");
    let write = |file: String, part: Segment| -> Result<ViewerSegment, ExportError> {
        write_atomic(&dir.join(&file), &part.encoded.bytes)?;
        Ok(ViewerSegment {
            file,
            bytes: part.encoded.bytes.len(),
            gaussians: part.encoded.header.count,
            reach: part.reach,
        })
    };
    let degrees = always.encoded.header.degrees;
    let first = write("model.4dgs".into(), always)?;
    let segments = files
        .enumerate()
        .map(|(k, part)| write(format!("model-{k:03}.4dgs"), part))
        .collect::<Result<Vec<_>, _>>()?;
    remove_stale_segments(dir, &segments)?;
    let mean = model
        .means
        .iter()
        .map(|m| DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64))
        .sum::<DVec3>()
        / model.len().max(1) as f64;
    let scene = ViewerScene {
        version: 5,
        model: ViewerModel {
            file: first.file,
            bytes: first.bytes,
            gaussians: first.gaussians,
            degrees,
        },
        segments,
        times: times.to_vec(),
        time: model.time,
        cameras: cameras
            .cameras
            .iter()
            .map(|c| ViewerCamera {
                name: c.name.clone(),
                intrinsics: c.intrinsics,
                pose: c.world_to_camera,
            })
            .collect(),
        start_camera: 0,
        centre: look_centre(cameras, mean).to_array(),
        up: mean_up(cameras).to_array(),
        background: opts.background,
        backdrop,
    };
    let scene_path = dir.join("scene.json");
    crate::atomic::write_json(&scene_path, &scene).map_err(|source| ExportError::Io {
        path: scene_path,
        source,
    })?;
    Ok(dir.join("index.html"))
}

/// Remove `model-NNN.4dgs` files of an earlier export that `segments` does not list.
fn remove_stale_segments(dir: &Path, segments: &[ViewerSegment]) -> Result<(), ExportError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ExportError::Io { path, source }
    };
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let name = entry.map_err(io(dir))?.file_name();
        let name = name.to_string_lossy();
        let stale = name.starts_with("model-")
            && name.ends_with(".4dgs")
            && !segments.iter().any(|s| s.file == name);
        if stale {
            std::fs::remove_file(dir.join(&*name)).map_err(io(&dir.join(&*name)))?;
        }
    }
    Ok(())
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
