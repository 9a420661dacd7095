//! The benchmark scene: `n` Gaussians with a realistic spread of sizes, and its camera.
#![allow(dead_code)]

use glam::{DMat3, DVec3};
use splat4d::model::ColourDegrees;
use splat4d::{Camera, Distortion, Gaussians, Intrinsics, TimeMapping, WorldToCamera};

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
    fn normal(&mut self) -> f32 {
        let u1 = self.uniform().max(1e-7);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }
}

/// `n` Gaussians in a 3×3×3 box seen from 4 units away; the median scale shrinks with
/// √n so the image coverage (overdraw) stays similar across sizes.
pub fn scene(n: usize) -> Gaussians<f32> {
    let mut rng = Rng(42);
    let mut g = Gaussians::<f32>::new(ColourDegrees::FULL, TimeMapping::default());
    g.active = ColourDegrees::FULL;
    let median = 0.0146 * (100_000.0 / n as f32).sqrt();
    for _ in 0..n {
        let mean = [
            3.0 * rng.uniform() - 1.5,
            3.0 * rng.uniform() - 1.5,
            3.0 * rng.uniform() - 1.5,
            rng.uniform(),
        ];
        let ls = [
            median.ln() + 0.8 * rng.normal(),
            median.ln() + 0.8 * rng.normal(),
            median.ln() + 0.8 * rng.normal(),
            (0.3f32).ln() + 0.3 * rng.normal(),
        ];
        let i = g.push(
            mean,
            ls,
            1.5 * rng.normal(),
            [rng.uniform(), rng.uniform(), rng.uniform()],
        );
        let q = [rng.normal(), rng.normal(), rng.normal(), rng.normal()];
        g.rot_left[i] = q;
        g.rot_right[i] = [q[0] + 0.1 * rng.normal(), q[1], q[2], q[3]];
        let k = g.coeffs_per_channel();
        for j in 3..3 * k {
            g.colours[i * 3 * k + j] = 0.05 * rng.normal();
        }
    }
    g
}

pub fn camera() -> Camera {
    let eye = DVec3::new(0.5, -4.5, 1.0);
    let z = (DVec3::ZERO - eye).normalize();
    let x = z.cross(DVec3::Z).normalize();
    let y = z.cross(x);
    let r = DMat3::from_cols(x, y, z).transpose();
    Camera {
        name: "bench".into(),
        intrinsics: Intrinsics::from_hfov(512, 384, 50.0),
        distortion: Distortion::None,
        world_to_camera: WorldToCamera::from_parts(r, -(r * eye)),
    }
}
