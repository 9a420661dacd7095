//! nerfstudio's `transforms.json`: `frames`, each with `file_path` (relative to the file)
//! and `transform_matrix` (4×4 camera-to-world in OpenGL axes: x right, y up, z back),
//! intrinsics `fl_x fl_y cx cy w h` at the top or per frame (per frame wins), a
//! `camera_model` (`OPENCV`: `k1 k2 p1 p2 [k3]`; `OPENCV_FISHEYE`: `k1..k4`; `PINHOLE`
//! or none), and `applied_transform` (3×4: what nerfstudio applied to the original poses,
//! undone here). nerfstudio casts rays through pixel centres at +0.5, as the engine does.
//!
//! A camera is a folder of frames (`images/cam0/00001.png`); when every frame sits in one
//! folder, frames with the same pose and intrinsics are one camera (a still rig), named
//! `camN` in order of appearance. A camera's frames are its images in name order.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DVec4};
use serde_json::Value;
use shared_types::camera::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::d3dgs::matrix;
use super::{Dataset, Footage, ImportError};

pub const TRANSFORMS_FILE: &str = "transforms.json";

pub fn read(source: &Path) -> Result<Dataset, ImportError> {
    let path = source.join(TRANSFORMS_FILE);
    let value = parse_json(&path)?;
    let bad = |message: String| ImportError::bad(&path, message);
    let frames = value
        .get("frames")
        .and_then(Value::as_array)
        .filter(|f| !f.is_empty())
        .ok_or_else(|| bad("`frames` is missing or empty".into()))?;
    let applied = match value.get("applied_transform") {
        None => DMat4::IDENTITY,
        Some(a) => {
            let m = matrix(a, 3, 4)
                .ok_or_else(|| bad("`applied_transform` is not a 3×4 matrix of numbers".into()))?;
            to_mat4(&[
                m[0].clone(),
                m[1].clone(),
                m[2].clone(),
                vec![0.0, 0.0, 0.0, 1.0],
            ])
        }
    };
    let undo = applied.inverse();
    // (camera key, camera, image) per frame.
    let mut seen: Vec<(String, Camera)> = Vec::new();
    let mut images: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();
    let folders: std::collections::BTreeSet<String> = frames
        .iter()
        .filter_map(|f| f.get("file_path").and_then(Value::as_str))
        .map(parent_name)
        .collect();
    for (i, frame) in frames.iter().enumerate() {
        let key = |k: &str| format!("`frames`[{i}].{k}");
        let file = frame
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| bad(format!("{} is missing", key("file_path"))))?;
        let image = source.join(file);
        let c2w = frame
            .get("transform_matrix")
            .and_then(|m| matrix(m, 4, 4))
            .ok_or_else(|| {
                bad(format!(
                    "{} is not a 4×4 matrix of numbers",
                    key("transform_matrix")
                ))
            })?;
        let c2w = undo * to_mat4(&c2w);
        let intrinsics =
            intrinsics(&value, frame, &image).map_err(|k| bad(format!("{}: {k}", key(""))))?;
        let distortion = distortion(&value, frame).map_err(|k| bad(format!("{}{k}", key(""))))?;
        // OpenGL's y up and z back are OpenCV's −y and −z.
        let gl = DMat3::from_mat4(c2w);
        let camera_to_world = DMat3::from_cols(gl.x_axis, -gl.y_axis, -gl.z_axis);
        let rotation = camera_to_world.transpose();
        let centre = c2w.w_axis.truncate();
        let mut camera = Camera {
            name: String::new(),
            intrinsics,
            distortion,
            world_to_camera: WorldToCamera::from_parts(rotation, -(rotation * centre)),
        };
        let name = if folders.len() > 1 {
            parent_name(file)
        } else {
            match seen.iter().find(|(_, c)| same_camera(c, &camera)) {
                Some((n, _)) => n.clone(),
                None => format!("cam{}", seen.len()),
            }
        };
        match seen.iter().find(|(n, _)| *n == name) {
            Some((_, first)) if !same_camera(first, &camera) => {
                return Err(bad(format!(
                    "{} ({file}) is in camera {name}'s folder but has another pose or lens; one folder must be one camera",
                    key("transform_matrix")
                )));
            }
            Some(_) => {}
            None => {
                camera.name = name.clone();
                seen.push((name.clone(), camera));
            }
        }
        images.entry(name).or_default().push(image);
    }
    let mut footage = BTreeMap::new();
    for (name, mut list) in images {
        list.sort_by_key(|p| {
            rig::media::natural_key(&p.file_name().unwrap_or_default().to_string_lossy())
        });
        if let Some(missing) = list.iter().find(|p| !p.is_file()) {
            return Err(bad(format!("{} is listed but missing", missing.display())));
        }
        footage.insert(name, Footage::Images(list));
    }
    Ok(Dataset {
        cameras: seen.into_iter().map(|(_, c)| c).collect(),
        footage,
        heldout: Vec::new(),
        fps: None,
    })
}

