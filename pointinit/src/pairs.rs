//! Point-map pairs: which image pairs to run or read ([`crate::Pairs`]), each pair's maps
//! from the ONNX model or exported files, checked and scaled into the posed cameras' world
//! frame ([`crate::pair_scale`]), its confident pixels turned into world points.

use std::path::Path;

use glam::DVec3;
use shared_types::{Camera, Progress};

use crate::config::{InitConfig, Pairs, PairsKeyword};
use crate::error::InitError;
use crate::fuse::{FusedPoint, colour_at, unproject};
use crate::npy::{self, NpyError, PairMaps, PointMap};
use crate::onnx::PointMapModel;
use crate::pair_scale::{Relative, pixel_centre, ray_scale, sparse_scale};
use crate::report::{PairReport, UsedSource};
use crate::views::View;

/// The pairs to process, as indices into `views`.
fn choose_pairs(
    kind: UsedSource,
    dir: &Path,
    views: &[(String, View)],
    config: &InitConfig,
) -> Result<Vec<(usize, usize)>, InitError> {
    let index = |name: &str| -> Result<usize, InitError> {
        views.iter().position(|(n, _)| n == name).ok_or_else(|| {
            InitError::Config(format!(
                "pair camera {name} has no frame or is not a training camera"
            ))
        })
    };
    Ok(match &config.pairs {
        Pairs::List(list) => {
            let mut out = Vec::new();
            for [a, b] in list {
                let (i, j) = (index(a)?, index(b)?);
                if i == j {
                    return Err(InitError::Config(format!(
                        "pair {a}/{b} uses one camera twice"
                    )));
                }
                out.push((i, j));
            }
            out
        }
        Pairs::Keyword(PairsKeyword::All) => {
            let n = views.len();
            let all = (0..n).flat_map(|i| (0..n).map(move |j| (i, j)));
            match kind {
                UsedSource::Npy => all
                    .filter(|&(i, j)| i != j && npy::has_pair(dir, &views[i].0, &views[j].0))
                    .collect(),
                _ => all.filter(|&(i, j)| i < j).collect(),
            }
        }
    })
}

/// Run/read every pair, align it, and return the reports and the fused (not downsampled)
/// points of the accepted pairs.
pub(crate) fn pointmap_points(
    kind: UsedSource,
    path: &Path,
    model: Option<&PointMapModel>,
    views: &[(String, View)],
    sparse: &[DVec3],
    config: &InitConfig,
    progress: &dyn Progress,
) -> Result<(Vec<PairReport>, Vec<FusedPoint>), InitError> {
    if model.is_none() && !path.is_dir() {
        return Err(InitError::Npy(NpyError::Io {
            path: path.into(),
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "point-map directory not found",
            ),
        }));
    }
    let pairs = choose_pairs(kind, path, views, config)?;
    progress.start(pairs.len() as u64, "pairs");
    let mut reports = Vec::new();
    let mut points = Vec::new();
    for (i, j) in pairs {
        let ((na, a), (nb, b)) = (&views[i], &views[j]);
        progress.message(&format!("{na}/{nb}"));
        let maps = match model {
            Some(m) => Some(m.run(&a.image, &b.image)?),
            None => match npy::read_pair(path, na, nb, &config.output_names) {
                Ok(m) => Some(m),
                Err(NpyError::MissingPair { .. }) => None,
                Err(e) => return Err(e.into()),
            },
        };
        let (report, pts) = match maps {
            Some(maps) => align_pair(na, a, nb, b, &maps, sparse, config),
            None => (
                rejected(na, nb, "no exported point maps for this pair".into()),
                vec![],
            ),
        };
        if let Some(r) = &report.reason {
            tracing::warn!("point init: pair {na}/{nb} rejected: {r}");
        } else {
            tracing::info!(
                "point init: pair {na}/{nb}: scale {:.4}, {} points",
                report.scale.unwrap_or(f64::NAN),
                report.points
            );
        }
        reports.push(report);
        points.extend(pts);
        progress.advance(1);
    }
    progress.finish();
    Ok((reports, points))
}

fn rejected(first: &str, second: &str, reason: String) -> PairReport {
    PairReport {
        first: first.into(),
        second: second.into(),
        frame: None,
        accepted: false,
        reason: Some(reason),
        scale: None,
        ray_scale: None,
        sparse_scale: None,
        sparse_matches: 0,
        residual: None,
        pixels: 0,
        non_finite: 0,
        confident: 0,
        points: 0,
    }
}

