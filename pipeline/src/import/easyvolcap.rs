//! EasyVolcap / EasyMocap (ZJU-MoCap) cameras: OpenCV FileStorage YAML files `intri.yml`
//! (`names`, and per camera `K_<name>`, `D_<name>` or `dist_<name>` as OpenCV's
//! `k1 k2 p1 p2 [k3]`, optionally `H_<name>` / `W_<name>`) and `extri.yml` (`Rot_<name>`
//! a 3×3 rotation, or `R_<name>` a Rodrigues vector; `T_<name>`; world-to-camera, OpenCV
//! axes), beside `videos/<name>.mp4` or `images/<name>/NNNNNN.jpg`. OpenCV's pixel
//! convention (the first pixel's centre at 0), shifted by +0.5 here.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DMat3, DVec3};
use serde_json::Value;
use shared_types::camera::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::{Dataset, Footage, ImportError};

pub fn read(source: &Path) -> Result<Dataset, ImportError> {
    let intri_path = source.join("intri.yml");
    let extri_path = source.join("extri.yml");
    let intri = yaml(&intri_path)?;
    let extri = yaml(&extri_path)?;
    let names: Vec<String> = intri
        .get("names")
        .and_then(Value::as_array)
        .map(|list| {
            list.iter()
                .map(|n| match n {
                    Value::String(s) => s.clone(),
                    other => other.to_string(),
                })
                .collect()
        })
        .filter(|l: &Vec<String>| !l.is_empty())
        .ok_or_else(|| {
            ImportError::bad(
                &intri_path,
                "`names` (the list of cameras) is missing or empty",
            )
        })?;
    let mut cameras = Vec::new();
    let mut footage = BTreeMap::new();
    for name in names {
        let video = source.join("videos").join(format!("{name}.mp4"));
        let folder = source.join("images").join(&name);
        let media = if video.is_file() {
            Footage::Video(video)
        } else if folder.is_dir() {
            Footage::Images(super::images_in(&folder)?)
        } else {
            return Err(ImportError::bad(
                source,
                format!("camera {name}: neither videos/{name}.mp4 nor images/{name}/ is there"),
            ));
        };
        let k = opencv_matrix(&intri, &format!("K_{name}"), 9)
            .map_err(|m| ImportError::bad(&intri_path, m))?;
        let dist = ["D_", "dist_"]
            .iter()
            .find_map(|p| {
                intri
                    .get(format!("{p}{name}"))
                    .map(|_| format!("{p}{name}"))
            })
            .map(|key| opencv_matrix(&intri, &key, 0))
            .transpose()
            .map_err(|m| ImportError::bad(&intri_path, m))?
            .unwrap_or_default();
        let distortion = if dist.iter().all(|&d| d == 0.0) {
            Distortion::None
        } else {
            Distortion::from_opencv_coefficients(&dist)
                .map_err(|m| ImportError::bad(&intri_path, format!("D_{name}: {m}")))?
        };
        let rotation = match opencv_matrix(&extri, &format!("Rot_{name}"), 9) {
            Ok(r) => {
                DMat3::from_cols_array(&[r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]])
            }
            Err(_) => {
                let r = opencv_matrix(&extri, &format!("R_{name}"), 3).map_err(|m| {
                    ImportError::bad(&extri_path, format!("{m} (or give Rot_{name}, 3×3)"))
                })?;
                calib::import::rodrigues(DVec3::new(r[0], r[1], r[2]))
            }
        };
        let t = opencv_matrix(&extri, &format!("T_{name}"), 3)
            .map_err(|m| ImportError::bad(&extri_path, m))?;
        let scalar = |key: String| intri.get(&key).and_then(Value::as_f64).map(|v| v as u32);
        let (width, height) = match (
            scalar(format!("W_{name}")),
            scalar(format!("H_{name}")),
            &media,
        ) {
            (Some(w), Some(h), _) => (w, h),
            (_, _, Footage::Images(list)) if !list.is_empty() => super::image_size(&list[0])?,
            _ => {
                return Err(ImportError::bad(
                    &intri_path,
                    format!(
                        "H_{name} and W_{name} (the image size) are missing; add them for videos"
                    ),
                ));
            }
        };
        cameras.push(Camera {
            name: name.clone(),
            intrinsics: Intrinsics {
                width,
                height,
                fx: k[0],
                fy: k[4],
                cx: k[2] + calib::import::OPENCV_PIXEL_OFFSET,
                cy: k[5] + calib::import::OPENCV_PIXEL_OFFSET,
            },
            distortion,
            world_to_camera: WorldToCamera::from_parts(rotation, DVec3::new(t[0], t[1], t[2])),
        });
        footage.insert(name, media);
    }
    Ok(Dataset {
        cameras,
        footage,
        heldout: Vec::new(),
        fps: None,
    })
}

fn yaml(path: &Path) -> Result<Value, ImportError> {
    calib::import::opencv_yaml_value(&super::read_text(path)?)
        .map_err(|e| ImportError::bad(path, format!("not OpenCV FileStorage YAML: {e}")))
}

/// The numbers of an `!!opencv-matrix` entry (`data`), `len` of them (0: any number).
fn opencv_matrix(file: &Value, key: &str, len: usize) -> Result<Vec<f64>, String> {
    let entry = file.get(key).ok_or_else(|| format!("`{key}` is missing"))?;
    let data = entry.get("data").unwrap_or(entry);
    let values: Vec<f64> = data
        .as_array()
        .ok_or_else(|| format!("`{key}` is not a matrix"))?
        .iter()
        .map(|v| {
            v.as_f64()
                .or_else(|| v.as_str().and_then(|s| s.trim().parse().ok()))
        })
        .collect::<Option<_>>()
        .ok_or_else(|| format!("`{key}` holds something that is not a number"))?;
    if len != 0 && values.len() != len {
        return Err(format!(
            "`{key}` has {} numbers, expected {len}",
            values.len()
        ));
    }
    if values.iter().any(|v| !v.is_finite()) {
        return Err(format!("`{key}` holds NaN or infinite values"));
    }
    Ok(values)
}
