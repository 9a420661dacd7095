//! Point init from exported point maps made from the simulator's ground-truth depth
//! (`groundtruth/depth/camN.npy` of `fixtures/tiny.toml`), checked against the scene's
//! true surfaces (`rig::sim::surface_triangles`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::{DVec2, DVec3};
use pointinit::npy::{self, OutputNames, PairMaps};
use pointinit::{
    InitConfig, InitInputs, Moment, Source, UsedSource, ViewImage, moment_maps, run_init,
};
use rayon::prelude::*;
use shared_types::{Camera, CameraSet, NoProgress};

struct Truth {
    dir: PathBuf,
    cameras: CameraSet,
    /// Per camera: z-depth (0 = nothing), row-major.
    depth: Vec<Vec<f32>>,
    images: Vec<ViewImage>,
    triangles: Vec<[DVec3; 3]>,
    /// Bounding-box diagonal of the surfaces the cameras see.
    scene_size: f64,
    sparse: PathBuf,
}

fn truth() -> &'static Truth {
    static T: OnceLock<Truth> = OnceLock::new();
    T.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let scene = rig::sim::Scene::from_file(&root.join("fixtures/tiny.toml")).unwrap();
        let dir = tempfile::tempdir().unwrap().keep();
        let capture = dir.join("capture");
        rig::sim::simulate(&scene, &capture, &NoProgress).unwrap();
        let gt: CameraSet = serde_json::from_str(
            &std::fs::read_to_string(capture.join("groundtruth/cameras.json")).unwrap(),
        )
        .unwrap();
        let video = scene.video_cameras().cloned().collect::<Vec<_>>();
        let t0 = video[0].start_time;
        assert!(video.iter().all(|c| c.start_time == t0));
        let cameras = CameraSet::new(
            video
                .iter()
                .map(|v| gt.get(&v.camera.name).unwrap().clone())
                .collect(),
        );
        std::fs::create_dir_all(dir.join("frames")).unwrap();
        let mut depth = Vec::new();
        let mut images = Vec::new();
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        let mut sparse = shared_types::PointCloud {
            xyz: vec![],
            rgb: vec![],
            time: None,
            time_span: None,
        };
        for (k, cam) in cameras.cameras.iter().enumerate() {
            assert!(cam.distortion.is_none());
            let d = npy::read_npy(&capture.join(format!("groundtruth/depth/{}.npy", cam.name)))
                .unwrap();
            let (w, h) = (
                cam.intrinsics.width as usize,
                cam.intrinsics.height as usize,
            );
            assert_eq!(d.shape, [h, w]);
            for (i, z) in d.data.iter().enumerate() {
                if *z > 0.0 {
                    let p = world_of(cam, i, *z as f64);
                    lo = lo.min(p);
                    hi = hi.max(p);
                    if i % 53 == k {
                        sparse.xyz.push(p.as_vec3().to_array());
                        sparse.rgb.push([100, 100, 100]);
                    }
                }
            }
            depth.push(d.data);
            let r = rig::sim::render_clean(&scene, &cam.name, t0).unwrap();
            let rgb = image::RgbImage::from_fn(w as u32, h as u32, |x, y| {
                let c = r.color[y as usize * w + x as usize];
                image::Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
            });
            let path = dir.join(format!("frames/{}.png", cam.name));
            rgb.save(&path).unwrap();
            images.push(ViewImage {
                camera: cam.name.clone(),
                path,
                time: 0.1 * k as f64,
            });
        }
        let sparse_path = dir.join("points3d.ply");
        shared_types::points::write_points_ply(&sparse, &sparse_path).unwrap();
        Truth {
            dir,
            cameras,
            depth,
            images,
            triangles: rig::sim::surface_triangles(&scene, t0),
            scene_size: (hi - lo).length(),
            sparse: sparse_path,
        }
    })
}

fn world_of(cam: &Camera, i: usize, z: f64) -> DVec3 {
    let w = cam.intrinsics.width as usize;
    let n = cam
        .intrinsics
        .to_normalised(DVec2::new((i % w) as f64 + 0.5, (i / w) as f64 + 0.5));
    cam.world_to_camera
        .inverse_apply(DVec3::new(n.x * z, n.y * z, z))
}

/// What a perfect model would output for pair (a, b), divided by `scale`.
fn gt_pair(t: &Truth, a: usize, b: usize, scale: f64) -> PairMaps {
    let view = |v: usize| (&t.cameras.cameras[v], t.depth[v].as_slice());
    npy::pair_maps_from_depth(view(a), view(b), scale)
}

