//! A learned backdrop: the far scene as a texture on a sphere around the rig. A pixel's
//! ray leaves the sphere at one point; the backdrop's colour there is the sum of a pyramid
//! of equirectangular textures, coarse to fine and each sampled bilinearly, so a part of
//! the sphere no training view saw takes its neighbourhood's colour from the coarse levels
//! while it is fitted (behind the trained Gaussians, `crate::train::backdrop_fit`). The fit
//! ends by baking it into one level faded to the flat colour in proportion to how little
//! the training views saw of each direction ([`Coverage`]).
//! Every render composites it where the Gaussians leave transmittance:
//! `rgb = rgb₀ + (1 − alpha) · backdrop(ray)`, with `rgb₀` rendered on black.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use crate::Camera;
use crate::trajectories::SceneFrame;

/// The coarsest level's width in texels (its height is half).
const COARSEST: usize = 16;

/// One level of the pyramid: `width × width/2` texels, longitude along x (wrapping),
/// latitude along y (clamped), row-major RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    pub width: usize,
    pub texels: Vec<[f32; 3]>,
}

impl Level {
    fn height(&self) -> usize {
        self.width / 2
    }

    fn taps(&self, uv: Uv, f: impl FnMut(usize, f32)) {
        taps(self.width, uv, f)
    }
}

/// The four bilinear taps of `uv` on an equirectangular grid `width × width/2`:
/// `f(cell index, weight)`.
fn taps(w: usize, [u, v]: Uv, mut f: impl FnMut(usize, f32)) {
    let h = w / 2;
    let x = u * w as f32 - 0.5;
    let y = (v * h as f32 - 0.5).clamp(0.0, (h - 1) as f32);
    // floor by truncation (`y` ≥ 0; `x` ≥ −0.5 for u in 0..1, any finite u handled):
    // a libm call per tap otherwise.
    let x0 = x as i64 - i64::from(x < (x as i64) as f32);
    let y0 = y as usize;
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let col = |d: i64| (x0 + d).rem_euclid(w as i64) as usize;
    let y1 = (y0 + 1).min(h - 1);
    f(y0 * w + col(0), (1.0 - fx) * (1.0 - fy));
    f(y0 * w + col(1), fx * (1.0 - fy));
    f(y1 * w + col(0), (1.0 - fx) * fy);
    f(y1 * w + col(1), fx * fy);
}

/// How much each training camera sees of each direction of the backdrop past the
/// Gaussians: per camera and per cell of a coarse equirectangular grid, the summed
/// transmittance of its pixels whose rays meet the sphere there.
#[derive(Clone, Debug, PartialEq)]
pub struct Coverage {
    pub width: usize,
    /// Per camera name, its grid (`width × width/2`, row-major).
    pub cameras: BTreeMap<String, Vec<f32>>,
}

/// The quantile of a camera's seen cells' coverage at which it sees a cell well.
const WELL_SEEN_QUANTILE: f32 = 0.9;

/// How many cameras must see a direction well for its learned colour to be kept whole:
/// one camera's view of it, with no second to fix where on the sphere it lies, is drawn
/// out of place from elsewhere (measured on two real captures and the simulated room:
/// two beat one everywhere, and three gives up the panels a novel view needs, BENCHMARKS.md
/// "A learned backdrop").
const WELL_SEEN_BY: f32 = 2.0;

impl Coverage {
    /// No camera's coverage yet, on a grid `width × width/2` (width even).
    pub fn new(width: usize) -> Self {
        Self {
            width,
            cameras: BTreeMap::new(),
        }
    }

    /// Add each pixel's transmittance `1 − alpha` in a view of `camera` where its ray
    /// meets the backdrop (`uvs`).
    pub fn add(&mut self, camera: &str, uvs: &[Uv], alpha: &[f32]) {
        let cells = self.width * self.width / 2;
        let seen = self
            .cameras
            .entry(camera.to_string())
            .or_insert_with(|| vec![0.0; cells]);
        for (&uv, &a) in uvs.iter().zip(alpha) {
            let t = (1.0 - a).max(0.0);
            taps(self.width, uv, |i, w| seen[i] += w * t);
        }
    }

