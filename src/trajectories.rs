//! Camera paths for rendering a trained model: an orbit or a spiral around the scene
//! centre, a smooth interpolation through the training cameras (Catmull-Rom on centres,
//! slerp on rotations), or the training / held-out cameras themselves; each frame paired
//! with the model time it shows (frozen, swept over the sequence, or real time).
//!
//! Pure geometry on the shared [`Camera`] type (OpenCV convention, world-to-camera).
//! Rendering and files are elsewhere (`eval`).

use std::f64::consts::TAU;
use std::str::FromStr;

use glam::{DMat3, DQuat, DVec3};

use crate::camera::{Camera, Distortion, Intrinsics, WorldToCamera};
use crate::model::TimeMapping;

/// Which way the camera travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathKind {
    /// A closed circle around the scene centre at the training cameras' mean distance and
    /// height, starting at the first training camera's azimuth, looking at the centre.
    Orbit,
    /// Two turns around the centre with radius and height gently varying, looking at it.
    Spiral,
    /// Smoothly through the training cameras in their order (hits each one exactly).
    Interpolate,
    /// The training cameras, one block of frames each.
    Train,
    /// The held-out cameras, one block of frames each.
    Heldout,
}

/// Which moment each frame shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeMode {
    /// Frozen at this capture time in seconds.
    Fixed(f64),
    /// From the start to the end of the sequence over the frames of the path.
    Sweep,
    /// Real time at the output frame rate from the start, looping over the sequence.
    Real,
}

/// Error parsing a `--path` or `--time` value.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("'{value}' is not a valid {what}; use {expected}")]
pub struct ParseError {
    pub value: String,
    pub what: &'static str,
    pub expected: &'static str,
}

impl FromStr for PathKind {
    type Err = ParseError;
    fn from_str(s: &str) -> Result<Self, ParseError> {
        Ok(match s {
            "orbit" => PathKind::Orbit,
            "spiral" => PathKind::Spiral,
            "interpolate" => PathKind::Interpolate,
            "train" => PathKind::Train,
            "heldout" => PathKind::Heldout,
            _ => {
                return Err(ParseError {
                    value: s.into(),
                    what: "camera path",
                    expected: "orbit, spiral, interpolate, train or heldout",
                });
            }
        })
    }
}

impl FromStr for TimeMode {
    type Err = ParseError;
    fn from_str(s: &str) -> Result<Self, ParseError> {
        let bad = || ParseError {
            value: s.into(),
            what: "time mode",
            expected: "fixed:SECONDS (e.g. fixed:1.5), sweep or real",
        };
        match s {
            "sweep" => Ok(TimeMode::Sweep),
            "real" => Ok(TimeMode::Real),
            _ => {
                let t: f64 = s
                    .strip_prefix("fixed:")
                    .and_then(|v| v.parse().ok())
                    .ok_or_else(bad)?;
                if t.is_finite() {
                    Ok(TimeMode::Fixed(t))
                } else {
                    Err(bad())
                }
            }
        }
    }
}

/// What to generate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSpec {
    pub kind: PathKind,
    pub time: TimeMode,
    /// Number of frames (> 0).
    pub frames: usize,
    /// Output frame rate (used by [`TimeMode::Real`]).
    pub fps: f64,
    /// Output image size; `None` keeps the first training camera's size (for `train` /
    /// `heldout`: each camera's own).
    pub size: Option<(u32, u32)>,
    /// Point to look at; `None` uses [`SceneFrame::from_cameras`].
    pub centre: Option<DVec3>,
}

impl PathSpec {
    /// A spec with the given kind, time mode and frame count, 30 fps, native size,
    /// automatic centre.
    pub fn new(kind: PathKind, time: TimeMode, frames: usize) -> Self {
        Self {
            kind,
            time,
            frames,
            fps: 30.0,
            size: None,
            centre: None,
        }
    }
}

/// Why no path could be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PathError {
    #[error("a camera path needs at least one frame")]
    NoFrames,
    #[error("the {what} path needs {needed} camera(s) but {got} were given; check cameras.json")]
    TooFewCameras {
        what: &'static str,
        needed: usize,
        got: usize,
    },
    #[error("the output frame rate {0} is not positive")]
    BadFps(f64),
    #[error("output size {width}×{height} is empty; give a positive width and height")]
    EmptySize { width: u32, height: u32 },
    #[error(
        "frame {frame} of the path looks straight along the up direction (or sits on the centre); choose another path or centre"
    )]
    Degenerate { frame: usize },
}

