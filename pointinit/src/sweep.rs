//! Dense points from plane-sweep stereo with the known cameras, for captures without point
//! maps (an imported calibration, wide baselines where SIFT matches a few dozen points).
//!
//! At one moment, the views (pinhole cameras with undistorted frames) are shrunk to `size`
//! pixels on their long side and each camera in turn is the reference: for depths uniform
//! in inverse depth around where the rig looks, one pixel of motion apart in the other
//! cameras (at most `max_planes`), every other camera's grey image is warped onto the
//! reference through the fronto-parallel plane at that depth and compared with a
//! zero-mean normalised cross-correlation (NCC) over a `(2·WINDOW+1)²` window. A
//! fronto-parallel window matches badly where the surface is steeply slanted (a floor or a
//! side wall seen at a grazing angle), so with `slanted` two more families of planes are
//! swept: planes facing the scene's up direction (the cameras' mean up) and planes facing
//! the reference camera's side (its x axis made level), each warping the whole window
//! through the plane, i.e. by the plane's homography (the multi-direction sweep of Gallup
//! et al., CVPR 2007). A pixel takes the depth where its best neighbour's NCC peaks over all
//! planes (refined by a parabola within the family) when that NCC reaches `min_score` and
//! the window has texture. Depths are then kept only where
//! another camera's depth map agrees (the point projects there at the same depth, and that
//! pixel's point projects back within a pixel): two independent searches found the same
//! surface. What is kept becomes coloured world points with the moment's time.

use glam::{DVec2, DVec3};
use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared_types::Camera;

use super::fuse::{rig_radius, rig_target};
use super::statics::TimedPoint;
use super::views::View;

/// Half-size of the NCC window (7×7 pixels).
const WINDOW: usize = 3;
/// Smallest standard deviation of a window's grey values (0..1) that counts as texture.
const MIN_TEXTURE: f32 = 0.015;
/// Depth range around where the rig looks: `[d / RANGE, d · RANGE]` for a reference
/// camera whose depth of the rig's target is `d`.
const RANGE: f64 = 4.0;
/// Relative depth difference two depth maps may have and still agree.
const DEPTH_TOLERANCE: f64 = 0.005;
/// Fewest depth planes swept.
const MIN_PLANES: usize = 16;
/// Pixels the round trip through another camera's depth map may move.
const PIXEL_TOLERANCE: f64 = 1.0;

/// A swept point: where it is, and its reference pixel's colour (`0..255`).
pub type ColouredPoint = (DVec3, [f32; 3]);

/// Sweep settings (from `[init]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepOptions {
    /// Long side (pixels) the views are shrunk to for the sweep (never enlarged).
    pub size: u32,
    /// Most depth planes per reference camera (they are one pixel of motion apart).
    pub max_planes: usize,
    /// Least NCC of the best neighbour for a pixel to take a depth.
    pub min_score: f32,
    /// Cameras whose depth maps must agree on a point (the reference included, ≥ 2).
    pub min_views: usize,
    /// Also sweep planes that face the scene's up direction (floors, ceilings, tables) and
    /// the reference camera's side (walls seen at a grazing angle), not only planes facing
    /// the reference camera: three times the work.
    pub slanted: bool,
}

/// What one moment's sweep gave.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    pub frame: usize,
    pub time: f64,
    /// Reference pixels, pixels that took a depth, and depths other cameras confirmed.
    pub pixels: usize,
    pub matched: usize,
    pub points: usize,
    pub seconds: f64,
}

/// One camera's depth map (pinhole, the view's size); 0 where no depth was found.
struct DepthMap {
    width: usize,
    height: usize,
    depth: Vec<f32>,
}

impl DepthMap {
    /// The depth at the pixel containing `p` (0 outside or where none).
    fn at(&self, p: DVec2) -> f64 {
        if !(p.x >= 0.0 && p.y >= 0.0) {
            return 0.0;
        }
        let (x, y) = (p.x as usize, p.y as usize);
        if x >= self.width || y >= self.height {
            return 0.0;
        }
        self.depth[y * self.width + x] as f64
    }
}

/// A view's grey image in `0..1` (Rec. 601 luma), row-major.
fn grey(image: &RgbImage) -> Vec<f32> {
    image
        .pixels()
        .map(|p| (0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32) / 255.0)
        .collect()
}