    /// Per cell, how far to trust the learned colour: each camera's share, 1 where it sees
    /// the cell as well as the [`WELL_SEEN_QUANTILE`] of the cells it sees, falling
    /// linearly to 0 where it never does, summed over the cameras and divided by
    /// [`WELL_SEEN_BY`] (at most 1).
    fn weights(&self) -> Vec<f32> {
        let mut total = vec![0.0f32; self.width * self.width / 2];
        for seen in self.cameras.values() {
            let mut sorted: Vec<f32> = seen.iter().copied().filter(|&s| s > 0.0).collect();
            if sorted.is_empty() {
                continue;
            }
            sorted.sort_by(f32::total_cmp);
            let well = sorted[((sorted.len() - 1) as f32 * WELL_SEEN_QUANTILE).round() as usize];
            for (t, &s) in total.iter_mut().zip(seen) {
                *t += (s / well).min(1.0);
            }
        }
        total.iter().map(|t| (t / WELL_SEEN_BY).min(1.0)).collect()
    }
}

/// Where a ray meets the backdrop, in texture coordinates `0..1` (longitude, latitude
/// from the top).
pub type Uv = [f32; 2];

/// The backdrop sphere and its texture pyramid.
#[derive(Clone, Debug, PartialEq)]
pub struct Backdrop {
    pub centre: DVec3,
    pub radius: f64,
    /// Orthonormal frame: `axes[2]` is up (latitude), `axes[0]` longitude 0.
    pub axes: [DVec3; 3],
    /// Coarsest first; each twice the width of the one before.
    pub levels: Vec<Level>,
}

/// The quantile of the static points' distances from the rig's target that sets the
/// sphere: the far walls rather than the floor and objects in front of them.
const RADIUS_QUANTILE: f64 = 0.75;

impl Backdrop {
    /// A backdrop around what `cameras` look at: its radius the 75th percentile of the
    /// static points' distances from there (the farthest camera's distance without
    /// points), its texture `colour` everywhere, `finest_width` texels around at the
    /// finest level (rounded to a power of two, at least the coarsest 16).
    pub fn around(
        cameras: &[Camera],
        static_points: &[[f32; 3]],
        colour: [f32; 3],
        finest_width: usize,
    ) -> Option<Self> {
        let frame = SceneFrame::from_cameras(cameras)?;
        let mut dist: Vec<f64> = static_points
            .iter()
            .map(|p| (DVec3::from_array(p.map(f64::from)) - frame.centre).length())
            .filter(|d| d.is_finite())
            .collect();
        dist.sort_by(f64::total_cmp);
        let radius = match dist.len() {
            0 => cameras
                .iter()
                .map(|c| (c.world_to_camera.centre() - frame.centre).length())
                .fold(0.0, f64::max),
            n => dist[((n - 1) as f64 * RADIUS_QUANTILE).round() as usize],
        };
        if !(radius > 1e-9 && radius.is_finite()) {
            return None;
        }
        let up = frame.up;
        let e0 = up.any_orthonormal_vector();
        let mut levels = Vec::new();
        let mut width = COARSEST;
        loop {
            let fill = if levels.is_empty() { colour } else { [0.0; 3] };
            levels.push(Level {
                width,
                texels: vec![fill; width * width / 2],
            });
            if width >= finest_width {
                break;
            }
            width *= 2;
        }
        Some(Self {
            centre: frame.centre,
            radius,
            axes: [e0, up.cross(e0), up],
            levels,
        })
    }

    /// Where the ray `origin + t·dir` (t > 0) leaves the sphere; its direction itself
    /// when it misses (an origin outside looking away).
    pub fn uv(&self, origin: DVec3, dir: DVec3) -> Uv {
        let o = origin - self.centre;
        let b = o.dot(dir);
        let disc = b * b - (o.length_squared() - self.radius * self.radius);
        let n = if disc >= 0.0 && -b + disc.sqrt() > 0.0 {
            o + dir * (-b + disc.sqrt())
        } else {
            dir
        };
        self.direction_uv(n)
    }

    /// Texture coordinates of the direction of `v` from the centre.
    fn direction_uv(&self, v: DVec3) -> Uv {
        use std::f64::consts::{PI, TAU};
        let n = v.normalize_or_zero();
        let [e0, e1, up] = self.axes;
        let lon = n.dot(e1).atan2(n.dot(e0));
        let lat = n.dot(up).clamp(-1.0, 1.0).asin();
        [(lon / TAU + 0.5) as f32, (0.5 - lat / PI) as f32]
    }