/// The scene's centre and up direction as seen by a set of cameras.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneFrame {
    /// The point closest (least squares) to all optical axes; the centroid of the
    /// camera centres when the axes are (nearly) parallel.
    pub centre: DVec3,
    /// Unit world direction that points up in the images on average.
    pub up: DVec3,
}

impl SceneFrame {
    /// Estimate centre and up from cameras (at least one).
    pub fn from_cameras(cameras: &[Camera]) -> Option<Self> {
        if cameras.is_empty() {
            return None;
        }
        let mut a = DMat3::ZERO;
        let mut b = DVec3::ZERO;
        let mut up = DVec3::ZERO;
        let mut centroid = DVec3::ZERO;
        for cam in cameras {
            let w2c = &cam.world_to_camera;
            let r = w2c.rotation();
            // Camera axes in world coordinates are the rows of R.
            let axis = r.row(2);
            up -= r.row(1);
            let c = w2c.centre();
            centroid += c;
            let p = DMat3::IDENTITY - outer(axis, axis);
            a += p;
            b += p * c;
        }
        centroid /= cameras.len() as f64;
        let up = up.try_normalize().unwrap_or(DVec3::Z);
        // Well-conditioned only when the axes are not all parallel.
        let centre = if a.determinant().abs() > 1e-6 * (cameras.len() as f64).powi(3) {
            a.inverse() * b
        } else {
            centroid
        };
        Some(Self { centre, up })
    }
}

fn outer(u: DVec3, v: DVec3) -> DMat3 {
    DMat3::from_cols(u * v.x, u * v.y, u * v.z)
}

/// Intrinsics of the generated views: the reference camera's field of view at `size`,
/// principal point at the image centre.
fn path_intrinsics(reference: &Intrinsics, size: Option<(u32, u32)>) -> Intrinsics {
    let (w, h) = size.unwrap_or((reference.width, reference.height));
    let fx = reference.fx * w as f64 / reference.width as f64;
    Intrinsics {
        width: w,
        height: h,
        fx,
        fy: fx * reference.fy / reference.fx,
        cx: 0.5 * w as f64,
        cy: 0.5 * h as f64,
    }
}

/// Model time of frame `i` of `n`.
fn frame_time(mode: TimeMode, i: usize, n: usize, fps: f64, mapping: &TimeMapping) -> f64 {
    let duration = if mapping.duration.is_finite() && mapping.duration > 0.0 {
        mapping.duration
    } else {
        0.0
    };
    match mode {
        TimeMode::Fixed(seconds) => mapping.model_time(seconds),
        TimeMode::Sweep if n > 1 => duration * i as f64 / (n - 1) as f64,
        TimeMode::Sweep => 0.0,
        TimeMode::Real => {
            let t = i as f64 / fps * mapping.units_per_second;
            if duration > 0.0 { t % duration } else { 0.0 }
        }
    }
}

fn camera_at(name: String, intrinsics: Intrinsics, w2c: WorldToCamera) -> Camera {
    Camera {
        name,
        intrinsics,
        distortion: Distortion::None,
        world_to_camera: w2c,
    }
}

/// Uniform Catmull-Rom through `p1`→`p2` at `u ∈ [0, 1]`.
fn catmull_rom(p0: DVec3, p1: DVec3, p2: DVec3, p3: DVec3, u: f64) -> DVec3 {
    let (u2, u3) = (u * u, u * u * u);
    0.5 * (2.0 * p1
        + (p2 - p0) * u
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * u2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * u3)
}

