//! Points triangulated at several moments of the clip with the known cameras: at each
//! moment the training cameras' simultaneous frames are undistorted to their pinhole twins
//! and COLMAP triangulates their matches with intrinsics and poses fixed
//! ([`calib::colmap_runner::known_poses`]). Every point keeps its moment's time and
//! COLMAP's colour. A moment that fails is reported and skipped, not fatal.

use std::path::{Path, PathBuf};
use std::time::Instant;

use calib::colmap_runner::known_poses::{KnownPosesOptions, KnownView, triangulate_known};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use shared_types::{CameraSet, Progress};

use super::config::InitConfig;
use super::error::InitError;
use super::inputs::Moment;
use super::statics::TimedPoint;
use super::views::pinhole_view;

/// What one moment gave.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MomentReport {
    pub frame: usize,
    pub time: f64,
    /// Views given to COLMAP.
    pub views: usize,
    /// Points triangulated, and kept (seen by at least `min_track` views).
    pub triangulated: usize,
    pub points: usize,
    /// Mean views per kept point and mean reprojection error (pixels).
    pub mean_track: f64,
    pub mean_error_px: f64,
    pub seconds: f64,
    /// Why the moment gave nothing (`None` when it ran).
    pub error: Option<String>,
}

/// Triangulate every moment in `work/mNN/` (COLMAP logs and models are kept there; copied
/// images and the database are removed afterwards). Returns each moment's report and all
/// kept points.
pub fn triangulate_moments(
    moments: &[Moment],
    cameras: &CameraSet,
    config: &InitConfig,
    binary: &Path,
    work: &Path,
    progress: &dyn Progress,
) -> Result<(Vec<MomentReport>, Vec<TimedPoint>), InitError> {
    let options = KnownPosesOptions {
        two_view_tracks: config.min_track <= 2,
        ..KnownPosesOptions::default()
    };
    progress.start(moments.len() as u64, "moments");
    let mut reports = Vec::new();
    let mut points = Vec::new();
    for (k, moment) in moments.iter().enumerate() {
        progress.message(&format!(
            "moment {}/{} (frame {}, t = {:.3})",
            k + 1,
            moments.len(),
            moment.frame,
            moment.time
        ));
        let start = Instant::now();
        let root = work.join(format!("m{k:02}"));
        let mut report = MomentReport {
            frame: moment.frame,
            time: moment.time,
            views: 0,
            triangulated: 0,
            points: 0,
            mean_track: 0.0,
            mean_error_px: 0.0,
            seconds: 0.0,
            error: None,
        };
        // Outside `root`: the workspace is created afresh from these images.
        let staging = work.join(format!("m{k:02}-undistorted"));
        let views = known_views(moment, cameras, config, &staging)?;
        report.views = views.len();
        match triangulate_known(binary, &root, &views, &options, progress) {
            Ok(model) => {
                report.triangulated = model.points3d.len();
                let kept: Vec<_> = model
                    .points3d
                    .values()
                    .filter(|p| p.track.len() >= config.min_track.max(2))
                    .collect();
                report.points = kept.len();
                if !kept.is_empty() {
                    let n = kept.len() as f64;
                    report.mean_track = kept.iter().map(|p| p.track.len() as f64).sum::<f64>() / n;
                    report.mean_error_px = kept.iter().map(|p| p.error).sum::<f64>() / n;
                }
                points.extend(kept.iter().map(|p| TimedPoint {
                    xyz: DVec3::from_array(p.xyz),
                    rgb: p.rgb.map(f32::from),
                    moment: k,
                    time: moment.time,
                }));
                tracing::info!(
                    "point init: moment {} (frame {}): {} points",
                    k + 1,
                    moment.frame,
                    report.points
                );
            }
            Err(e) => {
                tracing::warn!(
                    "point init: moment {} (frame {}) gave no points: {e}",
                    k + 1,
                    moment.frame
                );
                report.error = Some(e.to_string());
            }
        }
        for leftover in [root.join("images"), staging] {
            let _ = std::fs::remove_dir_all(leftover);
        }
        let _ = std::fs::remove_file(root.join("database.db"));
        report.seconds = start.elapsed().as_secs_f64();
        reports.push(report);
        progress.advance(1);
    }
    progress.finish();
    Ok((reports, points))
}

/// The moment's frames as pinhole views: a frame of a camera with a lens is undistorted
/// into `staging`; cameras not in the poses are left out with a warning.
fn known_views(
    moment: &Moment,
    cameras: &CameraSet,
    config: &InitConfig,
    staging: &Path,
) -> Result<Vec<KnownView>, InitError> {
    let mut views = Vec::new();
    for view in &moment.views {
        let Some(cam) = cameras.get(&view.camera) else {
            tracing::warn!(
                "point init: frame {} belongs to camera {}, which is not in the poses; left out",
                view.path.display(),
                view.camera
            );
            continue;
        };
        let (camera, image) = if cam.distortion.is_none() {
            let want = (cam.intrinsics.width, cam.intrinsics.height);
            let got = image::image_dimensions(&view.path).map_err(|source| InitError::Image {
                path: view.path.clone(),
                source,
            })?;
            if got != want {
                return Err(InitError::ImageSize {
                    path: view.path.clone(),
                    camera: cam.name.clone(),
                    got,
                    want,
                });
            }
            (cam.clone(), view.path.clone())
        } else {
            let (pinhole, rgb) = pinhole_view(cam, &view.path, config.fit)?;
            std::fs::create_dir_all(staging).map_err(|source| InitError::Io {
                path: staging.into(),
                source,
            })?;
            let path: PathBuf = staging.join(format!("{}.png", cam.name));
            rgb.save(&path).map_err(|source| InitError::Image {
                path: path.clone(),
                source,
            })?;
            (pinhole, path)
        };
        views.push(KnownView {
            name: cam.name.clone(),
            camera,
            image,
        });
    }
    Ok(views)
}