    /// Per pixel of `camera` (row-major, pixel centres), where its ray meets the backdrop.
    pub fn pixel_uvs(&self, camera: &Camera) -> Vec<Uv> {
        let w = camera.intrinsics.width as usize;
        let h = camera.intrinsics.height as usize;
        let origin = camera.world_to_camera.centre();
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let p = DVec2::new((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                self.uv(origin, camera.pixel_ray(p))
            })
            .collect()
    }

    /// The colour at `uv`.
    pub fn sample(&self, uv: Uv) -> [f32; 3] {
        let mut out = [0.0f32; 3];
        for level in &self.levels {
            level.taps(uv, |i, w| {
                let t = level.texels[i];
                (0..3).for_each(|c| out[c] += w * t[c]);
            });
        }
        out
    }

    /// Draw the backdrop behind `frame`, rendered on black from `camera`.
    pub fn draw(&self, camera: &Camera, frame: &mut crate::render::Rendered<f32>) {
        let behind = self.colours(&self.pixel_uvs(camera));
        composite(&behind, &mut frame.rgb, &frame.alpha);
    }

    /// The backdrop's colour at each of `uvs`.
    pub fn colours(&self, uvs: &[Uv]) -> Vec<[f32; 3]> {
        uvs.par_iter().map(|&uv| self.sample(uv)).collect()
    }

    /// The backward of [`composite`] of `behind` (this backdrop's [`Self::colours`] at
    /// `uvs`): from `d_rgb` (dL/d composited colour), the gradient of the render's alpha
    /// (written into `d_alpha`) and of the texels (added into `grads`, shaped by
    /// [`Self::zero_grads`]).
    pub fn composite_backward(
        &self,
        uvs: &[Uv],
        behind: &[[f32; 3]],
        alpha: &[f32],
        d_rgb: &[f32],
        d_alpha: &mut Vec<f32>,
        grads: &mut [Vec<[f32; 3]>],
    ) {
        d_alpha.clear();
        d_alpha.extend(
            d_rgb
                .chunks_exact(3)
                .zip(behind)
                .map(|(g, b)| -(g[0] * b[0] + g[1] * b[1] + g[2] * b[2])),
        );
        // Each level's gradient on its own thread: the same sums in the same pixel order
        // as one loop, so the result does not depend on the thread count.
        self.levels
            .par_iter()
            .zip(grads.par_iter_mut())
            .for_each(|(level, gl)| {
                for ((g, &a), &uv) in d_rgb.chunks_exact(3).zip(alpha).zip(uvs) {
                    let t = 1.0 - a;
                    level.taps(uv, |i, w| (0..3).for_each(|c| gl[i][c] += w * t * g[c]));
                }
            });
    }

    /// Zeroed gradients shaped like the levels.
    pub fn zero_grads(&self) -> Vec<Vec<[f32; 3]>> {
        let zero = |l: &Level| vec![[0.0; 3]; l.texels.len()];
        self.levels.iter().map(zero).collect()
    }

    /// The pyramid summed into one texture of the finest level's size (what the viewer
    /// draws; bilinear sampling of it differs from [`Self::sample`] only between texels).
    pub fn baked(&self) -> Level {
        self.baked_with(|_, colour| colour)
    }

    /// The finest level's texels, each `texel(uv, summed colour)`.
    fn baked_with(&self, texel: impl Fn(Uv, [f32; 3]) -> [f32; 3] + Sync) -> Level {
        let finest = self.levels.last().expect("a backdrop has levels");
        let (w, h) = (finest.width, finest.height());
        let texels = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let uv = [
                    ((i % w) as f32 + 0.5) / w as f32,
                    ((i / w) as f32 + 0.5) / h as f32,
                ];
                texel(uv, self.sample(uv))
            })
            .collect();
        Level { width: w, texels }
    }

    /// This backdrop baked into one level, its colour faded to `colour` where the training
    /// views did not see it (`coverage`): a direction no training view saw past the
    /// Gaussians has only the coarse levels' spill from its neighbours, which a novel view
    /// would show as lamps and panels out of place.
    pub fn faded(&self, coverage: &Coverage, colour: [f32; 3]) -> Backdrop {
        let weights = coverage.weights();
        let level = self.baked_with(|uv, c| {
            let mut w = 0.0;
            taps(coverage.width, uv, |i, k| w += k * weights[i]);
            [0, 1, 2].map(|k| w * c[k] + (1.0 - w) * colour[k])
        });
        Backdrop {
            centre: self.centre,
            radius: self.radius,
            axes: self.axes,
            levels: vec![level],
        }
    }
}

