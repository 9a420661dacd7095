//! Triangulating points with cameras that are already known (COLMAP's FAQ "reconstruct a
//! sparse model from known camera poses"): `feature_extractor` → the known intrinsics
//! written into the database's cameras → `exhaustive_matcher` → a text model holding the
//! known intrinsics and poses under the database's own image and camera IDs →
//! `point_triangulator` with intrinsics and poses held fixed.
//!
//! Workspace layout (`<root>`, one per set of simultaneous images):
//! ```text
//! <root>/images/video/<cam>/<cam>.<ext>   one folder, so one COLMAP camera, per camera
//! <root>/database.db                      features and matches
//! <root>/known/                           the known model (text), no points
//! <root>/triangulated/                    point_triangulator's output
//! <root>/logs/<step>.log                  everything COLMAP printed
//! ```
//! Unlike [`super::database`], this module writes to the database (the cameras table only).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DQuat;
use rusqlite::{Connection, params};
use shared_types::{Camera, Progress};

use super::{ColmapError, DatabaseError, VideoCameras, Workspace, args, io_err};
use crate::colmap::{CameraModel, ColmapImage, ColmapModel, ModelFormat};
use crate::convert::pinhole_from_engine;

/// One image of a known, distortion-free (pinhole) camera.
#[derive(Clone, Debug)]
pub struct KnownView {
    /// Camera name: the image's folder in the workspace, so one COLMAP camera each.
    pub name: String,
    /// The camera the image was taken with; its distortion must be none.
    pub camera: Camera,
    pub image: PathBuf,
}

/// How the triangulation is run.
#[derive(Clone, Debug, PartialEq)]
pub struct KnownPosesOptions {
    /// Longest image side SIFT works on.
    pub max_image_size: u32,
    /// Most SIFT features kept per image.
    pub max_num_features: u32,
    /// Keep points seen by only two images (COLMAP drops them by default; with 4 cameras
    /// most points are seen by two).
    pub two_view_tracks: bool,
    /// Points reprojecting worse than this (pixels) are dropped (`filter_max_reproj_error`).
    pub max_reprojection_error: f64,
    /// Threads for extraction, matching and triangulation (`-1`: all cores). One thread
    /// makes a run repeatable (COLMAP numbers images in the order they finish).
    pub num_threads: i32,
    pub random_seed: u32,
}

impl Default for KnownPosesOptions {
    fn default() -> Self {
        Self {
            max_image_size: 3200,
            max_num_features: 8192,
            two_view_tracks: true,
            max_reprojection_error: 4.0,
            num_threads: 1,
            random_seed: 0,
        }
    }
}

/// Triangulate the matches of `views` in a fresh workspace at `root` (anything there is
/// removed). Returns the triangulated model (the known cameras and poses, and the points
/// with their colour and track). Fewer than two views, or no verified match between any
/// two, is an empty model, not an error.
pub fn triangulate_known(
    binary: &Path,
    root: &Path,
    views: &[KnownView],
    options: &KnownPosesOptions,
    progress: &dyn Progress,
) -> Result<ColmapModel, ColmapError> {
    let frames: Vec<(String, PathBuf)> = views
        .iter()
        .map(|v| (v.name.clone(), v.image.clone()))
        .collect();
    let ws = Workspace::create(
        root,
        &frames,
        &[],
        super::StillsCameras::Shared,
        VideoCameras::Separate,
    )?;
    if views.len() < 2 {
        return Ok(ColmapModel::default());
    }
    let threads = options.num_threads.to_string();
    let seed = options.random_seed.to_string();
    let (db, images) = (ws.database(), ws.image_dir());
    ws.run_step(
        binary,
        "feature_extractor",
        "feature_extractor",
        args(&[
            ("--database_path", db.as_os_str()),
            ("--image_path", images.as_os_str()),
            ("--ImageReader.camera_model", "PINHOLE".as_ref()),
            ("--ImageReader.single_camera_per_folder", "1".as_ref()),
            ("--SiftExtraction.use_gpu", "0".as_ref()),
            ("--SiftExtraction.num_threads", threads.as_ref()),
            (
                "--SiftExtraction.max_image_size",
                options.max_image_size.to_string().as_ref(),
            ),
            (
                "--SiftExtraction.max_num_features",
                options.max_num_features.to_string().as_ref(),
            ),
        ]),
        progress,
    )?;
    let ids = set_known_cameras(&db, &ws, views)?;
    ws.run_step(
        binary,
        "exhaustive_matcher",
        "exhaustive_matcher",
        args(&[
            ("--database_path", db.as_os_str()),
            ("--random_seed", seed.as_ref()),
            ("--SiftMatching.use_gpu", "0".as_ref()),
            ("--SiftMatching.num_threads", threads.as_ref()),
        ]),
        progress,
    )?;
    // point_triangulator aborts (failed bundle adjustment) when nothing matched.
    if super::MatchGraph::read(&db)?.verified_matches.is_empty() {
        return Ok(ColmapModel::default());
    }
    let known = known_model(&ws, views, &ids);
    let known_dir = root.join("known");
    known.write(&known_dir, ModelFormat::Text)?;
    let out = root.join("triangulated");
    std::fs::create_dir_all(&out).map_err(io_err(&out))?;
    let keep_two = if options.two_view_tracks { "0" } else { "1" };
    ws.run_step(
        binary,
        "point_triangulator",
        "point_triangulator",
        args(&[
            ("--database_path", db.as_os_str()),
            ("--image_path", images.as_os_str()),
            ("--input_path", known_dir.as_os_str()),
            ("--output_path", out.as_os_str()),
            ("--random_seed", seed.as_ref()),
            ("--Mapper.num_threads", threads.as_ref()),
            ("--Mapper.ba_refine_focal_length", "0".as_ref()),
            ("--Mapper.ba_refine_principal_point", "0".as_ref()),
            ("--Mapper.ba_refine_extra_params", "0".as_ref()),
            ("--Mapper.tri_ignore_two_view_tracks", keep_two.as_ref()),
            (
                "--Mapper.filter_max_reproj_error",
                options.max_reprojection_error.to_string().as_ref(),
            ),
        ]),
        progress,
    )?;
    Ok(ColmapModel::read(&out)?)
}