/// Distance of each point to the nearest true surface triangle.
fn surface_distances(t: &Truth, points: &[[f32; 3]]) -> Vec<f64> {
    triangle_distances(&t.triangles, points)
}

/// Distance of each point to the nearest of `triangles`.
fn triangle_distances(triangles: &[[DVec3; 3]], points: &[[f32; 3]]) -> Vec<f64> {
    let spheres = triangles
        .iter()
        .map(|tri| {
            let c = (tri[0] + tri[1] + tri[2]) / 3.0;
            let r = tri.iter().map(|v| (*v - c).length()).fold(0.0, f64::max);
            (c, r)
        })
        .collect::<Vec<_>>();
    points
        .par_iter()
        .map(|p| {
            let p = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let mut best = f64::INFINITY;
            for (tri, (c, r)) in triangles.iter().zip(&spheres) {
                if (p - *c).length() - r >= best {
                    continue;
                }
                let d = (rig::sim::closest_on_triangle(p, *tri) - p).length();
                if d.is_finite() {
                    best = best.min(d);
                }
            }
            best
        })
        .collect()
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * q) as usize]
}

fn inputs(t: &Truth, sparse: bool) -> InitInputs {
    InitInputs {
        cameras: t.cameras.clone(),
        images: t.images.clone(),
        sparse: sparse.then(|| t.sparse.clone()),
        moments: vec![],
        plate_frames: Vec::new(),
        stills: Vec::new(),
    }
}

/// Per-pair scales of the exported maps: far from 1 and all different.
fn pair_scale(k: usize) -> f64 {
    [0.23, 3.7, 1.0, 0.61, 12.5, 0.05][k % 6]
}

#[test]
fn ground_truth_point_maps_fuse_onto_the_true_surfaces() {
    let t = truth();
    let maps_dir = t.dir.join("maps_gt");
    std::fs::create_dir_all(&maps_dir).unwrap();
    let names = OutputNames::default();
    let mut k = 0;
    for a in 0..4 {
        for b in a + 1..4 {
            let maps = gt_pair(t, a, b, pair_scale(k));
            let (na, nb) = (&t.cameras.cameras[a].name, &t.cameras.cameras[b].name);
            // Both layouts: .npz archives and directories of .npy files.
            if k % 2 == 0 {
                npy::write_pair_npz(&maps_dir, na, nb, &maps, &names).unwrap();
            } else {
                npy::write_pair_dir(&maps_dir, na, nb, &maps, &names).unwrap();
            }
            k += 1;
        }
    }
    let config = InitConfig {
        source: Source::Npy,
        pointmaps: Some(maps_dir),
        ..InitConfig::default()
    };
    let out = t.dir.join("out_gt");
    let report = run_init(&inputs(t, true), &config, &out, &NoProgress).unwrap();
    eprintln!("{report:#?}");
    assert_eq!(report.source, UsedSource::Npy);
    assert!(report.fallbacks.is_empty());
    assert_eq!(report.pairs.len(), 6);
    for (k, p) in report.pairs.iter().enumerate() {
        assert!(p.accepted, "{p:?}");
        let s = p.scale.unwrap();
        assert!((s / pair_scale(k) - 1.0).abs() < 1e-3, "pair {k}: {s}");
        assert!(p.sparse_matches >= 20, "{p:?}");
    }
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    assert_eq!(cloud.xyz.len(), report.points_written);
    assert!(cloud.xyz.len() > 5_000, "{}", cloud.xyz.len());
    let times = cloud.time.as_ref().unwrap();
    assert!(times.iter().all(|t| (0.0..=0.3 + 1e-6).contains(t)));
    let d = surface_distances(t, &cloud.xyz);
    let (median, p90) = (quantile(d.clone(), 0.5), quantile(d, 0.9));
    eprintln!(
        "scene size {:.3} m; median distance {:.2e} m ({:.2e} %), 90th percentile {:.2e} m",
        t.scene_size,
        median,
        100.0 * median / t.scene_size,
        p90
    );
    assert!(median < 0.005 * t.scene_size);
    // Far tighter than the 0.5 % bound: the maps are exact, only voxel averaging (of
    // points on curved or meeting surfaces) and f32 storage move the points.
    assert!(median < 0.25 * report.voxel, "voxel {}", report.voxel);
}