/// `rgb += (1 − alpha) · behind` per pixel (`rgb` rendered on black, `behind` the
/// backdrop's colours there).
pub fn composite(behind: &[[f32; 3]], rgb: &mut [f32], alpha: &[f32]) {
    rgb.par_chunks_exact_mut(3)
        .zip(alpha)
        .zip(behind)
        .for_each(|((px, &a), b)| (0..3).for_each(|c| px[c] += (1.0 - a) * b[c]));
}

/// Per fixed camera (name and size), where its pixels meet a backdrop: for views that are
/// drawn again and again (training, eval).
#[derive(Default)]
pub struct UvCache(HashMap<(String, u32, u32), Arc<Vec<Uv>>>);

impl UvCache {
    pub fn get(&mut self, backdrop: &Backdrop, camera: &Camera) -> Arc<Vec<Uv>> {
        let i = &camera.intrinsics;
        let key = (camera.name.clone(), i.width, i.height);
        self.0
            .entry(key)
            .or_insert_with(|| Arc::new(backdrop.pixel_uvs(camera)))
            .clone()
    }
}

/// Why a backdrop file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum BackdropFileError {
    #[error("cannot access backdrop {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path} is not a valid backdrop file ({reason}); rerun the train stage (`pipeline run DIR --only train --force`)"
    )]
    Corrupt { path: PathBuf, reason: String },
}

const MAGIC: [u8; 8] = *b"S4DBKDRP";
const VERSION: u32 = 1;

