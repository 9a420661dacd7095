//! Calibration import instead of solving with COLMAP: a COLMAP model folder, an
//! OpenCV-style JSON or YAML file (`K`, `dist`, `R` or `rvec`, `t`), a Caliscope
//! `camera_array.toml`, or a Pose2Sim `Calib_scene.toml` ([`pose2sim`], recognised by its
//! shape). Distortion vectors are OpenCV's full model (4, 5, 8, 12 or 14 coefficients) or
//! fisheye `k1..k4`. The result is a [`CameraSet`] in the engine's convention
//! (world-to-camera, OpenCV axes, translations in metres).
//!
//! Pixel convention: OpenCV-style files (and Caliscope's, Pose2Sim's) put a pixel's centre
//! at its integer coordinates; the engine puts it at integer + 0.5, so their principal
//! point is shifted by [`OPENCV_PIXEL_OFFSET`] on import (`pixel_centre = "half"` in a
//! JSON/YAML file says it is already in the engine's convention). COLMAP models are taken
//! as they are (COLMAP's convention is the engine's).
//!
//! Checks: `K` is upper-triangular without skew; `R` is a rotation (orthonormal,
//! determinant +1: a −1 means a left-handed/OpenGL-style frame); the rig's size is
//! plausible for the declared units (a rig wider than 100 m or smaller than 1 cm is refused
//! with a hint to set `units`). See `docs/poses.md` for the accepted keys.

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use serde_json::Value;
use shared_types::{Camera, CameraSet, Distortion, Intrinsics, WorldToCamera};

use crate::colmap::ColmapModel;
use crate::convert;

mod pose2sim;

/// Length units of translations / camera centres in a calibration file (`"m"`, `"cm"`,
/// `"mm"` in settings).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Units {
    #[serde(rename = "m")]
    Metres,
    #[serde(rename = "cm")]
    Centimetres,
    #[serde(rename = "mm")]
    Millimetres,
}

impl Units {
    pub fn to_metres(self) -> f64 {
        match self {
            Units::Metres => 1.0,
            Units::Centimetres => 0.01,
            Units::Millimetres => 0.001,
        }
    }

    fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "m" | "metre" | "metres" | "meter" | "meters" => Some(Units::Metres),
            "cm" | "centimetre" | "centimetres" | "centimeter" | "centimeters" => {
                Some(Units::Centimetres)
            }
            "mm" | "millimetre" | "millimetres" | "millimeter" | "millimeters" => {
                Some(Units::Millimetres)
            }
            _ => None,
        }
    }
}

/// Options for [`import_calibration_with`].
#[derive(Clone, Debug, Default)]
pub struct ImportOptions {
    /// Units of the file's translations, overriding a `units` key in it (default metres).
    pub units: Option<Units>,
}