#[test]
fn inconsistent_scales_and_nans_are_rejected_and_counted() {
    let t = truth();
    let maps_dir = t.dir.join("maps_bad");
    std::fs::create_dir_all(&maps_dir).unwrap();
    let names = OutputNames::default();
    let name = |i: usize| t.cameras.cameras[i].name.clone();
    // cam0/cam1: the second view's map is 1.5× too large relative to the first: the ray
    // scale (from view 2) and the sparse scale (from view 1) disagree.
    let mut m = gt_pair(t, 0, 1, 2.0);
    for p in &mut m.second.points {
        *p = p.map(|v| v * 1.5);
    }
    npy::write_pair_dir(&maps_dir, &name(0), &name(1), &m, &names).unwrap();
    // cam0/cam2: 80 % NaN.
    let mut m = gt_pair(t, 0, 2, 1.0);
    let n = m.first.points.len();
    for i in 0..(n * 8 / 10) {
        m.first.points[i] = [f32::NAN; 3];
        m.second.points[i][1] = f32::NAN;
    }
    npy::write_pair_dir(&maps_dir, &name(0), &name(2), &m, &names).unwrap();
    // cam1/cam3: a few NaN pixels and an infinite confidence; still usable.
    let mut m = gt_pair(t, 1, 3, 0.5);
    for i in (0..n).step_by(10) {
        m.second.points[i] = [f32::NAN; 3];
    }
    let nans = n.div_ceil(10);
    npy::write_pair_npz(&maps_dir, &name(1), &name(3), &m, &names).unwrap();
    let config = InitConfig {
        source: Source::Npy,
        pointmaps: Some(maps_dir),
        pairs: pointinit::Pairs::List(vec![
            [name(0), name(1)],
            [name(0), name(2)],
            [name(1), name(3)],
            [name(2), name(3)], // not exported: a counted rejection
        ]),
        ..InitConfig::default()
    };
    let out = t.dir.join("out_bad");
    let report = run_init(&inputs(t, true), &config, &out, &NoProgress).unwrap();
    eprintln!("{report:#?}");
    let p = &report.pairs;
    assert!(!p[0].accepted && p[0].reason.as_ref().unwrap().contains("disagrees"));
    assert!((p[0].ray_scale.unwrap() / (2.0 / 1.5) - 1.0).abs() < 1e-3);
    assert!((p[0].sparse_scale.unwrap() / 2.0 - 1.0).abs() < 0.02);
    assert!(!p[1].accepted && p[1].reason.as_ref().unwrap().contains("not finite"));
    assert!(p[2].accepted, "{:?}", p[2]);
    assert_eq!(p[2].non_finite, nans);
    assert!((p[2].scale.unwrap() / 0.5 - 1.0).abs() < 1e-3);
    assert!(!p[3].accepted && p[3].reason.as_ref().unwrap().contains("no exported"));
    assert_eq!(report.source, UsedSource::Npy);
    // Only the good pair's points are in the cloud, and they lie on the surfaces.
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    let d = surface_distances(t, &cloud.xyz);
    assert!(quantile(d, 0.5) < 0.005 * t.scene_size);
}

#[test]
fn all_pairs_rejected_falls_back_to_the_sparse_points() {
    let t = truth();
    let maps_dir = t.dir.join("maps_nan");
    std::fs::create_dir_all(&maps_dir).unwrap();
    let mut m = gt_pair(t, 2, 3, 1.0);
    m.first.points.iter_mut().for_each(|p| *p = [f32::NAN; 3]);
    m.second
        .points
        .iter_mut()
        .for_each(|p| *p = [f32::INFINITY; 3]);
    let (a, b) = (&t.cameras.cameras[2].name, &t.cameras.cameras[3].name);
    npy::write_pair_dir(&maps_dir, a, b, &m, &OutputNames::default()).unwrap();
    let config = InitConfig {
        pointmaps: Some(maps_dir),
        ..InitConfig::default()
    };
    let out = t.dir.join("out_nan");
    let report = run_init(&inputs(t, true), &config, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Sparse);
    assert_eq!(report.pairs.len(), 1);
    assert!(!report.pairs[0].accepted);
    assert_eq!(report.fallbacks.len(), 1, "{:?}", report.fallbacks);
    let sparse = shared_types::points::read_points_ply(&t.sparse).unwrap();
    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    assert_eq!(cloud.xyz, sparse.xyz);
    // Sparse points carry the mean time of the first frames.
    assert!(cloud.time.unwrap().iter().all(|t| (t - 0.15).abs() < 1e-6));
}