/// Which pixels are finite and confident; and how many are not finite.
fn valid_mask(map: &PointMap, min_confidence: f32) -> (Vec<bool>, usize) {
    let mut non_finite = 0;
    let mask = (0..map.points.len())
        .map(|i| {
            let p = map.points[i];
            let c = map.confidence.as_ref().map_or(f32::INFINITY, |c| c[i]);
            let finite = p.iter().all(|v| v.is_finite()) && !c.is_nan();
            if !finite {
                non_finite += 1;
            }
            finite && c >= min_confidence
        })
        .collect();
    (mask, non_finite)
}

/// Align one pair and turn its confident pixels into world points.
fn align_pair(
    na: &str,
    a: &View,
    nb: &str,
    b: &View,
    maps: &PairMaps,
    sparse: &[DVec3],
    config: &InitConfig,
) -> (PairReport, Vec<FusedPoint>) {
    let (m1, m2) = (&maps.first, &maps.second);
    let (mut v1, nf1) = valid_mask(m1, config.min_confidence);
    let (v2, nf2) = valid_mask(m2, config.min_confidence);
    for (v, p) in v1.iter_mut().zip(&m1.points) {
        *v &= p[2] > 0.0;
    }
    let mut report = rejected(na, nb, String::new());
    report.pixels = m1.points.len() + m2.points.len();
    report.non_finite = nf1 + nf2;
    report.confident = v1.iter().chain(&v2).filter(|v| **v).count();
    let reject = |mut r: PairReport, reason: String| {
        r.reason = Some(reason);
        (r, vec![])
    };
    if report.non_finite as f64 > config.max_non_finite * report.pixels as f64 {
        let msg = format!(
            "{} of {} pixels are not finite (NaN/inf)",
            report.non_finite, report.pixels
        );
        return reject(report, msg);
    }
    let scaled = |v: &View, m: &PointMap| Camera {
        intrinsics: v
            .camera
            .intrinsics
            .scaled_to(m.width as u32, m.height as u32),
        ..v.camera.clone()
    };
    let (ca, cb) = (scaled(a, m1), scaled(b, m2));
    let rel = Relative::between(&ca, &cb);
    let ray = ray_scale(&cb, &rel, m2, &v2);
    let sp = sparse_scale(&ca, m1, &v1, sparse, config.min_sparse_matches);
    report.ray_scale = ray.map(|r| r.scale);
    report.residual = ray.map(|r| r.residual);
    report.sparse_scale = sp.map(|s| s.0);
    report.sparse_matches = sp.map_or(0, |s| s.1);
    let scale = match (ray, sp) {
        (Some(r), _) if r.residual > config.max_residual => {
            let msg = format!(
                "second view does not fit its camera: median reprojection error {:.2}% of the width (limit {:.2}%)",
                100.0 * r.residual,
                100.0 * config.max_residual
            );
            return reject(report, msg);
        }
        (Some(r), Some((s, _))) => {
            if (r.scale / s).ln().abs() > (1.0 + config.scale_tolerance).ln() {
                let msg = format!(
                    "scale from rays {:.4} disagrees with scale from sparse points {:.4}",
                    r.scale, s
                );
                return reject(report, msg);
            }
            r.scale
        }
        (Some(r), None) => r.scale,
        (None, Some((s, _))) => s,
        (None, None) => {
            return reject(
                report,
                "scale not determined (no baseline or too few confident pixels, and no sparse points)".into(),
            );
        }
    };
    report.scale = Some(scale);
    let mut pts = Vec::new();
    for (i, p) in m1.points.iter().enumerate() {
        if v1[i] {
            let pc = pixel_centre(i, m1.width);
            pts.push(FusedPoint {
                xyz: unproject(&ca, pc, scale * p[2] as f64),
                rgb: colour_at(&a.image, pc, m1.width, m1.height),
                time: a.time,
                time_span: 0.0,
            });
        }
    }
    let max_px = config.max_residual * m2.width as f64;
    for (i, p) in m2.points.iter().enumerate() {
        if !v2[i] {
            continue;
        }
        let x = scale * (rel.rotation * DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            + rel.translation;
        if x.z <= 1e-9 {
            continue;
        }
        let pc = pixel_centre(i, m2.width);
        let proj = cb
            .intrinsics
            .to_pixels(glam::DVec2::new(x.x / x.z, x.y / x.z));
        if (proj - pc).length() > max_px {
            continue;
        }
        pts.push(FusedPoint {
            xyz: unproject(&cb, pc, x.z),
            rgb: colour_at(&b.image, pc, m2.width, m2.height),
            time: b.time,
            time_span: 0.0,
        });
    }
    report.accepted = true;
    report.reason = None;
    report.points = pts.len();
    (report, pts)
}
