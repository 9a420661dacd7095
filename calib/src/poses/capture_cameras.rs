//! The capture's cameras in an imported calibration: each camera folder (training and
//! held-out) must have its camera in the calibration, found by the folder's name or by the
//! name `[poses] names` maps it to (`names = { cam0 = "cam01" }`). The cameras come out
//! renamed to their folders, in the folders' order, with intrinsics for the frames'
//! working size ([`super::sizes`]); the calibration's other cameras are left out.

use std::collections::BTreeMap;
use std::path::Path;

use shared_types::{Camera, CameraSet};

use super::error::PosesError;
use super::sizes::fit_intrinsics;

/// One camera folder of the capture (`raw/<name>/`) as the poses stage must describe it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CaptureCamera {
    /// The folder's name: the camera's name in every output.
    pub name: String,
    /// Size of the recorded video (`streams.json`); `None`: the working size.
    pub recorded: Option<(u32, u32)>,
    /// Size of the aligned frames the engine sees (`frames.json`).
    pub working: (u32, u32),
}

/// The calibration's camera for each of `folders`, renamed to its folder and fitted to its
/// sizes. `names` maps folder names to calibration names; `file` is the calibration, for
/// the errors.
pub fn select_cameras(
    set: &CameraSet,
    folders: &[CaptureCamera],
    names: &BTreeMap<String, String>,
    file: &Path,
) -> Result<Vec<Camera>, PosesError> {
    let folder_names: Vec<String> = folders.iter().map(|f| f.name.clone()).collect();
    if let Some(unknown) = names.keys().find(|k| !folder_names.contains(k)) {
        return Err(PosesError::UnknownNamedFolder {
            folder: unknown.clone(),
            folders: folder_names,
        });
    }
    let calibration_name = |folder: &str| {
        names
            .get(folder)
            .cloned()
            .unwrap_or_else(|| folder.to_string())
    };
    let missing: Vec<(String, String)> = folders
        .iter()
        .filter(|f| set.get(&calibration_name(&f.name)).is_none())
        .map(|f| (f.name.clone(), calibration_name(&f.name)))
        .collect();
    if !missing.is_empty() {
        let calibration: Vec<String> = set.cameras.iter().map(|c| c.name.clone()).collect();
        let suggestion = suggest_names(&folder_names, &calibration);
        return Err(PosesError::CalibrationMissesCameras {
            file: file.to_path_buf(),
            missing,
            calibration,
            folders: folder_names,
            suggestion,
        });
    }
    let mut cameras = Vec::with_capacity(folders.len());
    for folder in folders {
        let mut camera = set
            .get(&calibration_name(&folder.name))
            .expect("checked above")
            .clone();
        let video = folder.recorded.unwrap_or(folder.working);
        camera.intrinsics = fit_intrinsics(
            &folder.name,
            &camera.intrinsics,
            file,
            video,
            folder.working,
        )?;
        camera.name = folder.name.clone();
        cameras.push(camera);
    }
    let left_out = set.cameras.len() - cameras.len();
    if left_out > 0 {
        tracing::info!(
            "the calibration {} has {left_out} camera(s) without a folder in raw/; they are left out",
            file.display()
        );
    }
    Ok(cameras)
}

/// The number in a camera name (`cam01` → 1, `int_cam3_img` → 3), if it has exactly one.
fn camera_number(name: &str) -> Option<u64> {
    let mut groups = name
        .split(|c: char| !c.is_ascii_digit())
        .filter(|g| !g.is_empty());
    let n = groups.next()?.parse().ok()?;
    groups.next().is_none().then_some(n)
}

/// A `[poses] names` line pairing each folder with the one calibration camera carrying
/// the same number, when every folder has exactly one such camera.
fn suggest_names(folders: &[String], calibration: &[String]) -> Option<String> {
    let mut pairs = Vec::new();
    for folder in folders {
        let n = camera_number(folder)?;
        let mut matches = calibration.iter().filter(|c| camera_number(c) == Some(n));
        let found = matches.next()?;
        if matches.next().is_some() {
            return None;
        }
        pairs.push(format!("{folder} = \"{found}\""));
    }
    Some(format!("names = {{ {} }}", pairs.join(", ")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::{Intrinsics, WorldToCamera};

    fn set(names: &[&str]) -> CameraSet {
        CameraSet::new(
            names
                .iter()
                .map(|n| Camera {
                    name: n.to_string(),
                    intrinsics: Intrinsics::from_hfov(1920, 1080, 90.0),
                    distortion: Default::default(),
                    world_to_camera: WorldToCamera::IDENTITY,
                })
                .collect(),
        )
    }

    fn folders(names: &[&str]) -> Vec<CaptureCamera> {
        names
            .iter()
            .map(|n| CaptureCamera {
                name: n.to_string(),
                recorded: Some((1920, 1080)),
                working: (960, 540),
            })
            .collect()
    }

    #[test]
    fn folders_find_their_cameras_by_name_or_through_names() {
        let file = Path::new("calib.toml");
        let calib = set(&["cam00", "cam01", "cam02", "extra"]);
        let capture = folders(&["cam1", "cam0"]);
        let e = select_cameras(&calib, &capture, &BTreeMap::new(), file).unwrap_err();
        let text = e.to_string();
        for part in [
            "calib.toml",
            "cam00, cam01, cam02, extra",
            "cam1, cam0",
            "[poses]",
            "names = { cam1 = \"cam01\", cam0 = \"cam00\" }",
        ] {
            assert!(text.contains(part), "{part}: {text}");
        }
        let names: BTreeMap<String, String> = [("cam0", "cam00"), ("cam1", "cam01")]
            .into_iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect();
        let cams = select_cameras(&calib, &capture, &names, file).unwrap();
        let got: Vec<&str> = cams.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(got, ["cam1", "cam0"]);
        assert_eq!(
            (cams[0].intrinsics.width, cams[0].intrinsics.height),
            (960, 540)
        );
        // A name for a folder that does not exist is a typo.
        let mut typo = names.clone();
        typo.insert("cam9".into(), "cam02".into());
        let e = select_cameras(&calib, &capture, &typo, file)
            .unwrap_err()
            .to_string();
        assert!(e.contains("cam9") && e.contains("cam1, cam0"), "{e}");
    }

    #[test]
    fn camera_numbers_and_suggestions() {
        assert_eq!(camera_number("cam01"), Some(1));
        assert_eq!(camera_number("int_cam3_img"), Some(3));
        assert_eq!(camera_number("00_03"), None);
        assert_eq!(camera_number("left"), None);
        let s = |f: &[&str], c: &[&str]| {
            let f: Vec<String> = f.iter().map(|x| x.to_string()).collect();
            let c: Vec<String> = c.iter().map(|x| x.to_string()).collect();
            suggest_names(&f, &c)
        };
        assert_eq!(
            s(&["cam0"], &["cam_0", "cam_1"]).as_deref(),
            Some("names = { cam0 = \"cam_0\" }")
        );
        assert_eq!(s(&["cam0"], &["a0", "b0"]), None);
        assert_eq!(s(&["left"], &["cam0"]), None);
    }
}