#[test]
fn point_maps_of_several_moments_split_static_from_moving() {
    let t = truth();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = rig::sim::Scene::from_file(&root.join("fixtures/tiny.toml")).unwrap();
    let t0 = scene.video_cameras().next().unwrap().start_time;
    let maps_dir = t.dir.join("maps_moments");
    // Three moments; the crate moves 0.55 m between them, the room stands still.
    let frames = [0usize, 7, 14];
    let mut moments = Vec::new();
    for &frame in &frames {
        let time = t0 + frame as f64 / 15.0;
        let mut depths = Vec::new();
        let mut views = Vec::new();
        for cam in &t.cameras.cameras {
            let r = rig::sim::render_clean(&scene, &cam.name, time).unwrap();
            let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
            let rgb = image::RgbImage::from_fn(w, h, |x, y| {
                let c = r.color[(y * w + x) as usize];
                image::Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
            });
            let path = t.dir.join(format!("frames/{}_{frame:06}.png", cam.name));
            rgb.save(&path).unwrap();
            views.push(ViewImage {
                camera: cam.name.clone(),
                path,
                time,
            });
            depths.push(
                r.depth
                    .iter()
                    .map(|d| if d.is_finite() { *d } else { 0.0 })
                    .collect::<Vec<_>>(),
            );
        }
        let dir = moment_maps::frame_dir(&maps_dir, frame);
        for a in 0..4 {
            for b in a + 1..4 {
                let (ca, cb) = (&t.cameras.cameras[a], &t.cameras.cameras[b]);
                let maps = npy::pair_maps_from_depth((ca, &depths[a]), (cb, &depths[b]), 0.5);
                npy::write_pair_npz(&dir, &ca.name, &cb.name, &maps, &OutputNames::default())
                    .unwrap();
            }
        }
        moments.push(Moment { frame, time, views });
    }
    assert_eq!(moment_maps::exported_frames(&maps_dir), frames);
    let config = InitConfig {
        source: Source::Npy,
        pointmaps: Some(maps_dir),
        max_points: usize::MAX,
        ..InitConfig::default()
    };
    let inputs = InitInputs {
        moments: moments.clone(),
        plate_frames: Vec::new(),
        stills: Vec::new(),
        ..inputs(t, false)
    };
    let out = t.dir.join("out_moments");
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Npy);
    assert_eq!(report.pairs.len(), 18);
    assert!(report.pairs.iter().all(|p| p.accepted && p.frame.is_some()));
    let s = report.statics;
    eprintln!("{s:?}");
    assert!(s.static_points > 1000 && s.dynamic_points > 100, "{s:?}");
    assert!(s.dynamic_points < s.static_points / 2, "{s:?}");

    let cloud = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    let (times, spans) = (cloud.time.unwrap(), cloud.time_span.unwrap());
    let clip = moments[2].time - moments[0].time;
    let surfaces: Vec<_> = moments
        .iter()
        .map(|m| rig::sim::surface_triangles(&scene, m.time))
        .collect();
    let voxel = report.voxel;
    let (mut statics, mut moving) = (vec![], vec![]);
    for ((p, time), span) in cloud.xyz.iter().zip(&times).zip(&spans) {
        if *span > 0.0 {
            statics.push(*p);
        } else {
            let k = moments
                .iter()
                .position(|m| (m.time as f32 - time).abs() < 1e-4)
                .unwrap_or_else(|| panic!("moving point at {time}, not at a moment"));
            moving.push((k, *p));
        }
    }
    // Static points are on the surfaces at every moment, most over the whole clip.
    for tris in &surfaces {
        let d = triangle_distances(tris, &statics);
        assert!(quantile(d, 0.9) < voxel, "static points off a surface");
    }
    let whole = spans
        .iter()
        .filter(|s| (**s as f64 - clip).abs() < 1e-4)
        .count();
    assert!(
        whole as f64 > 0.5 * statics.len() as f64,
        "{whole} of {}",
        statics.len()
    );
    // Moving points are on the surfaces of their moment, and most are off them at the
    // other moments (they are on the crate, which has moved).
    for (k, tris) in surfaces.iter().enumerate() {
        let own: Vec<_> = moving.iter().filter(|m| m.0 == k).map(|m| m.1).collect();
        let others: Vec<_> = moving.iter().filter(|m| m.0 != k).map(|m| m.1).collect();
        assert!(!own.is_empty(), "moment {k} has no moving point");
        assert!(quantile(triangle_distances(tris, &own), 0.9) < voxel);
        assert!(quantile(triangle_distances(tris, &others), 0.5) > 5.0 * voxel);
    }
}
