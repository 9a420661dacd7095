//! The init stage's entry point, [`run_init`]: which source to try, the fallback chain
//! (point maps → swept or triangulated moments → sparse COLMAP points → a random cloud,
//! each fallback announced with `tracing::warn!`), the static/moving split of points found
//! at several moments, downsampling and writing `points.ply`.

use std::path::Path;
use std::time::Instant;

use calib::colmap_runner::find_colmap;
use glam::DVec3;
use shared_types::points::{read_points_ply, write_points_ply};
use shared_types::{CameraSet, Progress};

use crate::config::{InitConfig, Source};
use crate::error::InitError;
use crate::fuse::{self, FusedPoint};
use crate::inputs::{InitInputs, Moment, StillImage};
use crate::onnx::PointMapModel;
use crate::pairs::pointmap_points;
use crate::plates::Plates;
use crate::report::{InitReport, PlatesReport, UsedSource};
use crate::statics::{self, StaticCounts};
use crate::views::{View, load_views, pinhole_view, undistorted};
use crate::{moment_maps, moments, sweep};

/// Radius (× the voxel edge) within which a swept point needs `[init] min_neighbours`
/// other points.
const ISOLATION_RADIUS: f64 = 3.0;
/// Partners of each view in the sweep of the static scene (plates and stills).
const STATIC_PARTNERS: usize = 3;