/// A `transforms.json` for `cameras` (in `index`'s camera order, each at its frames' size,
/// with its lens) over the frames of `index`: one frame per camera per output frame,
/// `file_path` its image under `prefix` (relative to the file), its intrinsics, lens and
/// camera-to-world in OpenGL axes, as nerfstudio writes them. [`read`] reads it back.
pub fn transforms(
    cameras: &[Camera],
    index: &rig::frames::FramesIndex,
    prefix: &str,
) -> Result<Value, String> {
    let mut frames = Vec::new();
    for frame in &index.frames {
        for (camera, view) in cameras.iter().zip(&frame.views) {
            let k = &camera.intrinsics;
            let w = &camera.world_to_camera;
            let c2w = w.rotation().transpose();
            let (x, y, z, c) = (c2w.x_axis, -c2w.y_axis, -c2w.z_axis, w.centre());
            let row = |r: usize| [x[r], y[r], z[r], c[r]];
            let mut entry = serde_json::json!({
                "file_path": format!("{prefix}/{}", view.file),
                "transform_matrix": [row(0), row(1), row(2), [0.0, 0.0, 0.0, 1.0]],
                "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height,
            });
            let c = camera.distortion.coefficients();
            let (model, keys): (_, &[&str]) = match camera.distortion {
                Distortion::None => ("PINHOLE", &[]),
                Distortion::Fisheye { .. } => ("OPENCV_FISHEYE", &["k1", "k2", "k3", "k4"]),
                Distortion::Opencv { .. } if c.len() <= 5 => {
                    ("OPENCV", &["k1", "k2", "p1", "p2", "k3"])
                }
                Distortion::Opencv { .. } => {
                    return Err(format!(
                        "camera {}: its lens has rational, thin-prism or tilt terms, which transforms.json cannot hold",
                        camera.name
                    ));
                }
            };
            entry["camera_model"] = model.into();
            for (key, v) in keys.iter().zip(&c) {
                entry[*key] = (*v).into();
            }
            frames.push(entry);
        }
    }
    Ok(serde_json::json!({ "frames": frames }))
}

/// A JSON file; a NaN or an infinity (which Python's `json` writes) is named as such.
pub(crate) fn parse_json(path: &Path) -> Result<Value, ImportError> {
    let text = super::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| {
        let line = e.line();
        let near = text.lines().nth(line.saturating_sub(1)).unwrap_or("").trim();
        if ["NaN", "Infinity"].iter().any(|w| near.contains(w)) {
            ImportError::bad(path, format!("line {line} holds a NaN or infinite value ({near}): the file's cameras are broken"))
        } else {
            ImportError::bad(path, format!("not JSON: {e}"))
        }
    })
}

fn parent_name(file: &str) -> String {
    Path::new(file)
        .parent()
        .and_then(|p| p.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn to_mat4(rows: &[Vec<f64>]) -> DMat4 {
    let col = |c: usize| DVec4::new(rows[0][c], rows[1][c], rows[2][c], rows[3][c]);
    DMat4::from_cols(col(0), col(1), col(2), col(3))
}

fn same_camera(a: &Camera, b: &Camera) -> bool {
    a.intrinsics == b.intrinsics
        && a.distortion == b.distortion
        && a.world_to_camera
            .centre()
            .distance(b.world_to_camera.centre())
            < 1e-9
        && (a.world_to_camera.rotation() - b.world_to_camera.rotation())
            .to_cols_array()
            .iter()
            .all(|v| v.abs() < 1e-9)
}

/// A number from the frame, else from the file's top level.
fn number(top: &Value, frame: &Value, key: &str) -> Option<f64> {
    frame
        .get(key)
        .or_else(|| top.get(key))
        .and_then(Value::as_f64)
}

fn intrinsics(top: &Value, frame: &Value, image: &Path) -> Result<Intrinsics, String> {
    let need = |key: &str| {
        number(top, frame, key)
            .ok_or_else(|| format!("`{key}` is missing (top level or per frame)"))
    };
    let (fx, fy) = (need("fl_x")?, need("fl_y").or_else(|_| need("fl_x"))?);
    let (width, height) = match (number(top, frame, "w"), number(top, frame, "h")) {
        (Some(w), Some(h)) => (w as u32, h as u32),
        _ => image::image_dimensions(image).map_err(|e| {
            format!(
                "`w` and `h` are missing and {} cannot be read: {e}",
                image.display()
            )
        })?,
    };
    let cx = number(top, frame, "cx").unwrap_or(width as f64 / 2.0);
    let cy = number(top, frame, "cy").unwrap_or(height as f64 / 2.0);
    Ok(Intrinsics {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
    })
}

fn distortion(top: &Value, frame: &Value) -> Result<Distortion, String> {
    let model = frame
        .get("camera_model")
        .or_else(|| top.get("camera_model"))
        .and_then(Value::as_str)
        .unwrap_or("PINHOLE");
    let k = |key: &str| number(top, frame, key).unwrap_or(0.0);
    match model {
        "PINHOLE" | "SIMPLE_PINHOLE" => Ok(Distortion::None),
        "OPENCV" => Ok(Distortion::radial_tangential(
            k("k1"),
            k("k2"),
            k("p1"),
            k("p2"),
            k("k3"),
        )),
        "OPENCV_FISHEYE" => Ok(Distortion::Fisheye {
            k1: k("k1"),
            k2: k("k2"),
            k3: k("k3"),
            k4: k("k4"),
        }),
        other => Err(format!(
            "camera_model `{other}` is not one this imports (PINHOLE, OPENCV, OPENCV_FISHEYE)"
        )),
    }
}
