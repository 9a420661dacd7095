//! Writing the stage's outputs, for solved and imported cameras alike: normalise cameras
//! and sparse points, then write `points3d.ply` and `cameras.json`, each atomically.
//! `points3d.ply` is a binary little-endian PLY point cloud: `x y z` float, `red green
//! blue` uchar, and the comment line `4C4D sparse points, normalised frame`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use shared_types::atomic::write_atomic;
use shared_types::ply::PlyTable;
use shared_types::points::{PointCloud, points_table};
use shared_types::{Camera, CameraSet, Intrinsics};

use super::capture_cameras::{CaptureCamera, select_cameras};
use super::error::PosesError;
use super::file::{PoseSource, PosesFile};
use super::normalise::normalisation_for;
use super::sizes::{SizeRelation, size_relation};

/// The comment line of `points3d.ply`.
const POINTS_COMMENT: &str = "4C4D sparse points, normalised frame";

/// One sparse point, normalised frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparsePoint {
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
}

/// What [`super::solve()`] or [`write_imported`] produced.
#[derive(Clone, Debug)]
pub struct PosesOutput {
    pub file: PosesFile,
    pub points: Vec<SparsePoint>,
    pub cameras_json: PathBuf,
    pub points_ply: Option<PathBuf>,
}

/// Normalise and write an imported (or otherwise known) camera set as the poses stage's
/// output, with no sparse points: the calibration's camera of each of the capture's camera
/// `folders` (through `names`, see [`select_cameras`]), renamed to its folder, intrinsics
/// fitted to its video and working sizes. `from` is the calibration file.
pub fn write_imported(
    set: &CameraSet,
    from: &Path,
    out_dir: &Path,
    folders: &[CaptureCamera],
    names: &BTreeMap<String, String>,
    radius: f64,
) -> Result<PosesOutput, PosesError> {
    let stale = out_dir.join("points3d.ply");
    if stale.exists() {
        std::fs::remove_file(&stale).map_err(|source| PosesError::Io {
            path: stale,
            source,
        })?;
    }
    let cameras = select_cameras(set, folders, names, from)?;
    let source = PoseSource::Import {
        path: from.to_path_buf(),
    };
    write_outputs(out_dir, cameras, Vec::new(), Vec::new(), source, radius)
}

/// Intrinsics for the working size: a resize (same aspect ratio up to a pixel of rounding)
/// is scaled; any other change of aspect ratio is refused (it would be a crop, not a
/// resize). Calibration imports go through [`super::fit_intrinsics`] instead, which also
/// knows codec padding.
pub fn scale_intrinsics(
    camera: &str,
    intr: &Intrinsics,
    working_size: Option<(u32, u32)>,
) -> Result<Intrinsics, PosesError> {
    let Some((w, h)) = working_size else {
        return Ok(*intr);
    };
    match size_relation((intr.width, intr.height), (w, h)) {
        SizeRelation::Same | SizeRelation::Resized => Ok(intr.scaled_to(w, h)),
        SizeRelation::CodecPadding | SizeRelation::Different => Err(PosesError::AspectMismatch {
            camera: camera.to_string(),
            calibrated: (intr.width, intr.height),
            working: (w, h),
        }),
    }
}

/// Normalise `cameras`, `points` and `stills` (the video cameras at mean distance
/// `radius` from their centre) and write `points3d.ply` (when there are points) and
/// `cameras.json`.
pub(super) fn write_outputs(
    out_dir: &Path,
    cameras: Vec<Camera>,
    points: Vec<SparsePoint>,
    stills: Vec<Camera>,
    source: PoseSource,
    radius: f64,
) -> Result<PosesOutput, PosesError> {
    let xyz: Vec<DVec3> = points.iter().map(|p| DVec3::from_array(p.xyz)).collect();
    let norm = normalisation_for(&cameras, &xyz, radius);
    let normalised = |cameras: Vec<Camera>| -> Vec<Camera> {
        cameras
            .into_iter()
            .map(|c| Camera {
                world_to_camera: norm.apply_to_pose(&c.world_to_camera),
                ..c
            })
            .collect()
    };
    let (cameras, stills) = (normalised(cameras), normalised(stills));
    let points: Vec<SparsePoint> = points
        .into_iter()
        .map(|p| SparsePoint {
            xyz: norm.apply(DVec3::from_array(p.xyz)).to_array(),
            ..p
        })
        .collect();
    std::fs::create_dir_all(out_dir).map_err(|source| PosesError::Io {
        path: out_dir.to_path_buf(),
        source,
    })?;
    let points_ply = (!points.is_empty()).then(|| out_dir.join("points3d.ply"));
    if let Some(ply) = &points_ply {
        write_atomic(ply, &sparse_points_table(&points).encode()).map_err(|source| {
            PosesError::Io {
                path: ply.clone(),
                source,
            }
        })?;
    }
    let file = PosesFile {
        set: CameraSet::new(cameras),
        normalisation: norm,
        source,
        points_file: points_ply.as_ref().map(|_| "points3d.ply".to_string()),
        num_points: points.len(),
        stills,
    };
    let cameras_json = out_dir.join("cameras.json");
    shared_types::atomic::write_json(&cameras_json, &file).map_err(|source| PosesError::Io {
        path: cameras_json.clone(),
        source,
    })?;
    Ok(PosesOutput {
        file,
        points,
        cameras_json,
        points_ply,
    })
}