/// Database IDs of one image: (image ID, camera ID).
type Ids = BTreeMap<String, (u32, u32)>;

/// Write each view's pinhole intrinsics into the database camera of its image (so that
/// matching verifies with the essential matrix), and return every image's IDs by name.
fn set_known_cameras(
    db_path: &Path,
    ws: &Workspace,
    views: &[KnownView],
) -> Result<Ids, ColmapError> {
    let err = |source| {
        ColmapError::Database(DatabaseError {
            path: db_path.to_path_buf(),
            source,
        })
    };
    let db = Connection::open(db_path).map_err(err)?;
    let mut ids = Ids::new();
    {
        let mut q = db
            .prepare("SELECT image_id, camera_id, name FROM images")
            .map_err(err)?;
        let rows = q
            .query_map([], |r| {
                Ok((
                    r.get::<_, u32>(0)?,
                    r.get::<_, u32>(1)?,
                    r.get::<_, String>(2)?,
                ))
            })
            .map_err(err)?;
        for row in rows {
            let (image, camera, name) = row.map_err(err)?;
            ids.insert(name, (image, camera));
        }
    }
    for (img, view) in ws.images.iter().zip(views) {
        let Some(&(_, camera_id)) = ids.get(&img.colmap_name) else {
            continue;
        };
        let cam = pinhole_from_engine(camera_id, &view.camera.intrinsics);
        let blob: Vec<u8> = cam.params.iter().flat_map(|p| p.to_le_bytes()).collect();
        db.execute(
            "UPDATE cameras SET model = ?1, width = ?2, height = ?3, params = ?4, \
             prior_focal_length = 1 WHERE camera_id = ?5",
            params![
                CameraModel::Pinhole.id(),
                cam.width as i64,
                cam.height as i64,
                blob,
                camera_id
            ],
        )
        .map_err(err)?;
    }
    Ok(ids)
}

/// The known model: each view's camera and pose under the database's IDs, no points.
/// Views whose image COLMAP did not read (no ID) are left out.
fn known_model(ws: &Workspace, views: &[KnownView], ids: &Ids) -> ColmapModel {
    let mut model = ColmapModel::default();
    for (img, view) in ws.images.iter().zip(views) {
        let Some(&(image_id, camera_id)) = ids.get(&img.colmap_name) else {
            continue;
        };
        let cam = pinhole_from_engine(camera_id, &view.camera.intrinsics);
        model.cameras.insert(camera_id, cam);
        let w2c = &view.camera.world_to_camera;
        let q = DQuat::from_mat3(&w2c.rotation()).normalize();
        model.images.insert(
            image_id,
            ColmapImage {
                id: image_id,
                qvec: [q.w, q.x, q.y, q.z],
                tvec: w2c.translation().to_array(),
                camera_id,
                name: img.colmap_name.clone(),
                points2d: Vec::new(),
            },
        );
    }
    model
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::looking_at;
    use glam::DVec3;
    use shared_types::Intrinsics;

    #[test]
    fn known_model_keeps_the_database_ids_and_the_pose() {
        let dir = tempfile::tempdir().unwrap();
        let img = dir.path().join("a.png");
        image::RgbImage::new(8, 6).save(&img).unwrap();
        let cam = looking_at(
            "cam0",
            Intrinsics::from_hfov(8, 6, 60.0),
            DVec3::new(1.0, -2.0, 0.5),
            DVec3::ZERO,
        );
        let views = [KnownView {
            name: "cam0".into(),
            camera: cam.clone(),
            image: img,
        }];
        let frames = [("cam0".to_string(), views[0].image.clone())];
        let ws = Workspace::create(
            &dir.path().join("ws"),
            &frames,
            &[],
            super::super::StillsCameras::Shared,
            VideoCameras::Separate,
        )
        .unwrap();
        let ids = Ids::from([(ws.images[0].colmap_name.clone(), (7, 3))]);
        let m = known_model(&ws, &views, &ids);
        let i = &m.images[&7];
        assert_eq!((i.camera_id, i.name.as_str()), (3, "video/cam0/cam0.png"));
        let dr = i.rotation() - cam.world_to_camera.rotation();
        assert!(dr.to_cols_array().iter().all(|v| v.abs() < 1e-12));
        assert!((i.centre() - DVec3::new(1.0, -2.0, 0.5)).length() < 1e-12);
        assert_eq!(m.cameras[&3].model, CameraModel::Pinhole);
        assert_eq!(m.cameras[&3].params[0], cam.intrinsics.fx);
    }
}