/// Write `backdrop` to `path` (atomically): magic, version, level count, centre, radius,
/// axes (`f64`), level widths (`u32`), then every level's texels (`f32`), little-endian.
pub fn save_backdrop(backdrop: &Backdrop, path: &Path) -> Result<(), BackdropFileError> {
    let mut buf = Vec::new();
    buf.extend_from_slice(&MAGIC);
    buf.extend_from_slice(&VERSION.to_le_bytes());
    buf.extend_from_slice(&(backdrop.levels.len() as u32).to_le_bytes());
    let frame = [
        backdrop.centre,
        backdrop.axes[0],
        backdrop.axes[1],
        backdrop.axes[2],
    ];
    for v in std::iter::once(backdrop.radius).chain(frame.iter().flat_map(|a| a.to_array())) {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    for level in &backdrop.levels {
        buf.extend_from_slice(&(level.width as u32).to_le_bytes());
    }
    for level in &backdrop.levels {
        for v in level.texels.as_flattened() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    crate::atomic::write_atomic(path, &buf).map_err(|source| BackdropFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Read a backdrop written by [`save_backdrop`].
pub fn load_backdrop(path: &Path) -> Result<Backdrop, BackdropFileError> {
    let bytes = std::fs::read(path).map_err(|source| BackdropFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let corrupt = |reason: String| BackdropFileError::Corrupt {
        path: path.to_path_buf(),
        reason,
    };
    const FIXED: usize = 16 + 13 * 8;
    if bytes.len() < FIXED || bytes[..8] != MAGIC {
        return Err(corrupt("bad magic".into()));
    }
    let u32_at = |i: usize| u32::from_le_bytes(bytes[i..i + 4].try_into().expect("4 bytes"));
    let f64_at = |i: usize| f64::from_le_bytes(bytes[i..i + 8].try_into().expect("8 bytes"));
    if u32_at(8) != VERSION {
        return Err(corrupt(format!("version {}", u32_at(8))));
    }
    let count = u32_at(12) as usize;
    let radius = f64_at(16);
    let vec_at = |k: usize| {
        DVec3::new(
            f64_at(24 + 24 * k),
            f64_at(32 + 24 * k),
            f64_at(40 + 24 * k),
        )
    };
    let widths_end = FIXED.checked_add(4 * count).filter(|&e| e <= bytes.len());
    let widths: Vec<usize> = match widths_end {
        Some(_) if count > 0 => (0..count).map(|k| u32_at(FIXED + 4 * k) as usize).collect(),
        _ => return Err(corrupt(format!("{count} levels"))),
    };
    if widths.iter().any(|&w| w < 2 || w % 2 != 0 || w > 1 << 16) {
        return Err(corrupt(format!("level widths {widths:?}")));
    }
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(corrupt(format!("radius {radius}")));
    }
    let floats: usize = widths.iter().map(|w| 3 * w * w / 2).sum();
    let payload = &bytes[FIXED + 4 * count..];
    if payload.len() != 4 * floats {
        return Err(corrupt(format!(
            "{} bytes of texels, expected {}",
            payload.len(),
            4 * floats
        )));
    }
    let mut values = payload
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")));
    let levels = widths
        .iter()
        .map(|&width| Level {
            width,
            texels: (0..width * width / 2)
                .map(|_| [(); 3].map(|_| values.next().expect("counted")))
                .collect(),
        })
        .collect();
    Ok(Backdrop {
        centre: vec_at(0),
        radius,
        axes: [vec_at(1), vec_at(2), vec_at(3)],
        levels,
    })
}

/// Adam over a backdrop's texels.
#[derive(Clone, Debug, PartialEq)]
pub struct BackdropAdam {
    m: Vec<Vec<[f32; 3]>>,
    v: Vec<Vec<[f32; 3]>>,
    step: u32,
    /// The learning rate of the next step (colour units per step).
    pub lr: f32,
}

impl BackdropAdam {
    pub fn new(backdrop: &Backdrop, lr: f32) -> Self {
        Self {
            m: backdrop.zero_grads(),
            v: backdrop.zero_grads(),
            step: 0,
            lr,
        }
    }

    /// One Adam step of `backdrop`'s texels along `grads`.
    pub fn apply(&mut self, backdrop: &mut Backdrop, grads: &[Vec<[f32; 3]>]) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        self.step += 1;
        let c1 = 1.0 - B1.powi(self.step as i32);
        let c2 = 1.0 - B2.powi(self.step as i32);
        let lr = self.lr;
        backdrop
            .levels
            .par_iter_mut()
            .zip(self.m.par_iter_mut().zip(self.v.par_iter_mut()))
            .zip(grads)
            .for_each(|((level, (ms, vs)), gl)| {
                for (((t, m), v), g) in level.texels.iter_mut().zip(ms).zip(vs).zip(gl) {
                    for c in 0..3 {
                        m[c] = B1 * m[c] + (1.0 - B1) * g[c];
                        v[c] = B2 * v[c] + (1.0 - B2) * g[c] * g[c];
                        t[c] -= lr * (m[c] / c1) / ((v[c] / c2).sqrt() + 1e-15);
                    }
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Intrinsics, WorldToCamera};

    fn camera(name: &str, eye: DVec3, width: u32) -> Camera {
        Camera {
            name: name.into(),
            intrinsics: Intrinsics::from_hfov(width, width / 2, 70.0),
            distortion: Default::default(),
            world_to_camera: WorldToCamera::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap(),
        }
    }

    fn rig() -> Vec<Camera> {
        (0..4)
            .map(|k| {
                let a = k as f64 * 0.6;
                camera(
                    &format!("cam{k}"),
                    DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.5),
                    16,
                )
            })
            .collect()
    }

    #[test]
    fn the_radius_is_the_far_quantile_of_the_static_points() {
        // 3 of 4 points at distance 3 from the rig's target (the origin), 1 at 1.
        let pts = [
            [3.0, 0.0, 0.0],
            [0.0, 3.0, 0.0],
            [0.0, 0.0, -3.0],
            [1.0, 0.0, 0.0],
        ];
        let b = Backdrop::around(&rig(), &pts, [0.5; 3], 64).unwrap();
        assert!(b.centre.length() < 1e-6, "{}", b.centre);
        assert!((b.radius - 3.0).abs() < 1e-6, "{}", b.radius);
        assert_eq!(
            b.levels.iter().map(|l| l.width).collect::<Vec<_>>(),
            [16, 32, 64]
        );
        assert_eq!(b.sample([0.3, 0.7]), [0.5; 3]);
        // Without points: the farthest camera.
        let b = Backdrop::around(&rig(), &[], [0.5; 3], 16).unwrap();
        assert!((b.radius - (4.0f64 + 0.25).sqrt()).abs() < 1e-6);
    }

    #[test]
    fn a_ray_meets_the_sphere_where_it_leaves_it() {
        let b = Backdrop::around(&rig(), &[[2.5, 0.0, 0.0]], [0.0; 3], 16).unwrap();
        let origin = DVec3::new(0.7, -0.4, 0.3);
        for dir in [
            DVec3::X,
            DVec3::new(-1.0, 2.0, 0.5),
            DVec3::new(0.2, -0.1, -1.0),
        ] {
            let d = dir.normalize();
            // f64 reference: march to the sphere and bisect.
            let (mut lo, mut hi) = (0.0f64, 10.0f64);
            for _ in 0..200 {
                let m = 0.5 * (lo + hi);
                if (origin + d * m).length() < 2.5 {
                    lo = m
                } else {
                    hi = m
                }
            }
            let hit = origin + d * lo;
            let want = b.direction_uv(hit);
            let got = b.uv(origin, d);
            assert!((got[0] - want[0]).abs() < 1e-6 && (got[1] - want[1]).abs() < 1e-6);
        }
        // The rig's up is the top row, longitude 0 the middle of the equator.
        assert!(b.axes[2].z > 0.9, "{}", b.axes[2]);
        assert!(b.uv(b.centre, b.axes[2])[1].abs() < 1e-6);
        let [u, v] = b.uv(b.centre, b.axes[0]);
        assert!((u - 0.5).abs() < 1e-6 && (v - 0.5).abs() < 1e-6);
    }

    #[test]
    fn the_composite_backward_matches_finite_differences() {
        let mut b = Backdrop::around(&rig(), &[[2.5, 0.0, 0.0]], [0.3, 0.5, 0.7], 64).unwrap();
        // Texture every level so that each tap matters.
        for (l, level) in b.levels.iter_mut().enumerate() {
            for (i, t) in level.texels.iter_mut().enumerate() {
                *t = [0, 1, 2].map(|c| 0.1 * ((i * 7 + c * 3 + l) % 5) as f32);
            }
        }
        let cam = camera("c", DVec3::new(0.3, 0.2, 0.1), 8);
        let uvs = b.pixel_uvs(&cam);
        let n = uvs.len();
        let rgb0: Vec<f32> = (0..3 * n).map(|i| 0.01 * (i % 13) as f32).collect();
        let alpha: Vec<f32> = (0..n).map(|i| 0.1 + 0.8 * (i % 7) as f32 / 7.0).collect();
        let w: Vec<f32> = (0..3 * n)
            .map(|i| ((i * 5) % 11) as f32 / 11.0 - 0.4)
            .collect();
        let loss = |b: &Backdrop, alpha: &[f32]| {
            let mut rgb = rgb0.clone();
            composite(&b.colours(&uvs), &mut rgb, alpha);
            rgb.iter().zip(&w).map(|(x, w)| (x * w) as f64).sum::<f64>()
        };
        let mut grads = b.zero_grads();
        let mut d_alpha = Vec::new();
        b.composite_backward(&uvs, &b.colours(&uvs), &alpha, &w, &mut d_alpha, &mut grads);
        let h = 1e-2f32;
        for (l, i, c) in [(0, 3, 0), (1, 40, 1), (2, 100, 2), (2, 257, 0)] {
            let mut plus = b.clone();
            plus.levels[l].texels[i][c] += h;
            let mut minus = b.clone();
            minus.levels[l].texels[i][c] -= h;
            let fd = (loss(&plus, &alpha) - loss(&minus, &alpha)) / (2.0 * h as f64);
            let an = grads[l][i][c] as f64;
            assert!(
                (fd - an).abs() < 1e-3 * (1.0 + fd.abs()),
                "texel ({l},{i},{c}): {fd} vs {an}"
            );
        }
        assert!(grads[2].iter().flatten().any(|g| g.abs() > 1e-3));
        for k in [0, n / 3, n - 1] {
            let mut a = alpha.clone();
            a[k] += h;
            let up = loss(&b, &a);
            a[k] -= 2.0 * h;
            let fd = (up - loss(&b, &a)) / (2.0 * h as f64);
            assert!(
                (fd - d_alpha[k] as f64).abs() < 1e-3 * (1.0 + fd.abs()),
                "alpha {k}"
            );
        }
    }

    #[test]
    fn files_round_trip_and_bad_ones_name_themselves() {
        let dir = tempfile::tempdir().unwrap();
        let mut b = Backdrop::around(&rig(), &[[2.5, 0.0, 0.0]], [0.3, 0.5, 0.7], 64).unwrap();
        b.levels[2].texels[5] = [1.0, -0.5, 0.25];
        let path = dir.path().join("backdrop.bin");
        save_backdrop(&b, &path).unwrap();
        assert!(load_backdrop(&path).unwrap() == b);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 4]).unwrap();
        let e = load_backdrop(&path).unwrap_err().to_string();
        assert!(
            e.contains("backdrop.bin") && e.contains("--only train"),
            "{e}"
        );
        std::fs::write(&path, b"not a backdrop").unwrap();
        assert!(
            load_backdrop(&path)
                .unwrap_err()
                .to_string()
                .contains("bad magic")
        );
    }

    #[test]
    fn adam_moves_only_seen_texels_and_the_bake_sums_the_levels() {
        let mut b = Backdrop::around(&rig(), &[[2.5, 0.0, 0.0]], [0.5; 3], 32).unwrap();
        let mut adam = BackdropAdam::new(&b, 0.01);
        let mut grads = b.zero_grads();
        grads[1][10] = [1.0, -1.0, 0.0];
        adam.apply(&mut b, &grads);
        let t = b.levels[1].texels[10];
        assert!((t[0] + 0.01).abs() < 1e-6 && (t[1] - 0.01).abs() < 1e-6 && t[2] == 0.0);
        assert_eq!(b.levels[1].texels[11], [0.0; 3]);
        let baked = b.baked();
        assert_eq!(baked.width, 32);
        let uv = [0.5 / 32.0 + 7.0 / 32.0, 0.5 / 16.0 + 3.0 / 16.0];
        let s = b.sample(uv);
        let k = 3 * 32 + 7;
        (0..3).for_each(|c| assert!((baked.texels[k][c] - s[c]).abs() < 1e-6));
    }

    #[test]
    fn the_fade_keeps_what_two_cameras_saw_and_flattens_the_rest() {
        let mut b = Backdrop::around(&rig(), &[[2.5, 0.0, 0.0]], [0.5; 3], 32).unwrap();
        for (i, t) in b.levels[1].texels.iter_mut().enumerate() {
            *t = [0.01 * (i % 7) as f32, 0.2, -0.1];
        }
        // Cell centres of a 16 × 8 grid, each seen whole by one pixel: camera a sees
        // columns 0..8, camera b columns 4..12 and one cell barely.
        let centre = |col: usize, row: usize| [(col as f32 + 0.5) / 16.0, (row as f32 + 0.5) / 8.0];
        let columns = |cols: std::ops::Range<usize>| -> Vec<Uv> {
            cols.flat_map(|c| (0..8).map(move |r| centre(c, r)))
                .collect()
        };
        let mut coverage = Coverage::new(16);
        coverage.add("a", &columns(0..8), &[0.0; 64]);
        let mut uvs = columns(4..12);
        let mut alpha = vec![0.0f32; uvs.len()];
        uvs.push(centre(14, 4));
        alpha.push(0.9);
        coverage.add("b", &uvs, &alpha);
        let total: f64 = coverage.cameras["b"].iter().map(|&s| f64::from(s)).sum();
        let reference: f64 = alpha.iter().map(|&a| 1.0 - f64::from(a)).sum();
        assert!((total - reference).abs() < 1e-5, "{total} vs {reference}");
        let w = coverage.weights();
        let cell = |col: usize, row: usize| w[row * 16 + col];
        assert_eq!(cell(5, 3), 1.0, "seen well by both");
        assert_eq!((cell(1, 3), cell(10, 6)), (0.5, 0.5), "by one");
        assert!((cell(14, 4) - 0.05).abs() < 1e-6, "{}", cell(14, 4));
        assert_eq!(cell(14, 6), 0.0);

        let flat = [0.1, 0.2, 0.3];
        let faded = b.faded(&coverage, flat);
        assert_eq!(
            (faded.centre, faded.radius, faded.axes),
            (b.centre, b.radius, b.axes)
        );
        assert_eq!(faded.levels.len(), 1);
        let texel = |col: usize, row: usize| {
            let uv = [(col as f32 + 0.5) / 32.0, (row as f32 + 0.5) / 16.0];
            (faded.levels[0].texels[row * 32 + col], b.sample(uv))
        };
        // Seen by both: the learned colour; by one: halfway; by none: the flat colour.
        let (kept, learned) = texel(12, 9);
        (0..3).for_each(|c| assert!((kept[c] - learned[c]).abs() < 1e-6, "{kept:?}"));
        let (half, learned) = texel(4, 9);
        (0..3).for_each(|c| {
            let mid = 0.5 * (learned[c] + flat[c]);
            assert!((half[c] - mid).abs() < 1e-6, "{half:?}");
        });
        assert_eq!(texel(29, 12).0, flat);
    }
}