/// The `points3d.ply` table of `points`.
fn sparse_points_table(points: &[SparsePoint]) -> PlyTable {
    let cloud = PointCloud {
        xyz: points.iter().map(|p| p.xyz.map(|v| v as f32)).collect(),
        rgb: points.iter().map(|p| p.rgb).collect(),
        time: None,
        time_span: None,
    };
    points_table(&cloud, vec![POINTS_COMMENT.to_string()])
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::WorldToCamera;
    use shared_types::ply::Scalar;

    #[test]
    fn points_ply_has_xyz_floats_rgb_bytes_and_its_comment() {
        let pts = [
            SparsePoint {
                xyz: [1.0, -2.0, 0.5],
                rgb: [255, 0, 7],
            },
            SparsePoint {
                xyz: [0.0, 0.0, 0.0],
                rgb: [1, 2, 3],
            },
        ];
        let table = PlyTable::decode(&sparse_points_table(&pts).encode()).unwrap();
        assert_eq!(table.comments, [POINTS_COMMENT]);
        assert_eq!(table.names, ["x", "y", "z", "red", "green", "blue"]);
        // 15 bytes per point: three floats, three bytes.
        assert_eq!(
            table.types,
            [
                Scalar::F32,
                Scalar::F32,
                Scalar::F32,
                Scalar::U8,
                Scalar::U8,
                Scalar::U8
            ]
        );
        assert_eq!(table.rows(), 2);
        assert_eq!(table.data[1], -2.0);
        assert_eq!(&table.data[3..6], &[255.0, 0.0, 7.0]);
    }

    #[test]
    fn poses_file_round_trips_and_reads_as_a_camera_set() {
        let dir = std::env::temp_dir().join(format!("calib_poses_file_{}", std::process::id()));
        let cam = Camera {
            name: "cam0".into(),
            intrinsics: Intrinsics::from_hfov(64, 48, 60.0),
            distortion: Default::default(),
            world_to_camera: WorldToCamera::IDENTITY,
        };
        let other = Camera {
            name: "cam1".into(),
            world_to_camera: WorldToCamera::from_parts(
                glam::DMat3::IDENTITY,
                glam::DVec3::new(-2.0, 0.0, 0.0),
            ),
            ..cam.clone()
        };
        // A still 1 m beyond cam1 (cameras at 0 and 2 m, 1 m from their centre: scale 1).
        let still = Camera {
            name: "still_00.jpg".into(),
            intrinsics: Intrinsics::from_hfov(80, 60, 50.0),
            world_to_camera: WorldToCamera::from_parts(
                glam::DMat3::IDENTITY,
                glam::DVec3::new(-3.0, 0.0, 0.0),
            ),
            ..cam.clone()
        };
        let out = write_outputs(
            &dir,
            vec![cam, other],
            vec![SparsePoint {
                xyz: [1.0, 0.0, 3.0],
                rgb: [9, 9, 9],
            }],
            vec![still],
            PoseSource::Import {
                path: "x.json".into(),
            },
            1.0,
        )
        .unwrap();
        let back = PosesFile::read(&out.cameras_json).unwrap();
        assert_eq!(back.normalisation, out.file.normalisation);
        assert_eq!(back.num_points, 1);
        // The still in the cameras' normalised frame: 3 m from cam0 → 3 units.
        assert_eq!(back.stills.len(), 1);
        let (c0, s0) = (
            back.set.cameras[0].world_to_camera.centre(),
            back.stills[0].world_to_camera.centre(),
        );
        assert!(((s0 - c0).length() - 3.0).abs() < 1e-9, "{c0} {s0}");
        assert_eq!(back.stills[0].intrinsics.width, 80);
        let set: CameraSet =
            serde_json::from_str(&std::fs::read_to_string(&out.cameras_json).unwrap()).unwrap();
        assert_eq!(set.cameras.len(), 2);
        assert!(PosesFile::read(&dir.join("missing.json")).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