/// The cameras and model times of a path. `train` are the training cameras (they set
/// the centre, up direction, radius and field of view); `heldout` is used only by
/// [`PathKind::Heldout`]. Every generated camera is an undistorted pinhole.
pub fn camera_path(
    spec: &PathSpec,
    train: &[Camera],
    heldout: &[Camera],
    time: &TimeMapping,
) -> Result<Vec<(Camera, f64)>, PathError> {
    let n = spec.frames;
    if n == 0 {
        return Err(PathError::NoFrames);
    }
    if !(spec.fps > 0.0 && spec.fps.is_finite()) {
        return Err(PathError::BadFps(spec.fps));
    }
    if let Some((width, height)) = spec.size
        && (width == 0 || height == 0)
    {
        return Err(PathError::EmptySize { width, height });
    }
    let too_few = |what, needed, got| PathError::TooFewCameras { what, needed, got };
    let t_of = |i| frame_time(spec.time, i, n, spec.fps, time);
    match spec.kind {
        PathKind::Train | PathKind::Heldout => {
            let (cams, what) = if spec.kind == PathKind::Train {
                (train, "train")
            } else {
                (heldout, "heldout")
            };
            if cams.is_empty() {
                return Err(too_few(what, 1, 0));
            }
            Ok((0..n)
                .map(|i| {
                    let cam = &cams[i * cams.len() / n];
                    let intr = match spec.size {
                        Some((w, h)) => cam.intrinsics.scaled_to(w, h),
                        None => cam.intrinsics,
                    };
                    (
                        camera_at(cam.name.clone(), intr, cam.world_to_camera),
                        t_of(i),
                    )
                })
                .collect())
        }
        PathKind::Interpolate => {
            let k = train.len();
            if k < 2 {
                return Err(too_few("interpolate", 2, k));
            }
            let intr = path_intrinsics(&train[0].intrinsics, spec.size);
            let centres: Vec<DVec3> = train.iter().map(|c| c.world_to_camera.centre()).collect();
            // Camera-to-world rotations as quaternions, sign-aligned with their neighbour.
            let mut quats: Vec<DQuat> = Vec::with_capacity(k);
            for c in train {
                let q = DQuat::from_mat3(&c.world_to_camera.rotation().transpose()).normalize();
                let q = match quats.last() {
                    Some(prev) if prev.dot(q) < 0.0 => -q,
                    _ => q,
                };
                quats.push(q);
            }
            let point = |j: isize| -> DVec3 {
                if j < 0 {
                    2.0 * centres[0] - centres[1]
                } else if j as usize >= k {
                    2.0 * centres[k - 1] - centres[k - 2]
                } else {
                    centres[j as usize]
                }
            };
            Ok((0..n)
                .map(|i| {
                    let s = if n > 1 {
                        (k - 1) as f64 * i as f64 / (n - 1) as f64
                    } else {
                        0.0
                    };
                    let seg = (s.floor() as usize).min(k - 2);
                    let u = s - seg as f64;
                    let j = seg as isize;
                    let eye = catmull_rom(point(j - 1), point(j), point(j + 1), point(j + 2), u);
                    let c2w = DMat3::from_quat(quats[seg].slerp(quats[seg + 1], u));
                    let r = c2w.transpose();
                    let w2c = WorldToCamera::from_parts(r, -(r * eye));
                    (camera_at(format!("interpolate_{i:06}"), intr, w2c), t_of(i))
                })
                .collect())
        }
        PathKind::Orbit | PathKind::Spiral => {
            let frame = SceneFrame::from_cameras(train).ok_or(too_few("orbit", 1, 0))?;
            let centre = spec.centre.unwrap_or(frame.centre);
            let up = frame.up;
            let intr = path_intrinsics(&train[0].intrinsics, spec.size);
            let (mut radius, mut height) = (0.0, 0.0);
            for c in train {
                let d = c.world_to_camera.centre() - centre;
                height += d.dot(up);
                radius += (d - d.dot(up) * up).length();
            }
            radius /= train.len() as f64;
            height /= train.len() as f64;
            let d0 = train[0].world_to_camera.centre() - centre;
            let u0 = (d0 - d0.dot(up) * up)
                .try_normalize()
                .or_else(|| up.any_orthonormal_vector().try_normalize())
                .ok_or(PathError::Degenerate { frame: 0 })?;
            let u1 = up.cross(u0);
            let spiral = spec.kind == PathKind::Spiral;
            let name = if spiral { "spiral" } else { "orbit" };
            (0..n)
                .map(|i| {
                    let phase = i as f64 / n as f64;
                    let (angle, r, h) = if spiral {
                        (
                            2.0 * TAU * phase,
                            radius * (1.0 - 0.15 * (TAU * phase).cos()),
                            height + 0.25 * radius * (TAU * phase).sin(),
                        )
                    } else {
                        (TAU * phase, radius, height)
                    };
                    let eye = centre + h * up + r * (angle.cos() * u0 + angle.sin() * u1);
                    let w2c = WorldToCamera::look_at(eye, centre, up)
                        .ok_or(PathError::Degenerate { frame: i })?;
                    Ok((camera_at(format!("{name}_{i:06}"), intr, w2c), t_of(i)))
                })
                .collect()
        }
    }
}
