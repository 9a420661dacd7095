//! Shared helpers of the engine's integration tests: a tiny deterministic RNG, random
//! scenes in front of a camera, and cameras.
#![allow(dead_code)]

use glam::{DMat3, DVec3};
use splat4d::{
    Camera, ColourDegrees, Distortion, Gaussians, Intrinsics, TimeMapping, WorldToCamera,
};

/// SplitMix64: deterministic, dependency-free.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// A camera at `eye` looking at `target` (x right, y down, z forward, right-handed).
pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> WorldToCamera {
    let z = (target - eye).normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(x);
    let r = DMat3::from_cols(x, y, z).transpose();
    WorldToCamera::from_parts(r, -(r * eye))
}

/// A pinhole camera on the −y axis at distance 4 looking at the origin (z up).
pub fn camera(width: u32, height: u32) -> Camera {
    Camera {
        name: "test".into(),
        intrinsics: Intrinsics::from_hfov(width, height, 50.0),
        distortion: Distortion::None,
        world_to_camera: look_at(DVec3::new(0.3, -4.0, 0.5), DVec3::ZERO, DVec3::Z),
    }
}

/// Options for [`random_scene`].
#[derive(Clone, Copy, Debug)]
pub struct SceneSpec {
    pub count: usize,
    /// Range of spatial log-scales.
    pub log_scale: (f64, f64),
    /// Range of opacity logits.
    pub logit: (f64, f64),
    /// Scale of the non-DC colour coefficients.
    pub rest: f64,
    pub degrees: ColourDegrees,
}

impl Default for SceneSpec {
    fn default() -> Self {
        Self {
            count: 8,
            log_scale: (-2.2, -1.2),
            logit: (-1.0, 1.5),
            rest: 0.15,
            degrees: ColourDegrees::FULL,
        }
    }
}

/// A random scene around the origin, time span [0, 1], with random rotations.
pub fn random_scene(seed: u64, spec: SceneSpec) -> Gaussians<f64> {
    let mut rng = Rng(seed);
    let mut g = Gaussians::<f64>::new(
        spec.degrees,
        TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 1.0,
        },
    );
    g.active = spec.degrees;
    for _ in 0..spec.count {
        let mean = [
            rng.range(-0.8, 0.8),
            rng.range(-0.8, 0.8),
            rng.range(-0.6, 0.6),
            rng.range(0.3, 0.7),
        ];
        let ls = [
            rng.range(spec.log_scale.0, spec.log_scale.1),
            rng.range(spec.log_scale.0, spec.log_scale.1),
            rng.range(spec.log_scale.0, spec.log_scale.1),
            rng.range(-0.8, 0.0),
        ];
        let i = g.push(
            mean,
            ls,
            rng.range(spec.logit.0, spec.logit.1),
            [rng.uniform(), rng.uniform(), rng.uniform()],
        );
        // Rotations: near identity in the space-time planes (so the Gaussian stays
        // visible in time), arbitrary in space.
        g.rot_left[i] = [
            1.0 + 0.3 * rng.normal(),
            0.4 * rng.normal(),
            0.4 * rng.normal(),
            0.4 * rng.normal(),
        ];
        g.rot_right[i] = [
            1.0 + 0.3 * rng.normal(),
            0.15 * rng.normal(),
            0.15 * rng.normal(),
            0.15 * rng.normal(),
        ];
        let k = g.coeffs_per_channel();
        let base = i * 3 * k;
        for j in 3..3 * k {
            g.colours[base + j] = spec.rest * rng.normal();
        }
    }
    g
}

/// Random per-pixel weights in [-1, 1] (a linear loss `Σ w·output`).
pub fn weights(seed: u64, n: usize) -> Vec<f64> {
    let mut rng = Rng(seed);
    (0..n).map(|_| rng.range(-1.0, 1.0)).collect()
}

pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Relative error `|a − b| / max(|a|, |b|, floor)` of two gradient vectors (2-norms).
pub fn rel_err(analytic: &[f64], numeric: &[f64], floor: f64) -> f64 {
    let diff: f64 = analytic
        .iter()
        .zip(numeric)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt();
    let na: f64 = analytic.iter().map(|a| a * a).sum::<f64>().sqrt();
    let nb: f64 = numeric.iter().map(|a| a * a).sum::<f64>().sqrt();
    diff / na.max(nb).max(floor)
}

/// An empty model with spatial and temporal colour degree 1 (the hard-case tests' model).
pub fn hard_model() -> Gaussians<f64> {
    let mut g = Gaussians::new(
        ColourDegrees {
            spatial: 1,
            temporal: 1,
        },
        TimeMapping::default(),
    );
    g.active = g.capacity;
    g
}

/// Push the extreme-scale Gaussians every backend's hard-case tests draw (in front of
/// [`camera`] at t = 0.5): a flat disk (1e-6 thick, rotated), a 1e-6 point, a 1e3 blob and
/// a 1e3 × 1e-6 × 1e-6 needle.
pub fn push_extreme_scales(g: &mut Gaussians<f64>) {
    let disk = g.push(
        [0.0, 0.0, 0.0, 0.5],
        [-14.0, -1.0, -14.0, 0.0],
        1.5,
        [0.9, 0.9, 0.1],
    );
    g.rot_left[disk] = [0.8, 0.1, 0.5, 0.2];
    let tiny = (1e-6f64).ln();
    let huge = (1e3f64).ln();
    g.push(
        [-0.3, 0.2, 0.1, 0.5],
        [tiny, tiny, tiny, 0.0],
        3.0,
        [1.0, 0.0, 0.0],
    );
    g.push(
        [0.1, 2.0, 0.0, 0.5],
        [huge, huge, huge, 0.0],
        -2.0,
        [0.0, 0.0, 1.0],
    );
    g.push(
        [0.0, 0.0, 0.3, 0.5],
        [huge, tiny, tiny, 0.0],
        0.0,
        [0.3, 0.3, 0.3],
    );
}

/// `n` faint, nearly identical Gaussians stacked on the centre pixel of [`camera`] at
/// t = 0.5 (1e-5 apart, tiny opacity and rotation differences): the hard-case pile.
pub fn stacked_splats(n: usize) -> Gaussians<f64> {
    let mut g = hard_model();
    for k in 0..n {
        let d = 1e-5 * k as f64;
        let id = g.push(
            [0.0, d, 0.0, 0.5],
            [-4.0, -4.0, -4.0, 0.0],
            -4.5 + 1e-4 * (k % 7) as f64,
            [(k % 3) as f64 / 2.0, 0.5, 1.0],
        );
        g.rot_left[id] = [1.0, 1e-3 * (k % 5) as f64, 0.0, 0.0];
    }
    g
}

/// A world point (with time `t`) at camera coordinates `(x, y, z)` of `cam`.
pub fn at_camera(cam: &Camera, x: f64, y: f64, z: f64, t: f64) -> [f64; 4] {
    let p = cam.world_to_camera.inverse_apply(DVec3::new(x, y, z));
    [p.x, p.y, p.z, t]
}

/// The shared GPU backend of a test binary (a software adapter such as lavapipe is
/// allowed). Without an adapter: a panic under `CI=true`, else `None` with a line saying
/// `what` was skipped.
pub fn gpu(what: &str) -> Option<&'static splat4d::render::gpu::GpuBackend> {
    use splat4d::gpu::AdapterPolicy;
    use splat4d::render::gpu::GpuBackend;
    static GPU: std::sync::OnceLock<Result<GpuBackend, String>> = std::sync::OnceLock::new();
    match GPU
        .get_or_init(|| GpuBackend::new(AdapterPolicy::AllowSoftware).map_err(|e| e.to_string()))
    {
        Ok(g) => Some(g),
        Err(e) => {
            if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
                panic!(
                    "no GPU adapter under CI=true: {e}; run scripts/setup.sh (mesa-vulkan-drivers)"
                );
            }
            eprintln!("SKIPPED {what}: {e}");
            None
        }
    }
}