/// Run the init stage: write `<out_dir>/points.ply` and report what was done.
pub fn run_init(
    inputs: &InitInputs,
    config: &InitConfig,
    out_dir: &Path,
    progress: &dyn Progress,
) -> Result<InitReport, InitError> {
    let start = Instant::now();
    let cameras = &inputs.cameras.cameras;
    if cameras.is_empty() {
        return Err(InitError::Config(
            "no cameras given; run the poses stage first".into(),
        ));
    }
    for img in &inputs.images {
        if inputs.cameras.get(&img.camera).is_none() {
            return Err(InitError::Config(format!(
                "frame {} belongs to camera {}, which is not in the poses",
                img.path.display(),
                img.camera
            )));
        }
    }
    let sparse = match &inputs.sparse {
        Some(p) if p.is_file() => read_points_ply(p)?,
        _ => shared_types::PointCloud::default(),
    };
    let sparse_xyz = sparse
        .xyz
        .iter()
        .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect::<Vec<_>>();
    let times = inputs.images.iter().map(|i| i.time).collect::<Vec<_>>();
    let moment_times = inputs.moments.iter().map(|m| m.time);
    let all_times = times
        .iter()
        .copied()
        .chain(moment_times)
        .collect::<Vec<_>>();
    let t_range = if all_times.is_empty() {
        (0.0, 0.0)
    } else {
        (
            all_times.iter().copied().fold(f64::INFINITY, f64::min),
            all_times.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let radius = fuse::rig_radius(cameras);
    let voxel = config.voxel_size.max(0.0) * radius;

    // Auto triangulates only when the caller gave moments (library callers may not).
    let triangulate = match config.source {
        Source::Triangulate | Source::Sweep => true,
        Source::Auto => config.moments > 0 && !inputs.moments.is_empty(),
        _ => false,
    };
    let mut fallbacks = Vec::new();
    let mut fall = |msg: String| {
        tracing::warn!("point init: {msg}");
        fallbacks.push(msg);
    };
    let pointmap_source = match config.source {
        Source::Onnx => match &config.model {
            Some(m) => Some((UsedSource::Onnx, m.clone())),
            None => return Err(InitError::Config("source = \"onnx\" needs `model`".into())),
        },
        Source::Npy => match &config.pointmaps {
            Some(d) => Some((UsedSource::Npy, d.clone())),
            None => {
                return Err(InitError::Config(
                    "source = \"npy\" needs `pointmaps`".into(),
                ));
            }
        },
        Source::Auto => match (&config.model, &config.pointmaps) {
            (Some(m), _) => Some((UsedSource::Onnx, m.clone())),
            (None, Some(d)) => Some((UsedSource::Npy, d.clone())),
            (None, None) => {
                let next = if triangulate {
                    "sweeping moments"
                } else {
                    "using the sparse COLMAP points"
                };
                fall(format!(
                    "no point-map model or exported point maps configured; {next}"
                ));
                None
            }
        },
        Source::Triangulate | Source::Sweep | Source::Sparse | Source::Random => None,
    };

    let mut pairs = Vec::new();
    let mut fused: Vec<FusedPoint> = Vec::new();
    let mut used = None;
    let mut moment_reports = Vec::new();
    let mut sweeps = Vec::new();
    let mut statics = StaticCounts::default();
    let mut raw_points = None;
    // Point maps of several moments are split into static and moving points (and already
    // downsampled); one moment's are downsampled below.
    let mut split = false;
    if let Some((kind, path)) = pointmap_source {
        let sets = moment_maps::sets(kind, &path, inputs, config);
        let model = match kind {
            UsedSource::Onnx => Some(PointMapModel::load(&path, &config.model_config())?),
            _ => None,
        };
        let mut timed = Vec::new();
        for (k, set) in sets.iter().enumerate() {
            let views = load_views(&inputs.cameras, set.views, config.fit)?;
            let (mut p, pts) = pointmap_points(
                kind,
                &set.dir,
                model.as_ref(),
                &views,
                &sparse_xyz,
                config,
                progress,
            )?;
            p.iter_mut().for_each(|r| r.frame = set.frame);
            pairs.extend(p);
            if sets.len() == 1 {
                fused = pts;
            } else {
                timed.extend(moment_maps::timed(&fuse::voxel_downsample(&pts, voxel), k));
            }
        }
        if sets.len() > 1 && !timed.is_empty() {
            let (pts, counts) = statics::split_static(
                &timed,
                &sparse_extra(config, &sparse_xyz, &sparse.rgb),
                config.static_radius.max(0.0) * radius,
                // Dense maps: static points as dense as moving ones (one per voxel).
                voxel,
                voxel,
                moment_maps::clip(&sets),
                None,
            );
            tracing::info!(
                "point init: point maps of {} moments: {} static points, {} moving points",
                sets.len(),
                counts.static_points,
                counts.dynamic_points
            );
            raw_points = Some(timed.len() + counts.sparse_merged);
            statics = counts;
            fused = pts;
            split = true;
        }
        if fused.is_empty() {
            fall(format!(
                "no usable point-map pair ({} of {} rejected); using the sparse COLMAP points",
                pairs.iter().filter(|p| !p.accepted).count(),
                pairs.len()
            ));
        } else {
            used = Some(kind);
        }
    }
    // Points of several moments (swept and/or triangulated), told static or moving below.
    let chosen = &inputs.moments[..inputs.moments.len().min(config.moments)];
    let mut timed = Vec::new();
    let mut timed_source = None;
    // Without point maps the dense sweep comes first (`auto` too): on the simulated demo
    // it beats COLMAP's triangulated points by 1.8 dB held out (docs/init.md).
    let sweep = config.source == Source::Sweep || (config.source == Source::Auto && triangulate);
    if used.is_none() && sweep {
        let points;
        (sweeps, points) = sweep_moments(chosen, &inputs.cameras, config, progress)?;
        if points.is_empty() {
            fall(format!(
                "the plane sweep confirmed no depth at {} moments; triangulating moments",
                chosen.len()
            ));
        } else {
            timed = points;
            timed_source = Some(UsedSource::Swept);
        }
    }
    if used.is_none() && timed.is_empty() && triangulate {
        let binary = find_colmap(config.colmap.as_deref());
        match (chosen.is_empty(), binary) {
            (true, _) => {
                fall("no moments to triangulate (`[init] moments` = 0 or no frames)".into())
            }
            (false, Err(e)) => fall(format!("cannot triangulate moments: {e}")),
            (false, Ok(binary)) => {
                let work = out_dir.join("triangulate");
                std::fs::create_dir_all(&work).map_err(|source| InitError::Io {
                    path: work.clone(),
                    source,
                })?;
                let (reports, points) = moments::triangulate_moments(
                    chosen,
                    &inputs.cameras,
                    config,
                    &binary,
                    &work,
                    progress,
                )?;
                moment_reports = reports;
                if points.is_empty() {
                    fall(format!(
                        "no moment gave triangulated points ({} tried; COLMAP logs in triangulate/mNN/logs/ of the init output)",
                        chosen.len()
                    ));
                } else {
                    timed = points;
                    timed_source = Some(UsedSource::Triangulated);
                }
            }
        }
    }
    let mut plates_report = None;
    let mut isolated = 0;
    if timed_source == Some(UsedSource::Swept) {
        // A swept depth with no neighbours is a false match: left in, it would start a
        // large Gaussian (scales come from neighbour distances) floating in mid-air.
        let xyz: Vec<DVec3> = timed.iter().map(|p| p.xyz).collect();
        let keep = fuse::supported(&xyz, ISOLATION_RADIUS * voxel, config.min_neighbours);
        let before = timed.len();
        timed = timed
            .into_iter()
            .zip(keep)
            .filter_map(|(p, k)| k.then_some(p))
            .collect();
        isolated = before - timed.len();
    }
    let mut still_sweep = None;
    // The moving points' share of the moments' points, which the cap keeps.
    let mut moving_share = None;
    if let Some(source) = timed_source {
        let plates = plates_of(inputs, config, progress)?;
        let tagged = plates
            .as_ref()
            .map(|p| plate_tags(p, inputs.plate_frames.len(), &timed, chosen))
            .transpose()?;
        let tags = tagged.as_ref().map(|(t, _)| t.as_slice());
        let mut extra = sparse_extra(config, &sparse_xyz, &sparse.rgb);
        let (mut pts, mut counts) =
            split_moments(&timed, chosen, config, &extra, radius, voxel, tags);
        moving_share = Some(counts.dynamic_points as f64 / pts.len().max(1) as f64);
        if source == UsedSource::Swept && config.sweep_stills && !inputs.stills.is_empty() {
            // The stills' points join the static ones (split again, a second's work);
            // the moving points keep the share of the cap the moments alone give them.
            let (points, report) = sweep_stills(plates.as_ref(), &inputs.stills, config)?;
            extra.extend(points);
            still_sweep = Some(report);
            (pts, counts) = split_moments(&timed, chosen, config, &extra, radius, voxel, tags);
        }
        plates_report = tagged.map(|(_, r)| r);
        raw_points = Some(timed.len() + counts.sparse_merged);
        statics = counts;
        fused = pts;
        used = Some(source);
    } else if used.is_none() && triangulate {
        fall("no moment gave points; using the sparse COLMAP points".into());
    }
    if used.is_none() && config.source != Source::Random {
        if sparse.xyz.is_empty() {
            fall(
                "no sparse COLMAP points; using a random cloud in the cameras' common view volume"
                    .into(),
            );
        } else {
            // The solve's points carry no moment: static over the clip's known range.
            let (t0, t1) = t_range;
            fused = sparse_xyz
                .iter()
                .zip(&sparse.rgb)
                .map(|(p, c)| FusedPoint {
                    xyz: *p,
                    rgb: c.map(f32::from),
                    time: 0.5 * (t0 + t1),
                    time_span: t1 - t0,
                })
                .collect();
            used = Some(UsedSource::Sparse);
        }
    }
    let points_before = raw_points.unwrap_or(fused.len());
    let (source, downsampled) = match used {
        Some(s @ (UsedSource::Onnx | UsedSource::Npy)) if !split => {
            (s, fuse::voxel_downsample(&fused, voxel))
        }
        Some(s) => (s, fused),
        None => (
            UsedSource::Random,
            fuse::random_cloud(cameras, config.random_points, t_range, config.seed),
        ),
    };
    let mut downsampled = downsampled;
    if source != UsedSource::Random && downsampled.len() < config.min_points {
        fall(format!(
            "only {} points from {source:?} (fewer than min_points = {}); adding a random cloud of {} points",
            downsampled.len(),
            config.min_points,
            config.random_points
        ));
        downsampled.extend(fuse::random_cloud(
            cameras,
            config.random_points,
            t_range,
            config.seed,
        ));
    }
    let points_before = if source == UsedSource::Random {
        downsampled.len()
    } else {
        points_before
    };
    let points_after_voxel = downsampled.len();
    let kept = match moving_share {
        Some(share) => fuse::cap_shared(downsampled, config.max_points, share, config.seed),
        None => fuse::cap(downsampled, config.max_points, config.seed),
    };
    std::fs::create_dir_all(out_dir).map_err(|source| InitError::Io {
        path: out_dir.into(),
        source,
    })?;
    let output = out_dir.join("points.ply");
    write_points_ply(&fuse::to_cloud(&kept), &output)?;
    Ok(InitReport {
        source,
        fallbacks,
        pairs,
        moments: moment_reports,
        sweeps,
        still_sweep,
        statics,
        plates: plates_report,
        isolated,
        points_before,
        points_after_voxel,
        points_written: kept.len(),
        voxel,
        output,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The cameras' static plates from `[init] plates` frames each; `None` when that is 0 or
/// the caller gave no frames for them.
fn plates_of(
    inputs: &InitInputs,
    config: &InitConfig,
    progress: &dyn Progress,
) -> Result<Option<Plates>, InitError> {
    if config.plates == 0 || inputs.plate_frames.is_empty() {
        return Ok(None);
    }
    progress.message("static plates");
    let plates = Plates::new(
        &inputs.cameras,
        &inputs.plate_frames,
        config.motion_threshold,
    )?;
    Ok((!plates.is_empty()).then_some(plates))
}

/// Static tags of `points` (found at `moments`) from the cameras' static `plates` (of
/// `frames` frames in all), and what the plates did.
fn plate_tags(
    plates: &Plates,
    frames: usize,
    points: &[statics::TimedPoint],
    moments: &[Moment],
) -> Result<(Vec<bool>, PlatesReport), InitError> {
    let (tags, moving_fraction) = plates.static_tags(points, moments)?;
    let frames_per_camera = frames / plates.len();
    tracing::info!(
        "point init: static plates of {} cameras ({} frames each); {:.1} % of the moments' pixels move",
        plates.len(),
        frames_per_camera,
        100.0 * moving_fraction.iter().sum::<f64>() / moving_fraction.len().max(1) as f64
    );
    Ok((
        tags,
        PlatesReport {
            cameras: plates.len(),
            frames_per_camera,
            moving_fraction,
        },
    ))
}

/// The static scene swept ([`sweep::sweep_static`]) in the cameras' static `plates` and
/// the `stills`, each view against its [`STATIC_PARTNERS`] best-placed partners: the
/// confirmed points (coloured) and what the sweep did.
fn sweep_stills(
    plates: Option<&Plates>,
    stills: &[StillImage],
    config: &InitConfig,
) -> Result<(Vec<sweep::ColouredPoint>, sweep::SweepReport), InitError> {
    let start = Instant::now();
    let mut views = Vec::new();
    for (camera, plate) in plates.map_or(&[][..], |p| p.images()) {
        let what = format!("the static plate of {}", camera.name);
        let (camera, image) = undistorted(camera, plate.clone(), config.fit, &what)?;
        views.push(View {
            camera,
            image,
            time: 0.0,
        });
    }
    for still in stills {
        let (camera, image) = pinhole_view(&still.camera, &still.path, config.fit)?;
        views.push(View {
            camera,
            image,
            time: 0.0,
        });
    }
    let refs: Vec<&View> = views.iter().collect();
    let (points, mut report) = sweep::sweep_static(&refs, STATIC_PARTNERS, &config.sweep_options());
    report.seconds = start.elapsed().as_secs_f64();
    tracing::info!(
        "point init: the static scene swept in {} plates and {} stills: {} of {} pixels matched, {} confirmed",
        plates.map_or(0, Plates::len),
        stills.len(),
        report.matched,
        report.pixels,
        report.points
    );
    Ok((points, report))
}

/// Sweep every moment of `moments` ([`sweep::sweep_moment`]): each moment's report and
/// all confirmed points.
fn sweep_moments(
    moments: &[Moment],
    cameras: &CameraSet,
    config: &InitConfig,
    progress: &dyn Progress,
) -> Result<(Vec<sweep::SweepReport>, Vec<statics::TimedPoint>), InitError> {
    let options = config.sweep_options();
    progress.start(moments.len() as u64, "moments swept");
    let (mut reports, mut points) = (Vec::new(), Vec::new());
    for (k, moment) in moments.iter().enumerate() {
        progress.message(&format!(
            "moment {}/{} (frame {})",
            k + 1,
            moments.len(),
            moment.frame
        ));
        let start = Instant::now();
        let views = load_views(cameras, &moment.views, config.fit)?;
        let views: Vec<&View> = views.iter().map(|(_, v)| v).collect();
        let (pts, mut report) = sweep::sweep_moment(&views, k, moment.time, &options);
        report.frame = moment.frame;
        report.seconds = start.elapsed().as_secs_f64();
        tracing::info!(
            "point init: moment {} (frame {}) swept: {} of {} pixels matched, {} confirmed",
            k + 1,
            moment.frame,
            report.matched,
            report.pixels,
            report.points
        );
        points.extend(pts);
        reports.push(report);
        progress.advance(1);
    }
    progress.finish();
    Ok((reports, points))
}

/// Points found at several `moments` told static or moving ([`statics::split_static`]; by
/// the plates' `tags` when given), with the pose solve's sparse points as static extras.
fn split_moments(
    points: &[statics::TimedPoint],
    moments: &[Moment],
    config: &InitConfig,
    sparse: &[(DVec3, [f32; 3])],
    radius: f64,
    voxel: f64,
    tags: Option<&[bool]>,
) -> (Vec<FusedPoint>, StaticCounts) {
    let clip = (
        moments.iter().map(|m| m.time).fold(f64::INFINITY, f64::min),
        moments
            .iter()
            .map(|m| m.time)
            .fold(f64::NEG_INFINITY, f64::max),
    );
    let static_radius = config.static_radius.max(0.0) * radius;
    let (pts, counts) = statics::split_static(
        points,
        sparse,
        static_radius,
        static_radius,
        voxel,
        clip,
        tags,
    );
    tracing::info!(
        "point init: {} static points ({} sparse merged), {} moving points",
        counts.static_points,
        counts.sparse_merged,
        counts.dynamic_points
    );
    (pts, counts)
}

/// The pose solve's sparse points as static extras of a static/moving split, when
/// `merge_sparse` is set.
fn sparse_extra(config: &InitConfig, xyz: &[DVec3], rgb: &[[u8; 3]]) -> Vec<(DVec3, [f32; 3])> {
    if !config.merge_sparse {
        return Vec::new();
    }
    xyz.iter()
        .zip(rgb)
        .map(|(p, c)| (*p, c.map(f32::from)))
        .collect()
}