#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("cannot read calibration {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("calibration {path} is not valid {format}: {message}")]
    Syntax {
        path: PathBuf,
        format: &'static str,
        message: String,
    },
    #[error(
        "{path}: unknown calibration format; use a COLMAP model folder, .json, .yaml/.yml, a \
         Caliscope camera_array.toml or a Pose2Sim Calib_scene.toml"
    )]
    UnknownFormat { path: PathBuf },
    #[error("{path}: camera {camera}: {message}")]
    Camera {
        path: PathBuf,
        camera: String,
        message: String,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Colmap(#[from] crate::colmap::ModelError),
    #[error(transparent)]
    Convert(#[from] convert::ConvertError),
}

/// Names a calibration is looked for under in a capture directory, in order.
pub const CALIBRATION_NAMES: [&str; 7] = [
    "calibration.json",
    "calibration.yaml",
    "calibration.yml",
    "calibration.toml",
    "camera_array.toml",
    "Calib_scene.toml",
    "calibration",
];

/// The calibration file or COLMAP folder in a capture directory, if there is one.
pub fn find_calibration(capture_dir: &Path) -> Option<PathBuf> {
    CALIBRATION_NAMES
        .iter()
        .map(|n| capture_dir.join(n))
        .find(|p| {
            if p.is_dir() {
                ColmapModel::detect_format(p).is_some()
            } else {
                p.is_file()
            }
        })
}

/// Import a calibration (units from the file, metres when it says nothing).
pub fn import_calibration(path: &Path) -> Result<CameraSet, ImportError> {
    import_calibration_with(path, &ImportOptions::default())
}

/// Import a calibration with explicit options.
pub fn import_calibration_with(
    path: &Path,
    options: &ImportOptions,
) -> Result<CameraSet, ImportError> {
    import(path, options, false)
}

/// Import only the lenses of a calibration file (`[poses] intrinsics`): as
/// [`import_calibration`], but a camera without rotation or translation is accepted (its
/// pose is the identity and means nothing), and the rig's size is not checked.
pub fn import_lenses(path: &Path) -> Result<CameraSet, ImportError> {
    import(path, &ImportOptions::default(), true)
}

fn import(
    path: &Path,
    options: &ImportOptions,
    lenses_only: bool,
) -> Result<CameraSet, ImportError> {
    if path.is_dir() {
        // COLMAP's scale is arbitrary: no unit check.
        return from_colmap(path);
    }
    let set = {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let text = std::fs::read_to_string(path).map_err(|source| ImportError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let syntax = |format: &'static str, message: String| ImportError::Syntax {
            path: path.to_path_buf(),
            format,
            message,
        };
        let value: Value = match ext.as_str() {
            "json" => serde_json::from_str(&text).map_err(|e| syntax("JSON", e.to_string()))?,
            "yaml" | "yml" => {
                let y: serde_yaml::Value = serde_yaml::from_str(&opencv_yaml_to_yaml(&text))
                    .map_err(|e| syntax("YAML", e.to_string()))?;
                serde_json::to_value(y).map_err(|e| syntax("YAML", e.to_string()))?
            }
            "toml" => {
                let t: toml::Value =
                    toml::from_str(&text).map_err(|e| syntax("TOML", e.to_string()))?;
                let value = serde_json::to_value(t).map_err(|e| syntax("TOML", e.to_string()))?;
                if pose2sim::is_pose2sim(&value) {
                    let set = from_pose2sim(path, &value)?;
                    if !lenses_only {
                        check_scale(path, &set)?;
                    }
                    return Ok(set);
                }
                value
            }
            _ => {
                return Err(ImportError::UnknownFormat {
                    path: path.to_path_buf(),
                });
            }
        };
        from_value(path, &value, options, lenses_only)?
    };
    if !lenses_only {
        check_scale(path, &set)?;
    }
    Ok(set)
}

/// A Pose2Sim calibration (always metres).
fn from_pose2sim(path: &Path, value: &Value) -> Result<CameraSet, ImportError> {
    let mut cameras =
        pose2sim::cameras(value).map_err(|(camera, message)| ImportError::Camera {
            path: path.to_path_buf(),
            camera,
            message,
        })?;
    cameras.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(CameraSet::new(cameras))
}

/// A COLMAP model folder: one camera per image, named by the image's file stem.
fn from_colmap(dir: &Path) -> Result<CameraSet, ImportError> {
    let model = ColmapModel::read(dir)?;
    let mut cameras = Vec::new();
    for image in model.images.values() {
        let name = Path::new(&image.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        cameras.push(convert::camera_from_image(&model, image, &name)?);
    }
    cameras.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(CameraSet::new(cameras))
}

/// An OpenCV FileStorage YAML text as a JSON value (`!!opencv-matrix` entries become
/// `{rows, cols, dt, data}` tables): for readers of other tools' files.
pub fn opencv_yaml_value(text: &str) -> Result<Value, String> {
    let y: serde_yaml::Value =
        serde_yaml::from_str(&opencv_yaml_to_yaml(text)).map_err(|e| e.to_string())?;
    serde_json::to_value(y).map_err(|e| e.to_string())
}

/// OpenCV's FileStorage YAML (`%YAML:1.0`, `!!opencv-matrix`) → plain YAML.
fn opencv_yaml_to_yaml(text: &str) -> String {
    text.lines()
        .filter(|l| !l.trim_start().starts_with('%'))
        .map(|l| {
            l.replace("!!opencv-matrix", "")
                .replace("!!opencv-nd-matrix", "")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The camera entries of a parsed file: `cameras` as a list (with `name`) or a table
/// (keyed by name; a numeric key `N` becomes `camN`), or a top-level table of cameras.
fn camera_entries(v: &Value) -> Vec<(String, &Value)> {
    let container = v.get("cameras").unwrap_or(v);
    match container {
        Value::Array(list) => list
            .iter()
            .enumerate()
            .map(|(i, c)| (name_of(c).unwrap_or_else(|| format!("cam{i}")), c))
            .collect(),
        Value::Object(map) => map
            .iter()
            .filter(|(_, c)| c.is_object() && looks_like_camera(c))
            .map(|(k, c)| {
                let name = if let Some(id) = c.get("cam_id").and_then(Value::as_i64) {
                    format!("cam{id}")
                } else if k.chars().all(|ch| ch.is_ascii_digit()) {
                    format!("cam{k}")
                } else {
                    name_of(c).unwrap_or_else(|| k.clone())
                };
                (name, c)
            })
            .collect(),
        _ => Vec::new(),
    }
}

fn name_of(c: &Value) -> Option<String> {
    c.get("name").and_then(Value::as_str).map(str::to_string)
}

const K_KEYS: [&str; 5] = [
    "K",
    "camera_matrix",
    "cameraMatrix",
    "matrix",
    "intrinsic_matrix",
];
const DIST_KEYS: [&str; 8] = [
    "dist",
    "distortion",
    "distortions",
    "distCoef",
    "distCoeffs",
    "dist_coeffs",
    "distortion_coefficients",
    "D",
];
const R_KEYS: [&str; 4] = ["R", "rotation", "rotation_matrix", "Rot"];
const RVEC_KEYS: [&str; 3] = ["rvec", "rotation_vector", "rodrigues"];
const T_KEYS: [&str; 5] = ["t", "T", "tvec", "translation", "translation_vector"];
const C_KEYS: [&str; 4] = ["C", "centre", "center", "camera_center"];

fn looks_like_camera(c: &Value) -> bool {
    K_KEYS.iter().any(|k| c.get(k).is_some())
}

fn get<'a>(c: &'a Value, keys: &[&str]) -> Option<&'a Value> {
    keys.iter().find_map(|k| c.get(k))
}

/// Numbers of a matrix/vector value: nested lists, a flat list, or OpenCV's
/// `{rows, cols, data}`.
fn numbers(v: &Value) -> Option<Vec<f64>> {
    match v {
        Value::Number(n) => n.as_f64().map(|x| vec![x]),
        Value::Array(items) => {
            let mut out = Vec::new();
            for i in items {
                out.extend(numbers(i)?);
            }
            Some(out)
        }
        Value::Object(m) => m.get("data").and_then(numbers),
        _ => None,
    }
}

fn from_value(
    path: &Path,
    v: &Value,
    options: &ImportOptions,
    lenses_only: bool,
) -> Result<CameraSet, ImportError> {
    let file_units = v.get("units").and_then(Value::as_str);
    let units = match (options.units, file_units) {
        (Some(u), _) => u,
        (None, Some(s)) => Units::parse(s).ok_or_else(|| ImportError::Invalid {
            path: path.to_path_buf(),
            message: format!("unknown units {s:?}; use \"m\", \"cm\" or \"mm\""),
        })?,
        (None, None) => Units::Metres,
    };
    let top_convention = v.get("convention").and_then(Value::as_str);
    let pixel_offset =
        pixel_offset(v.get("pixel_centre")).map_err(|message| ImportError::Invalid {
            path: path.to_path_buf(),
            message,
        })?;
    let entries = camera_entries(v);
    if entries.is_empty() {
        return Err(ImportError::Invalid {
            path: path.to_path_buf(),
            message: "no cameras found (expected `cameras` with K, dist, R or rvec, t per camera)"
                .into(),
        });
    }
    let mut cameras = Vec::new();
    for (name, c) in entries {
        if c.get("ignore").and_then(Value::as_bool) == Some(true) {
            continue;
        }
        let err = |message: String| ImportError::Camera {
            path: path.to_path_buf(),
            camera: name.clone(),
            message,
        };
        let convention = c
            .get("convention")
            .and_then(Value::as_str)
            .or(top_convention)
            .unwrap_or("world_to_camera");
        let mut cam = camera_from_value(&name, c, units, convention, lenses_only).map_err(err)?;
        cam.intrinsics.cx += pixel_offset;
        cam.intrinsics.cy += pixel_offset;
        cameras.push(cam);
    }
    cameras.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(CameraSet::new(cameras))
}

/// What to add to a file's principal point to put pixel centres at integer + 0.5, the
/// engine's (and COLMAP's) convention: `pixel_centre = "integer"` (OpenCV's, the default
/// for these files) adds 0.5, `"half"` (files written in the engine's convention, such as
/// the simulator's truth) nothing.
fn pixel_offset(key: Option<&Value>) -> Result<f64, String> {
    match key.map(|k| k.as_str().unwrap_or("")) {
        None | Some("integer") => Ok(OPENCV_PIXEL_OFFSET),
        Some("half") => Ok(0.0),
        Some(other) => Err(format!(
            "unknown pixel_centre {other:?}; use \"integer\" (OpenCV: the first pixel's centre \
             is 0) or \"half\" (COLMAP: it is 0.5)"
        )),
    }
}

/// OpenCV puts a pixel's centre at its integer coordinates, the engine at integer + 0.5:
/// an OpenCV principal point is this much smaller than the engine's.
pub const OPENCV_PIXEL_OFFSET: f64 = 0.5;

/// One camera of a parsed file; with `lenses_only`, a missing rotation or translation is
/// the identity.
fn camera_from_value(
    name: &str,
    c: &Value,
    units: Units,
    convention: &str,
    lenses_only: bool,
) -> Result<Camera, String> {
    let k = get(c, &K_KEYS)
        .and_then(numbers)
        .filter(|k| k.len() == 9)
        .ok_or("K must be a 3×3 matrix")?;
    if k[3].abs() > 1e-9 || k[6].abs() > 1e-9 || k[7].abs() > 1e-9 || (k[8] - 1.0).abs() > 1e-9 {
        return Err(format!(
            "K {k:?} is not of the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]"
        ));
    }
    if k[1].abs() > 1e-6 * k[0].abs() {
        return Err(format!(
            "K has skew {} which the engine does not model; recalibrate with zero skew",
            k[1]
        ));
    }
    let size = get(c, &["size", "resolution", "image_size", "imageSize"])
        .and_then(numbers)
        .filter(|s| s.len() == 2)
        .or_else(|| {
            let w = get(c, &["image_width", "width"])?.as_f64()?;
            let h = get(c, &["image_height", "height"])?.as_f64()?;
            Some(vec![w, h])
        })
        .ok_or("image size missing: add size = [width, height] (the size K applies to)")?;
    if size
        .iter()
        .any(|&s| s < 1.0 || s.fract() != 0.0 || s > u32::MAX as f64)
    {
        return Err(format!(
            "image size {size:?} is not a positive whole number of pixels"
        ));
    }
    let intrinsics = Intrinsics {
        width: size[0] as u32,
        height: size[1] as u32,
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
    };
    let model = get(c, &["model", "distortion_model", "camera_model"])
        .and_then(Value::as_str)
        .unwrap_or("opencv");
    let fisheye = matches!(
        model.to_ascii_lowercase().as_str(),
        "fisheye" | "equidistant" | "opencv_fisheye" | "kannala_brandt"
    );
    let d = get(c, &DIST_KEYS)
        .map(|v| numbers(v).ok_or("distortion must be a list of numbers"))
        .transpose()?
        .unwrap_or_default();
    let distortion = distortion_from(&d, fisheye)?;

    let r = if let Some(rv) = get(c, &R_KEYS).and_then(numbers) {
        match rv.len() {
            9 => DMat3::from_cols_slice(&rv).transpose(), // rows in the file
            3 => rodrigues(DVec3::new(rv[0], rv[1], rv[2])),
            n => {
                return Err(format!(
                    "R has {n} numbers; expected a 3×3 matrix or a 3-vector (Rodrigues)"
                ));
            }
        }
    } else if let Some(rv) = get(c, &RVEC_KEYS)
        .and_then(numbers)
        .filter(|v| v.len() == 3)
    {
        rodrigues(DVec3::new(rv[0], rv[1], rv[2]))
    } else if lenses_only {
        DMat3::IDENTITY
    } else {
        return Err("rotation missing: give R (3×3) or rvec (3)".into());
    };
    check_rotation(&r)?;
    let to_m = units.to_metres();
    let translation = if let Some(t) = get(c, &T_KEYS).and_then(numbers) {
        if t.len() != 3 {
            return Err(format!("t has {} numbers, expected 3", t.len()));
        }
        Some(DVec3::new(t[0], t[1], t[2]) * to_m)
    } else {
        None
    };
    let centre = get(c, &C_KEYS)
        .and_then(numbers)
        .filter(|v| v.len() == 3)
        .map(|v| DVec3::new(v[0], v[1], v[2]) * to_m);
    let w2c = match convention.to_ascii_lowercase().as_str() {
        "world_to_camera" | "w2c" | "opencv" => {
            let t = match (translation, centre) {
                (Some(t), _) => t,
                (None, Some(c)) => -(r * c),
                (None, None) if lenses_only => DVec3::ZERO,
                (None, None) => {
                    return Err(
                        "translation missing: give t (world-to-camera) or C (camera centre)".into(),
                    );
                }
            };
            WorldToCamera::from_parts(r, t)
        }
        "camera_to_world" | "c2w" => {
            // R, t map camera → world: invert.
            let t = translation
                .or(centre)
                .ok_or("translation missing: give t")?;
            let rt = r.transpose();
            WorldToCamera::from_parts(rt, -(rt * t))
        }
        other => {
            return Err(format!(
                "unknown convention {other:?}; use \"world_to_camera\" or \"camera_to_world\""
            ));
        }
    };
    Ok(Camera {
        name: name.to_string(),
        intrinsics,
        distortion,
        world_to_camera: w2c,
    })
}

fn distortion_from(d: &[f64], fisheye: bool) -> Result<Distortion, String> {
    if d.iter().all(|&x| x == 0.0) {
        return Ok(Distortion::None);
    }
    let at = |i: usize| d.get(i).copied().unwrap_or(0.0);
    if fisheye {
        if d.len() > 4 {
            return Err(format!(
                "fisheye distortion has {} coefficients, expected 4 (k1..k4)",
                d.len()
            ));
        }
        return Ok(Distortion::Fisheye {
            k1: at(0),
            k2: at(1),
            k3: at(2),
            k4: at(3),
        });
    }
    Distortion::from_opencv_coefficients(d).map_err(|e| {
        format!("{e}; for a fisheye lens (4 coefficients k1..k4) set model = \"fisheye\"")
    })
}

/// Rotation matrix of a Rodrigues vector (axis × angle in radians).
pub fn rodrigues(v: DVec3) -> DMat3 {
    let angle = v.length();
    if angle < 1e-15 {
        return DMat3::IDENTITY;
    }
    DMat3::from_axis_angle(v / angle, angle)
}

fn check_rotation(r: &DMat3) -> Result<(), String> {
    let err = (*r * r.transpose() - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |m, x| m.max(x.abs()));
    if err > 1e-3 {
        return Err(format!(
            "R is not a rotation (RRᵀ differs from I by {err:.2e}); is it a full 3×3 rotation matrix?"
        ));
    }
    if r.determinant() < 0.0 {
        return Err(
            "R has determinant −1 (a left-handed frame): the file likely uses OpenGL/Blender axes \
             (y up, z backward); convert to OpenCV axes (x right, y down, z forward)"
                .into(),
        );
    }
    Ok(())
}

/// Refuse rigs whose size is implausible in metres: a sign of wrong units.
fn check_scale(path: &Path, set: &CameraSet) -> Result<(), ImportError> {
    let centres: Vec<DVec3> = set
        .cameras
        .iter()
        .map(|c| c.world_to_camera.centre())
        .collect();
    let mut widest = 0.0f64;
    for (i, a) in centres.iter().enumerate() {
        for b in &centres[i + 1..] {
            widest = widest.max((*a - *b).length());
        }
    }
    if centres.len() >= 2 && !(0.01..=100.0).contains(&widest) {
        return Err(ImportError::Invalid {
            path: path.to_path_buf(),
            message: format!(
                "the cameras are {widest:.4} apart (widest pair) if translations are metres, which is implausible \
                 for a capture rig: set `units = \"cm\"` or `\"mm\"` in the file, or under [poses] in capture.toml"
            ),
        });
    }
    Ok(())
}