/// Bilinear sample of a grey image at continuous pixel coordinates (pixel centres at
/// integer + 0.5); `None` outside the centres' hull.
fn bilinear(img: &[f32], w: usize, h: usize, p: DVec2) -> Option<f32> {
    let (x, y) = (p.x - 0.5, p.y - 0.5);
    if !(x >= 0.0 && y >= 0.0) || x > (w - 1) as f64 || y > (h - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let top = img[y0 * w + x0] * (1.0 - fx) + img[y0 * w + x1] * fx;
    let bottom = img[y1 * w + x0] * (1.0 - fx) + img[y1 * w + x1] * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Sums of `values` over the `(2r+1)²` window around each pixel (windows clipped at the
/// border), through a summed-area table in `f64`.
fn box_sums(values: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let mut table = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += values[y * w + x] as f64;
            table[(y + 1) * (w + 1) + x + 1] = table[y * (w + 1) + x + 1] + row;
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let s = table[y1 * (w + 1) + x1] - table[y0 * (w + 1) + x1] - table[y1 * (w + 1) + x0]
                + table[y0 * (w + 1) + x0];
            out[y * w + x] = s as f32;
        }
    }
    out
}

/// Per pixel of the reference: the unit-z ray in world coordinates (`X = C + d · ray` is
/// the point at depth `d`).
fn rays(camera: &Camera) -> Vec<DVec3> {
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let rt = camera.world_to_camera.rotation().transpose();
    (0..w * h)
        .map(|i| {
            let p = DVec2::new((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            let n = camera.intrinsics.to_normalised(p);
            rt * DVec3::new(n.x, n.y, 1.0)
        })
        .collect()
}

/// The depth of the rig's target in `camera` (the rig radius when it is behind).
fn target_depth(camera: &Camera, target: DVec3, radius: f64) -> f64 {
    let d = camera.world_to_camera.apply(target).z;
    if d > 1e-9 { d } else { radius }
}

/// How many planes put neighbouring planes about one pixel of motion apart in `others`:
/// the largest motion per unit of inverse depth, at the target's depth, of the reference's
/// centre and corner pixels, times the inverse-depth range; within
/// `[MIN_PLANES, max_planes]`.
fn plane_count(camera: &Camera, others: &[&Camera], depth: f64, max_planes: usize) -> usize {
    let (w, h) = (
        camera.intrinsics.width as f64,
        camera.intrinsics.height as f64,
    );
    let centre = camera.world_to_camera.centre();
    let rt = camera.world_to_camera.rotation().transpose();
    let step = 1e-3 / depth;
    let mut motion = 0.0f64;
    for p in [(0.5, 0.5), (0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
        let n = camera
            .intrinsics
            .to_normalised(DVec2::new(p.0 * w, p.1 * h));
        let ray = rt * DVec3::new(n.x, n.y, 1.0);
        let at = |inv: f64| centre + ray / inv;
        for o in others {
            if let (Some((a, _)), Some((b, _))) = (
                o.project(at(1.0 / depth)),
                o.project(at(1.0 / depth + step)),
            ) {
                motion = motion.max((a - b).length() / step);
            }
        }
    }
    let range = RANGE / depth - 1.0 / (RANGE * depth);
    ((motion * range).ceil() as usize).clamp(MIN_PLANES, max_planes.max(MIN_PLANES))
}

/// The depths swept: `planes` values uniform in inverse depth over `[d / RANGE, d · RANGE]`,
/// nearest first, `d` the depth of the rig's target.
fn plane_depths(d: f64, planes: usize) -> Vec<f64> {
    let (near, far) = (1.0 / (d / RANGE), 1.0 / (d * RANGE));
    let planes = planes.max(2);
    (0..planes)
        .map(|k| 1.0 / (near + (far - near) * k as f64 / (planes - 1) as f64))
        .collect()
}

/// A family of parallel planes: world normal `normal` and, per plane, the parameter
/// uniform between neighbours (`inverse`: the inverse of the offset, else the offset
/// itself); plane `k` is `{X : normal · (X − origin) = offset_k}`, so a reference ray
/// (unit z, [`rays`]) meets it at depth `offset_k / (normal · ray)`.
struct Family {
    normal: DVec3,
    params: Vec<f64>,
    inverse: bool,
}

impl Family {
    fn offset(&self, param: f64) -> f64 {
        if self.inverse { 1.0 / param } else { param }
    }
}

/// The scene's up direction: cameras are held level (no roll), so their x axes are
/// horizontal and up is the direction most perpendicular to all of them (the smallest
/// eigenvector of `Σ x xᵀ`, by power iteration on `trace − Σ x xᵀ` from the cameras' mean
/// up axis, which it stays near when the x axes do not tell, as for parallel cameras);
/// `None` when the cameras' up axes cancel out.
fn scene_up(cameras: &[Camera]) -> Option<DVec3> {
    let axis = |c: &Camera, a: DVec3| c.world_to_camera.rotation().transpose() * a;
    // Image y points down.
    let mean: DVec3 = cameras.iter().map(|c| -axis(c, DVec3::Y)).sum();
    if mean.length() <= 0.5 * cameras.len() as f64 {
        return None;
    }
    let xs: Vec<DVec3> = cameras.iter().map(|c| axis(c, DVec3::X)).collect();
    let trace = xs.len() as f64;
    let mut up = mean.normalize();
    for _ in 0..100 {
        let next = trace * up - xs.iter().map(|x| x * x.dot(up)).sum::<DVec3>();
        up = next.normalize_or(up);
    }
    Some(if up.dot(mean) < 0.0 { -up } else { up })
}

/// The plane families swept for `camera`: fronto-parallel planes uniform in inverse
/// depth, and with `up` (slanted sweeps) level planes and planes facing the camera's side,
/// `planes` each, uniform in offset over `[-d, d]`.
fn families(camera: &Camera, d: f64, planes: usize, up: Option<DVec3>) -> Vec<Family> {
    let rt = camera.world_to_camera.rotation().transpose();
    let mut out = vec![Family {
        normal: rt * DVec3::Z,
        params: plane_depths(d, planes).iter().map(|x| 1.0 / x).collect(),
        inverse: true,
    }];
    let Some(up) = up else {
        return out;
    };
    let x = rt * DVec3::X;
    let side = x - x.dot(up) * up;
    // Offsets uniform over [-d, d], skipping the plane through the camera itself.
    let offsets: Vec<f64> = (0..planes.max(2))
        .map(|k| -d + 2.0 * d * (k as f64 + 0.5) / planes.max(2) as f64)
        .collect();
    for normal in [Some(up), (side.length() > 0.1).then(|| side.normalize())]
        .into_iter()
        .flatten()
    {
        out.push(Family {
            normal,
            params: offsets.clone(),
            inverse: false,
        });
    }
    out
}

/// The reference's window statistics: sums of I and I², and whether each window has
/// texture.
struct Reference {
    sum: Vec<f32>,
    sum_sq: Vec<f32>,
    count: Vec<f32>,
    textured: Vec<bool>,
}

impl Reference {
    fn new(img: &[f32], w: usize, h: usize) -> Self {
        let sum = box_sums(img, w, h, WINDOW);
        let sq: Vec<f32> = img.iter().map(|v| v * v).collect();
        let sum_sq = box_sums(&sq, w, h, WINDOW);
        let count = box_sums(&vec![1.0; w * h], w, h, WINDOW);
        let textured = (0..w * h)
            .map(|i| {
                let n = count[i];
                let var = sum_sq[i] / n - (sum[i] / n).powi(2);
                var >= MIN_TEXTURE * MIN_TEXTURE
            })
            .collect();
        Self {
            sum,
            sum_sq,
            count,
            textured,
        }
    }
}

/// NCC of every reference window against `other` warped through a plane that puts
/// reference pixel `i` at depth `depths[i]` (`-1` where the warp leaves `other` or the
/// depth range anywhere in the window, or either side is flat).
#[allow(clippy::too_many_arguments)]
fn plane_scores(
    reference: &Reference,
    ref_img: &[f32],
    rays: &[DVec3],
    origin: DVec3,
    depths: &[f64],
    other: &Camera,
    other_img: &[f32],
    w: usize,
    h: usize,
) -> Vec<f32> {
    let (ow, oh) = (
        other.intrinsics.width as usize,
        other.intrinsics.height as usize,
    );
    let mut warped = vec![0.0f32; w * h];
    let mut valid = vec![0.0f32; w * h];
    for (i, ray) in rays.iter().enumerate() {
        if depths[i] > 0.0
            && let Some((p, _)) = other.project(origin + depths[i] * *ray)
            && let Some(v) = bilinear(other_img, ow, oh, p)
        {
            warped[i] = v;
            valid[i] = 1.0;
        }
    }
    let sw = box_sums(&warped, w, h, WINDOW);
    let sww = box_sums(
        &warped.iter().map(|v| v * v).collect::<Vec<_>>(),
        w,
        h,
        WINDOW,
    );
    let siw = box_sums(
        &warped
            .iter()
            .zip(ref_img)
            .map(|(a, b)| a * b)
            .collect::<Vec<_>>(),
        w,
        h,
        WINDOW,
    );
    let count = box_sums(&valid, w, h, WINDOW);
    (0..w * h)
        .map(|i| {
            let n = reference.count[i];
            if !reference.textured[i] || count[i] < n - 0.5 {
                return -1.0;
            }
            let (mi, mw) = (reference.sum[i] / n, sw[i] / n);
            let vi = reference.sum_sq[i] / n - mi * mi;
            let vw = sww[i] / n - mw * mw;
            if vw < 0.25 * MIN_TEXTURE * MIN_TEXTURE {
                return -1.0;
            }
            ((siw[i] / n - mi * mw) / (vi * vw).sqrt()).clamp(-1.0, 1.0)
        })
        .collect()
}

/// The depth map of `views[reference]` against the views `partners` (`greys`: each view's
/// [`grey`] image).
fn depth_map(
    views: &[&View],
    greys: &[Vec<f32>],
    reference: usize,
    partners: &[usize],
    (target, radius): (DVec3, f64),
    up: Option<DVec3>,
    options: &SweepOptions,
) -> DepthMap {
    let r = views[reference];
    let (w, h) = (r.image.width() as usize, r.image.height() as usize);
    let ref_img = &greys[reference];
    let stats = Reference::new(ref_img, w, h);
    let rays = rays(&r.camera);
    let origin = r.camera.world_to_camera.centre();
    let others: Vec<(&Camera, &[f32])> = partners
        .iter()
        .filter(|&&k| k != reference)
        .map(|&k| (&views[k].camera, greys[k].as_slice()))
        .collect();
    let d = target_depth(&r.camera, target, radius);
    let other_cameras: Vec<&Camera> = others.iter().map(|(c, _)| *c).collect();
    let planes = plane_count(&r.camera, &other_cameras, d, options.max_planes);
    let (near, far) = (d / RANGE, d * RANGE);
    let n = w * h;
    let (mut best, mut depth) = (vec![f32::MIN; n], vec![0.0f32; n]);
    for family in families(&r.camera, d, planes, up) {
        let facing: Vec<f64> = rays.iter().map(|ray| family.normal.dot(*ray)).collect();
        // Pixel i's depth on the plane of parameter `param` (0 outside the depth range).
        let depth_at = |param: f64, i: usize| {
            let z = family.offset(param) / facing[i];
            if (near..=far).contains(&z) { z } else { 0.0 }
        };
        let (score, param) = sweep_family(&family.params, n, |param| {
            let depths: Vec<f64> = (0..n).map(|i| depth_at(param, i)).collect();
            let mut s = vec![-1.0f32; n];
            for (cam, img) in &others {
                let o = plane_scores(&stats, ref_img, &rays, origin, &depths, cam, img, w, h);
                s.iter_mut().zip(o).for_each(|(a, o)| *a = a.max(o));
            }
            s
        });
        for i in 0..n {
            if score[i] > best[i] {
                best[i] = score[i];
                depth[i] = param[i].map_or(0.0, |p| depth_at(p, i) as f32);
            }
        }
    }
    for (d, &b) in depth.iter_mut().zip(&best) {
        if b < options.min_score {
            *d = 0.0;
        }
    }
    DepthMap {
        width: w,
        height: h,
        depth,
    }
}

/// Sweeps one family's planes (`params`, uniform between neighbours; `scores` gives
/// every pixel's NCC on a plane): per pixel the best NCC and its plane's parameter refined
/// by a parabola through the neighbouring planes (`None` at the first or last plane).
fn sweep_family(
    params: &[f64],
    n: usize,
    scores: impl Fn(f64) -> Vec<f32> + Sync,
) -> (Vec<f32>, Vec<Option<f64>>) {
    // Planes in parallel batches; per pixel the best plane and the scores beside it.
    let (mut best, mut best_k) = (vec![f32::MIN; n], vec![usize::MAX; n]);
    let (mut before, mut after) = (vec![-1.0f32; n], vec![-1.0f32; n]);
    let mut prev = vec![-1.0f32; n];
    let batch = rayon::current_num_threads().max(1) * 2;
    for (b, chunk) in params.chunks(batch).enumerate() {
        let batch_scores: Vec<Vec<f32>> = chunk.par_iter().map(|&p| scores(p)).collect();
        for (j, s) in batch_scores.into_iter().enumerate() {
            let k = b * batch + j;
            for i in 0..n {
                if s[i] > best[i] {
                    (best[i], best_k[i], before[i], after[i]) = (s[i], k, prev[i], -1.0);
                } else if best_k[i].wrapping_add(1) == k {
                    after[i] = s[i];
                }
            }
            prev = s;
        }
    }
    let param = (0..n)
        .map(|i| {
            let k = best_k[i];
            if k == 0 || k + 1 >= params.len() {
                return None;
            }
            let (a, b, c) = (before[i], best[i], after[i]);
            let denom = a - 2.0 * b + c;
            let shift = if denom < 0.0 {
                (0.5 * (a - c) / denom).clamp(-0.5, 0.5) as f64
            } else {
                0.0
            };
            Some(params[k] + shift * (params[k + 1] - params[k]))
        })
        .collect();
    (best, param)
}

/// Whether `other`'s depth map agrees with the point `x` (seen at pixel `p` of `camera`).
fn agrees(x: DVec3, p: DVec2, camera: &Camera, other: &Camera, map: &DepthMap) -> bool {
    let Some((q, z)) = other.project(x) else {
        return false;
    };
    let d = map.at(q);
    if d <= 0.0 || (d - z).abs() > DEPTH_TOLERANCE * z {
        return false;
    }
    let centre = DVec2::new(q.x.floor() + 0.5, q.y.floor() + 0.5);
    let back = super::fuse::unproject(other, centre, d);
    camera
        .project(back)
        .is_some_and(|(b, _)| (b - p).length() <= PIXEL_TOLERANCE)
}

/// `view` shrunk to at most `size` pixels on its long side (Triangle filter), with its
/// camera rescaled to match.
fn shrunk(view: &View, size: u32) -> View {
    let (w, h) = view.image.dimensions();
    let long = w.max(h);
    if long <= size || size == 0 {
        return View {
            camera: view.camera.clone(),
            image: view.image.clone(),
            time: view.time,
        };
    }
    let (nw, nh) = (
        ((w as f64 * size as f64 / long as f64).round() as u32).max(1),
        ((h as f64 * size as f64 / long as f64).round() as u32).max(1),
    );
    let mut camera = view.camera.clone();
    camera.intrinsics = camera.intrinsics.scaled_to(nw, nh);
    View {
        camera,
        image: image::imageops::resize(&view.image, nw, nh, image::imageops::FilterType::Triangle),
        time: view.time,
    }
}

/// Sweep one moment's views (each against every other): every confirmed depth as a
/// coloured point of moment `moment` at `time`, and the counts.
pub fn sweep_moment(
    views: &[&View],
    moment: usize,
    time: f64,
    options: &SweepOptions,
) -> (Vec<TimedPoint>, SweepReport) {
    let (points, report) = sweep_views(views, None, options);
    let points = points
        .into_iter()
        .map(|(xyz, rgb)| TimedPoint {
            xyz,
            rgb,
            moment,
            time,
        })
        .collect();
    (points, SweepReport { time, ..report })
}

/// Sweep views of the static scene (the cameras' static plates and the stills), each
/// against the `partners` views best placed to match it ([`partners`]): every confirmed
/// depth as a coloured point, and the counts.
pub fn sweep_static(
    views: &[&View],
    partners: usize,
    options: &SweepOptions,
) -> (Vec<ColouredPoint>, SweepReport) {
    sweep_views(views, Some(partners), options)
}

/// Triangulation angles (degrees) at which a partner view matches a reference best: wide
/// enough for depth, narrow enough that the surface still looks alike.
const PARTNER_ANGLES: (f64, f64) = (5.0, 40.0);
/// Largest angle (degrees) between a partner's viewing direction and the reference's.
const PARTNER_AXIS_ANGLE: f64 = 60.0;

/// The (at most `count`) cameras that best partner `cameras[reference]` in a sweep:
/// looking within [`PARTNER_AXIS_ANGLE`] of its direction, and seeing the point it looks
/// at (at the rig's target depth) under a triangulation angle nearest the middle of
/// [`PARTNER_ANGLES`] (inside it first).
pub fn partners(
    cameras: &[Camera],
    reference: usize,
    count: usize,
    (target, radius): (DVec3, f64),
) -> Vec<usize> {
    let r = &cameras[reference];
    let axis = |c: &Camera| c.world_to_camera.rotation().transpose() * DVec3::Z;
    let centre = r.world_to_camera.centre();
    let looked_at = centre + target_depth(r, target, radius) * axis(r);
    let (lo, hi) = PARTNER_ANGLES;
    let mut scored: Vec<(f64, usize)> = cameras
        .iter()
        .enumerate()
        .filter(|(k, c)| {
            *k != reference && axis(c).angle_between(axis(r)).to_degrees() <= PARTNER_AXIS_ANGLE
        })
        .map(|(k, c)| {
            let angle = (centre - looked_at)
                .angle_between(c.world_to_camera.centre() - looked_at)
                .to_degrees();
            let outside = if angle < lo {
                lo - angle
            } else {
                (angle - hi).max(0.0)
            };
            (outside * 1e3 + (angle - 0.5 * (lo + hi)).abs(), k)
        })
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    scored.into_iter().take(count).map(|(_, k)| k).collect()
}

/// Sweep `views`, each against every other view, or against its `partners` best-placed
/// ones ([`partners`]): every depth that another view's depth map confirms as a coloured
/// point, and the counts.
fn sweep_views(
    views: &[&View],
    partners: Option<usize>,
    options: &SweepOptions,
) -> (Vec<ColouredPoint>, SweepReport) {
    let small: Vec<View> = views.iter().map(|v| shrunk(v, options.size)).collect();
    let views: Vec<&View> = small.iter().collect();
    let views = views.as_slice();
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let mut report = SweepReport::default();
    if views.len() < 2 {
        return (Vec::new(), report);
    }
    let (target, radius) = (rig_target(&cameras), rig_radius(&cameras));
    let greys: Vec<Vec<f32>> = views.iter().map(|v| grey(&v.image)).collect();
    let up = scene_up(&cameras).filter(|_| options.slanted);
    let maps: Vec<DepthMap> = (0..views.len())
        .map(|r| {
            let others = match partners {
                Some(count) => self::partners(&cameras, r, count, (target, radius)),
                None => (0..views.len()).collect(),
            };
            depth_map(views, &greys, r, &others, (target, radius), up, options)
        })
        .collect();
    let mut points = Vec::new();
    for (r, map) in maps.iter().enumerate() {
        let cam = &views[r].camera;
        report.pixels += map.depth.len();
        for (i, &d) in map.depth.iter().enumerate() {
            if d <= 0.0 {
                continue;
            }
            report.matched += 1;
            let p = DVec2::new((i % map.width) as f64 + 0.5, (i / map.width) as f64 + 0.5);
            let x = super::fuse::unproject(cam, p, d as f64);
            let support = 1
                + (0..views.len())
                    .filter(|&o| o != r && agrees(x, p, cam, &views[o].camera, &maps[o]))
                    .count();
            if support < options.min_views.max(2) {
                continue;
            }
            let c = views[r]
                .image
                .get_pixel((i % map.width) as u32, (i / map.width) as u32);
            points.push((x, [c[0] as f32, c[1] as f32, c[2] as f32]));
        }
    }
    report.points = points.len();
    (points, report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_sums_match_a_direct_sum() {
        let (w, h) = (7, 5);
        let v: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 * 0.1).collect();
        let s = box_sums(&v, w, h, 1);
        for y in 0..h {
            for x in 0..w {
                let mut direct = 0.0;
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        direct += v[yy * w + xx];
                    }
                }
                assert!((s[y * w + x] - direct).abs() < 1e-5, "({x}, {y})");
            }
        }
    }

    #[test]
    fn planes_are_uniform_in_inverse_depth_around_the_target() {
        let cam = calib::test_support::looking_at(
            "c",
            shared_types::Intrinsics::from_hfov(64, 48, 60.0),
            DVec3::new(0.0, -2.0, 0.0),
            DVec3::ZERO,
        );
        let d = plane_depths(target_depth(&cam, DVec3::ZERO, 1.0), 5);
        assert!(
            (d[0] - 0.5).abs() < 1e-12 && (d[4] - 8.0).abs() < 1e-9,
            "{d:?}"
        );
        let inv: Vec<f64> = d.iter().map(|d| 1.0 / d).collect();
        for k in 1..4 {
            assert!(((inv[k] - inv[k - 1]) - (inv[k + 1] - inv[k])).abs() < 1e-12);
        }
    }

    #[test]
    fn neighbouring_planes_are_about_a_pixel_of_motion_apart() {
        let intr = shared_types::Intrinsics::from_hfov(320, 240, 60.0);
        let looking = |eye| calib::test_support::looking_at("c", intr, eye, DVec3::ZERO);
        let (a, b) = (
            looking(DVec3::new(0.0, -3.0, 0.5)),
            looking(DVec3::new(2.0, -2.5, 0.5)),
        );
        let d = target_depth(&a, DVec3::ZERO, 1.0);
        let depths = plane_depths(d, plane_count(&a, &[&b], d, 100_000));
        let ray = a.pixel_ray(DVec2::new(160.0, 120.0));
        let z = (a.world_to_camera.rotation() * ray).z;
        let centre = a.world_to_camera.centre();
        let motions: Vec<f64> = depths
            .windows(2)
            .filter_map(|p| {
                let (u, _) = b.project(centre + ray * (p[0] / z))?;
                let (v, _) = b.project(centre + ray * (p[1] / z))?;
                Some((u - v).length())
            })
            .collect();
        let largest = motions.iter().copied().fold(0.0, f64::max);
        let at_target = motions[depths.iter().position(|&x| x >= d).unwrap()];
        assert!(
            largest < 1.5 && (0.3..=1.0).contains(&at_target),
            "{largest} {at_target}"
        );
        // A cap wins over the count.
        assert_eq!(plane_count(&a, &[&b], d, 40), 40);
        assert_eq!(plane_count(&a, &[&b], d, 2), MIN_PLANES);
    }

    /// A random-dot floor (z = 0) seen by `camera`: the image, and each pixel's true depth.
    fn floor_view(camera: &Camera) -> (View, Vec<f64>) {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let hash = |x: i64, y: i64| {
            let v = (x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663)) as u64;
            (v.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 56) as f64 / 255.0
        };
        // Value noise at 2 cm cells, bilinear between cell corners.
        let texture = |u: f64, v: f64| {
            let (x, y) = (u / 0.02, v / 0.02);
            let (x0, y0) = (x.floor(), y.floor());
            let (fx, fy) = (x - x0, y - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let top = hash(x0, y0) * (1.0 - fx) + hash(x0 + 1, y0) * fx;
            let bottom = hash(x0, y0 + 1) * (1.0 - fx) + hash(x0 + 1, y0 + 1) * fx;
            top * (1.0 - fy) + bottom * fy
        };
        let centre = camera.world_to_camera.centre();
        let mut depth = vec![0.0; (w * h) as usize];
        let image = RgbImage::from_fn(w, h, |x, y| {
            let ray = camera.pixel_ray(DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
            if ray.z >= -1e-6 {
                return image::Rgb([128, 128, 128]);
            }
            let t = -centre.z / ray.z;
            let hit = centre + t * ray;
            depth[(y * w + x) as usize] = camera.world_to_camera.apply(hit).z;
            let g = (255.0 * texture(hit.x, hit.y)) as u8;
            image::Rgb([g, g, g])
        });
        let view = View {
            camera: camera.clone(),
            image,
            time: 0.0,
        };
        (view, depth)
    }

    /// Depth maps of the first camera: (pixels with a depth, median relative error).
    fn floor_sweep(slanted: bool) -> (usize, f64) {
        let intr = shared_types::Intrinsics::from_hfov(160, 120, 60.0);
        let target = DVec3::new(0.0, 2.0, 0.0);
        let cameras: Vec<Camera> = [-0.4, 0.0, 0.4]
            .iter()
            .map(|&x| calib::test_support::looking_at("c", intr, DVec3::new(x, 0.0, 0.6), target))
            .collect();
        let views: Vec<(View, Vec<f64>)> = cameras.iter().map(floor_view).collect();
        let refs: Vec<&View> = views.iter().map(|(v, _)| v).collect();
        let greys: Vec<Vec<f32>> = refs.iter().map(|v| grey(&v.image)).collect();
        let options = SweepOptions {
            size: 160,
            max_planes: 256,
            min_score: 0.7,
            min_views: 2,
            slanted,
        };
        let up = scene_up(&cameras).filter(|_| slanted);
        let map = depth_map(&refs, &greys, 0, &[1, 2], (target, 1.0), up, &options);
        let truth = &views[0].1;
        let mut errors: Vec<f64> = map
            .depth
            .iter()
            .zip(truth)
            .filter(|(d, t)| **d > 0.0 && **t > 0.0)
            .map(|(d, t)| (*d as f64 - t).abs() / t)
            .collect();
        errors.sort_by(f64::total_cmp);
        (errors.len(), errors[errors.len() / 2])
    }

    #[test]
    fn a_floor_at_a_grazing_angle_is_found_by_the_level_planes() {
        let cameras = [DVec3::new(-1.0, 0.0, 0.5), DVec3::new(1.0, 0.0, 0.5)].map(|eye| {
            calib::test_support::looking_at(
                "c",
                shared_types::Intrinsics::from_hfov(64, 48, 60.0),
                eye,
                DVec3::new(0.0, 2.0, 0.0),
            )
        });
        let up = scene_up(&cameras).unwrap();
        assert!((up - DVec3::Z).length() < 1e-6, "{up}");
        let (fronto, fronto_error) = floor_sweep(false);
        let (slanted, slanted_error) = floor_sweep(true);
        eprintln!(
            "floor: {fronto} pixels at median error {fronto_error:.4} fronto-parallel only, \
             {slanted} at {slanted_error:.4} with level planes"
        );
        assert!(
            slanted as f64 >= 1.3 * fronto as f64 && slanted_error < 0.01,
            "fronto-parallel only: {fronto} pixels (median error {fronto_error:.4}); \
             with level planes: {slanted} pixels (median error {slanted_error:.4})"
        );
    }

    #[test]
    fn partners_see_what_the_reference_looks_at_from_a_useful_angle() {
        let intr = shared_types::Intrinsics::from_hfov(64, 48, 60.0);
        let target = DVec3::ZERO;
        // Camera k at `degrees` around the target, 3 m away, looking at it.
        let around = |degrees: f64| {
            let a = degrees.to_radians();
            let eye = DVec3::new(3.0 * a.sin(), -3.0 * a.cos(), 0.0);
            calib::test_support::looking_at("c", intr, eye, target)
        };
        let away = calib::test_support::looking_at(
            "away",
            intr,
            DVec3::new(0.5, -3.0, 0.0),
            DVec3::new(0.5, -6.0, 0.0),
        );
        // 0°: the reference; then 20° (inside the useful angles), 2° (too close), 60°
        // (too wide), and a camera beside the reference looking the other way.
        let cameras = [around(0.0), around(60.0), around(2.0), away, around(20.0)];
        assert_eq!(partners(&cameras, 0, 2, (target, 1.0)), [4, 2]);
        assert_eq!(partners(&cameras, 0, 9, (target, 1.0)), [4, 2, 1]);
    }

    #[test]
    fn the_static_sweep_confirms_a_floor_seen_by_a_video_camera_and_a_still() {
        let target = DVec3::new(0.0, 2.0, 0.0);
        // A video camera and a still of another size, 0.5 m to its side.
        let video = calib::test_support::looking_at(
            "cam0",
            shared_types::Intrinsics::from_hfov(160, 120, 60.0),
            DVec3::new(-0.2, 0.0, 0.6),
            target,
        );
        let still = calib::test_support::looking_at(
            "still.jpg",
            shared_types::Intrinsics::from_hfov(200, 150, 55.0),
            DVec3::new(0.2, 0.0, 0.65),
            target,
        );
        let (a, _) = floor_view(&video);
        let (b, _) = floor_view(&still);
        let options = SweepOptions {
            size: 160,
            max_planes: 256,
            min_score: 0.7,
            min_views: 2,
            slanted: true,
        };
        let (points, report) = sweep_static(&[&a, &b], 1, &options);
        assert_eq!(report.points, points.len());
        // Both views shrunk to 160 px on their long side.
        assert_eq!(report.pixels, 160 * 120 * 2);
        let mut heights: Vec<f64> = points.iter().map(|(x, _)| x.z.abs()).collect();
        heights.sort_by(f64::total_cmp);
        let median = heights[heights.len() / 2];
        eprintln!(
            "{} points, median height above the floor {median:.4} m",
            points.len()
        );
        assert!(points.len() > report.pixels / 20, "{report:?}");
        assert!(median < 0.005, "{median}");
    }

    #[test]
    fn bilinear_interpolates_between_pixel_centres() {
        let img = [0.0, 1.0, 2.0, 3.0];
        assert_eq!(bilinear(&img, 2, 2, DVec2::new(0.5, 0.5)), Some(0.0));
        assert_eq!(bilinear(&img, 2, 2, DVec2::new(1.0, 1.0)), Some(1.5));
        assert_eq!(bilinear(&img, 2, 2, DVec2::new(1.5, 1.5)), Some(3.0));
        assert_eq!(bilinear(&img, 2, 2, DVec2::new(0.4, 1.0)), None);
        assert_eq!(bilinear(&img, 2, 2, DVec2::new(f64::NAN, 1.0)), None);
    }
}
