//! CMU Panoptic as Dynamic 3D Gaussians prepares it: `ims/<cam>/NNNNNN.jpg` beside
//! `train_meta.json` and `test_meta.json`. Each meta file holds, per time step, one entry
//! per camera: `k` (3×3 intrinsics), `w2c` (4×4 world-to-camera, OpenCV axes), `fn` (the
//! image, relative to `ims/`) and `cam_id`; `w` and `h` give the image size. D3DGS's
//! rasteriser puts pixel centres at +0.5 with this `k`, as the engine does. The protocol
//! holds out `test_meta.json`'s cameras.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use serde_json::Value;
use shared_types::camera::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::{Dataset, Footage, ImportError};

/// Panoptic's HD cameras film at 30 fps.
const FPS: f64 = 30.0;

pub fn read(source: &Path) -> Result<Dataset, ImportError> {
    let mut cameras = Vec::new();
    let mut footage = BTreeMap::new();
    let mut heldout = Vec::new();
    for (file, test) in [("train_meta.json", false), ("test_meta.json", true)] {
        let path = source.join(file);
        if test && !path.exists() {
            continue;
        }
        for (camera, images) in read_meta(&path, &source.join("ims"))? {
            if footage.contains_key(&camera.name) {
                return Err(ImportError::bad(
                    &path,
                    format!("camera {} is listed in both meta files", camera.name),
                ));
            }
            if test {
                heldout.push(camera.name.clone());
            }
            footage.insert(camera.name.clone(), Footage::Images(images));
            cameras.push(camera);
        }
    }
    Ok(Dataset {
        cameras,
        footage,
        heldout,
        fps: Some(FPS),
    })
}

/// The cameras of one meta file (their calibration at the first time step) and each
/// camera's images over time.
fn read_meta(path: &Path, ims: &Path) -> Result<Vec<(Camera, Vec<PathBuf>)>, ImportError> {
    let value: Value = serde_json::from_str(&super::read_text(path)?)
        .map_err(|e| ImportError::bad(path, format!("not JSON: {e}")))?;
    let bad = |message: String| ImportError::bad(path, message);
    let size = |key: &str| {
        value
            .get(key)
            .and_then(Value::as_u64)
            .filter(|&v| v > 0)
            .map(|v| v as u32)
            .ok_or_else(|| {
                bad(format!(
                    "`{key}` (the image size) is missing or not a positive number"
                ))
            })
    };
    let (width, height) = (size("w")?, size("h")?);
    let steps = |key: &str| {
        value
            .get(key)
            .and_then(Value::as_array)
            .filter(|a| !a.is_empty())
            .ok_or_else(|| {
                bad(format!(
                    "`{key}` is missing or empty (one list per time step)"
                ))
            })
    };
    let (ks, w2cs, fns, ids) = (steps("k")?, steps("w2c")?, steps("fn")?, steps("cam_id")?);
    if [w2cs.len(), fns.len(), ids.len()]
        .iter()
        .any(|&n| n != ks.len())
    {
        return Err(bad(format!(
            "`k`, `w2c`, `fn` and `cam_id` list {}, {}, {} and {} time steps; they must agree",
            ks.len(),
            w2cs.len(),
            fns.len(),
            ids.len()
        )));
    }
    let at = |list: &Value, t: usize, key: &str| -> Result<Vec<Value>, ImportError> {
        list.as_array()
            .cloned()
            .ok_or_else(|| bad(format!("`{key}`[{t}] is not a list of cameras")))
    };
    let first_ids = at(&ids[0], 0, "cam_id")?;
    let mut out = Vec::new();
    for (j, id) in first_ids.iter().enumerate() {
        let name = match id {
            Value::Number(n) => n.to_string(),
            Value::String(s) => s.clone(),
            _ => return Err(bad(format!("`cam_id`[0][{j}] is not a camera id"))),
        };
        let k = matrix(
            &at(&ks[0], 0, "k")?.get(j).cloned().unwrap_or_default(),
            3,
            3,
        )
        .ok_or_else(|| {
            bad(format!(
                "`k`[0][{j}] (camera {name}) is not a 3×3 matrix of numbers"
            ))
        })?;
        let w2c = matrix(
            &at(&w2cs[0], 0, "w2c")?.get(j).cloned().unwrap_or_default(),
            4,
            4,
        )
        .ok_or_else(|| {
            bad(format!(
                "`w2c`[0][{j}] (camera {name}) is not a 4×4 matrix of numbers"
            ))
        })?;
        let rotation = DMat3::from_cols_array_2d(&[
            [w2c[0][0], w2c[1][0], w2c[2][0]],
            [w2c[0][1], w2c[1][1], w2c[2][1]],
            [w2c[0][2], w2c[1][2], w2c[2][2]],
        ]);
        let translation = DVec3::new(w2c[0][3], w2c[1][3], w2c[2][3]);
        let mut images = Vec::new();
        for (t, step) in fns.iter().enumerate() {
            let files = at(step, t, "fn")?;
            let step_ids = at(&ids[t], t, "cam_id")?;
            let index = step_ids.iter().position(|i| i == id).ok_or_else(|| {
                bad(format!("camera {name} is missing from `cam_id`[{t}]: every time step must list every camera"))
            })?;
            let file = files.get(index).and_then(Value::as_str).ok_or_else(|| {
                bad(format!(
                    "`fn`[{t}][{index}] (camera {name}) is not a file name"
                ))
            })?;
            images.push(ims.join(file));
        }
        if let Some(missing) = images.iter().find(|p| !p.is_file()) {
            return Err(bad(format!(
                "camera {name}: {} is listed in `fn` but missing",
                missing.display()
            )));
        }
        let (iw, ih) = super::image_size(&images[0])?;
        if (iw, ih) != (width, height) {
            return Err(bad(format!(
                "camera {name}: {} is {iw} × {ih}, but `w` × `h` say {width} × {height}",
                images[0].display()
            )));
        }
        let camera = Camera {
            name,
            intrinsics: Intrinsics {
                width,
                height,
                fx: k[0][0],
                fy: k[1][1],
                cx: k[0][2],
                cy: k[1][2],
            },
            distortion: Distortion::None,
            world_to_camera: WorldToCamera::from_parts(rotation, translation),
        };
        out.push((camera, images));
    }
    Ok(out)
}

/// A `rows × cols` matrix of numbers (nested lists), row-major.
pub(crate) fn matrix(value: &Value, rows: usize, cols: usize) -> Option<Vec<Vec<f64>>> {
    let list = value.as_array().filter(|r| r.len() == rows)?;
    list.iter()
        .map(|row| {
            let row = row.as_array().filter(|r| r.len() == cols)?;
            row.iter().map(Value::as_f64).collect::<Option<Vec<f64>>>()
        })
        .collect()
}
