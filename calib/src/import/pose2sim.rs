//! Pose2Sim's calibration TOML (`Calib_scene.toml` and the files its converters write):
//! one table per camera with `name`, `size = [w, h]`, `matrix` (K), `distortions` (OpenCV
//! `k1 k2 p1 p2 [k3 …]`, or fisheye `k1..k4` with `fisheye = true`), `rotation` (a
//! Rodrigues vector, world-to-camera), `translation` (metres), and a `[metadata]` table
//! (`adjusted`, `error`) that is not a camera.
//!
//! Recognised by its shape ([`is_pose2sim`]): no `cameras` table (that is Caliscope's), and
//! a camera table with `distortions`, a 3-number `rotation` and a `fisheye` flag, or a
//! `[metadata]` table beside camera tables. Parsed strictly, so a missing key names its
//! table.

use serde::Deserialize;
use serde_json::Value;
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::{OPENCV_PIXEL_OFFSET, check_rotation, rodrigues};

/// One camera table of a Pose2Sim calibration.
#[derive(Debug, Deserialize)]
struct Pose2SimCamera {
    name: Option<String>,
    size: [f64; 2],
    matrix: [[f64; 3]; 3],
    distortions: Vec<f64>,
    rotation: [f64; 3],
    translation: [f64; 3],
    #[serde(default)]
    fisheye: bool,
}

fn is_camera_table(v: &Value) -> bool {
    v.get("matrix").is_some() && v.get("distortions").is_some()
}

/// Whether a parsed TOML file is a Pose2Sim calibration.
pub fn is_pose2sim(v: &Value) -> bool {
    let Value::Object(tables) = v else {
        return false;
    };
    if tables.contains_key("cameras") {
        return false;
    }
    let cameras: Vec<&Value> = tables.values().filter(|t| is_camera_table(t)).collect();
    let pose2sim_camera = |c: &&Value| {
        c.get("fisheye").is_some()
            && c.get("rotation")
                .and_then(Value::as_array)
                .is_some_and(|r| r.len() == 3)
    };
    !cameras.is_empty()
        && (tables.get("metadata").is_some_and(Value::is_object)
            || cameras.iter().any(pose2sim_camera))
}

/// The cameras of a Pose2Sim calibration (`Err`: the table and what is wrong with it),
/// named by their `name` key (the table's name without one), in the file's order.
pub fn cameras(v: &Value) -> Result<Vec<Camera>, (String, String)> {
    let Value::Object(tables) = v else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for (table, c) in tables {
        if table == "metadata" || !c.is_object() {
            continue;
        }
        let camera = serde_json::from_value::<Pose2SimCamera>(c.clone())
            .map_err(|e| e.to_string())
            .and_then(|c| camera(table, c))
            .map_err(|e| (table.clone(), e))?;
        out.push(camera);
    }
    Ok(out)
}

fn camera(table: &str, c: Pose2SimCamera) -> Result<Camera, String> {
    let [w, h] = c.size;
    if [w, h]
        .iter()
        .any(|&s| s < 1.0 || s.fract() != 0.0 || s > f64::from(u32::MAX))
    {
        return Err(format!("size {:?} is not a whole number of pixels", c.size));
    }
    let k = c.matrix;
    if k[1][0] != 0.0 || k[2][0] != 0.0 || k[2][1] != 0.0 || k[2][2] != 1.0 {
        return Err(format!(
            "matrix {k:?} is not [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
        ));
    }
    if k[0][1].abs() > 1e-6 * k[0][0].abs() {
        return Err(format!(
            "matrix has skew {}, which the engine does not model; recalibrate with zero skew",
            k[0][1]
        ));
    }
    let distortion = if c.distortions.iter().all(|&d| d == 0.0) {
        Distortion::None
    } else if c.fisheye {
        match c.distortions[..] {
            [k1, k2, k3, k4] => Distortion::Fisheye { k1, k2, k3, k4 },
            _ => {
                return Err(format!(
                    "fisheye = true takes 4 distortions (k1..k4), found {}",
                    c.distortions.len()
                ));
            }
        }
    } else {
        Distortion::from_opencv_coefficients(&c.distortions)?
    };
    let r = rodrigues(glam::DVec3::from_array(c.rotation));
    check_rotation(&r)?;
    Ok(Camera {
        name: c.name.unwrap_or_else(|| table.to_string()),
        intrinsics: Intrinsics {
            width: w as u32,
            height: h as u32,
            fx: k[0][0],
            fy: k[1][1],
            // Pose2Sim calibrates with OpenCV: pixel centres at integers.
            cx: k[0][2] + OPENCV_PIXEL_OFFSET,
            cy: k[1][2] + OPENCV_PIXEL_OFFSET,
        },
        distortion,
        world_to_camera: WorldToCamera::from_parts(r, glam::DVec3::from_array(c.translation)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Value {
        serde_json::to_value(toml::from_str::<toml::Value>(text).unwrap()).unwrap()
    }

    const CAM: &str = "name = \"c\"\nsize = [ 640.0, 480.0,]\nmatrix = [ [ 500.0, 0.0, 320.0,], [ 0.0, 500.0, 240.0,], [ 0.0, 0.0, 1.0,],]\ndistortions = [ -0.1, 0.01, 0.0, 0.0,]\nrotation = [ 0.0, 0.0, 0.0,]\ntranslation = [ 0.0, 0.0, 2.0,]\n";

    #[test]
    fn recognised_by_shape_not_by_name() {
        let file =
            format!("[cam_1]\n{CAM}fisheye = false\n\n[metadata]\nadjusted = false\nerror = 0.0\n");
        assert!(is_pose2sim(&parse(&file)));
        // Without metadata, the fisheye flag says it.
        assert!(is_pose2sim(&parse(&format!("[a]\n{CAM}fisheye = true\n"))));
        // Caliscope keeps its cameras under `cameras`.
        assert!(!is_pose2sim(&parse(&format!(
            "[cameras.0]\n{CAM}fisheye = false\n"
        ))));
        assert!(!is_pose2sim(&parse(&format!("[a]\n{CAM}"))));
    }

    #[test]
    fn fisheye_flag_and_errors_name_the_table() {
        let v = parse(&format!(
            "[cam_1]\n{}fisheye = true\n[metadata]\nadjusted = false\n",
            CAM.replace("-0.1, 0.01, 0.0, 0.0", "0.05, -0.01, 0.002, 0.0")
        ));
        let cams = cameras(&v).unwrap();
        assert_eq!(cams.len(), 1);
        assert_eq!(
            cams[0].distortion,
            Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: 0.0
            }
        );
        let v = parse(&format!(
            "[cam_2]\n{}fisheye = false\n",
            CAM.replace("rotation = [ 0.0, 0.0, 0.0,]\n", "")
        ));
        let (table, e) = cameras(&v).unwrap_err();
        assert_eq!(table, "cam_2");
        assert!(e.contains("rotation"), "{e}");
    }
}
