//! The static scene shared by every chunk: the first chunk's Gaussians that stand still
//! over its frames, frozen as static Gaussians (each its slice at the chunk's middle: no
//! velocity, alive for all time), so they draw the same at every moment of the clip.

use splat4d::Gaussians;
use splat4d::export::bake::{SH_COEFFS, bake_rows, linear_motion};
use splat4d::train::densify::gather_gaussians;

/// Log temporal scale of a frozen static Gaussian: σ = e¹¹ model units (hours of clip),
/// so its temporal weight is 1 wherever a clip can reach (the engine clamps at 12).
pub const STATIC_LOG_TIME_SCALE: f32 = 11.0;

/// Smallest temporal weight a Gaussian that stands still keeps over its window: it lives
/// through the window, if faintly at its ends (a wall split twice by densification has a
/// temporal σ 2.56 times shorter than the clip's span it started with).
const MIN_WEIGHT: f64 = 0.1;

/// Whether Gaussian `i` stands still over the model times `window`: it lives through all
/// of it (its temporal weight at least [`MIN_WEIGHT`] at both ends) and its centre moves
/// at most `max_drift` (world units) from one end to the other. The walls of a 4D fit
/// drift a little (on the demo room over 1.5 s: 3 cm for half of them, 13 cm for the
/// 99th percentile); what moves is short-lived or moves much further.
pub fn stands_still(model: &Gaussians<f32>, i: usize, window: (f64, f64), max_drift: f64) -> bool {
    let (_, velocity, s44, _) = linear_motion(model, i);
    let centre = model.means[i][3] as f64;
    let alive = |t: f64| (t - centre).powi(2) <= -2.0 * MIN_WEIGHT.ln() * s44;
    let length = (window.1 - window.0).abs();
    let speed = velocity.iter().map(|v| v * v).sum::<f64>().sqrt();
    alive(window.0) && alive(window.1) && speed * length <= max_drift
}

/// The indices of `model`'s Gaussians that stand still over `window`, and of the others.
pub fn split(
    model: &Gaussians<f32>,
    window: (f64, f64),
    max_drift: f64,
) -> (Vec<usize>, Vec<usize>) {
    (0..model.len()).partition(|&i| stands_still(model, i, window, max_drift))
}

/// How far a Gaussian that stands still may drift over a chunk of `seconds`: as far as
/// the scene's extent (the radius of the camera centres × 1.1: 4 m for the demo rig) in
/// 30 s, and at least 5 % of it. The walls of a short fit drift at a roughly constant
/// speed, so their drift grows with the chunk: over the demo's 1.5 s, 0.6 % of the extent
/// for half of them and 3 % for the 99th percentile; over a 5.4-s chunk of the
/// minute-long clip trained 400 steps, 9 % for half and 36 % for the 99th percentile. A
/// fixed 5 % froze a sixth of that chunk's Gaussians and left later chunks without their
/// walls. A person walking at 1 m/s on the demo rig drifts 7.5 times further.
pub fn max_drift(scene_extent: f64, seconds: f64) -> f64 {
    scene_extent * (seconds / 30.0).max(0.05)
}

/// `model`'s Gaussians `rows` frozen at model time `t`: each its slice at `t` (conditional
/// mean and covariance, opacity × temporal weight, colour folded at `t`) as a 4D Gaussian
/// that does not move and lives for all time. Rows culled at `t` are left out.
pub fn freeze(model: &Gaussians<f32>, rows: &[usize], t: f64) -> Gaussians<f32> {
    let part = gather_gaussians(model, rows);
    let mut out = Gaussians::new(model.capacity, model.time);
    out.active = model.active;
    let spatial = model.capacity.spatial_count().min(SH_COEFFS);
    let coeffs = 3 * model.coeffs_per_channel();
    for splat in bake_rows(&part, t, 0.0).into_iter().flatten() {
        let [x, y, z] = splat.position;
        out.means.push([x, y, z, t as f32]);
        let [a, b, c] = splat.log_scale;
        out.log_scales.push([a, b, c, STATIC_LOG_TIME_SCALE]);
        // ql = qr = q is the 3D rotation q that leaves time alone.
        out.rot_left.push(splat.rotation);
        out.rot_right.push(splat.rotation);
        out.opacity_logits.push(splat.opacity_logit);
        let start = out.colours.len();
        out.colours.resize(start + coeffs, 0.0);
        for (s, sh) in splat.sh.iter().take(spatial).enumerate() {
            out.colours[start + 3 * s..start + 3 * s + 3].copy_from_slice(sh);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};
    use splat4d::model::{ColourDegrees, TimeMapping};
    use splat4d::{CpuBackend, RenderBackend, RenderOptions};

    /// A wall of slowly drifting, long-lived Gaussians with colour in every degree, a
    /// short-lived one and a fast one.
    fn model() -> Gaussians<f32> {
        let mut m = Gaussians::new(
            ColourDegrees::FULL,
            TimeMapping::frames_over_30(0.0, 30.0, 4.0),
        );
        for k in 0..12 {
            let (x, y) = ((k % 4) as f32 * 0.3 - 0.45, (k / 4) as f32 * 0.3 - 0.3);
            let i = m.push(
                [x, y, 0.0, 2.0],
                [-2.0, -2.5, -3.0, 1.5],
                1.0,
                [0.2 + 0.05 * k as f32, 0.5, 0.7],
            );
            // A small tilt of the 4D rotation: a slow drift and a rotated ellipse.
            m.rot_left[i] = [1.0, 0.02, 0.1 * k as f32 / 12.0, 0.03];
            m.rot_right[i] = [1.0, 0.0, 0.1 * k as f32 / 12.0, 0.0];
            let n = m.coeffs_per_channel();
            for (j, c) in m.colours[i * 3 * n..(i + 1) * 3 * n]
                .iter_mut()
                .enumerate()
                .skip(3)
            {
                *c = 0.05 * ((j * 7 + k) % 5) as f32 - 0.1;
            }
        }
        // Short-lived (σt = e^-2 model units) and fast (strongly tilted in x–t).
        m.push(
            [0.0, 0.0, 0.2, 2.0],
            [-2.0, -2.0, -2.0, -2.0],
            2.0,
            [1.0, 0.0, 0.0],
        );
        let fast = m.push(
            [0.1, 0.1, 0.2, 2.0],
            [-2.0, -2.0, -2.0, 1.5],
            2.0,
            [0.0, 1.0, 0.0],
        );
        m.rot_left[fast] = [0.9, 0.4, 0.0, 0.0];
        m.rot_right[fast] = [0.9, -0.4, 0.0, 0.0];
        m.active = ColourDegrees::FULL;
        m
    }

    fn camera() -> Camera {
        Camera {
            name: "cam".into(),
            intrinsics: Intrinsics::from_hfov(64, 48, 60.0),
            distortion: Distortion::None,
            world_to_camera: WorldToCamera::look_at(
                glam::DVec3::new(0.2, -0.3, 2.0),
                glam::DVec3::ZERO,
                glam::DVec3::Y,
            )
            .unwrap(),
        }
    }

    fn render(m: &Gaussians<f32>, t: f64) -> Vec<f32> {
        let options = RenderOptions::default();
        CpuBackend
            .render(m, &camera(), t as f32, &options)
            .unwrap()
            .rgb
    }

    #[test]
    fn the_wall_stands_still_and_the_short_lived_and_fast_ones_move() {
        let m = model();
        let (still, moving) = split(&m, (1.0, 3.0), 0.1);
        assert_eq!(still, (0..12).collect::<Vec<_>>());
        assert_eq!(moving, [12, 13]);
        // The fast one stands still for a drift limit beyond its travel (about 1.1 per
        // unit of time), the wall's slow drift (about 0.03 per unit) not below its own.
        assert_eq!(split(&m, (1.0, 3.0), 10.0).0.len(), 13);
        assert!(split(&m, (1.0, 3.0), 0.01).0.is_empty());
        // Over a window much longer than the wall lives, nothing stands still; the wall
        // (σt ≈ e^1.5 = 4.5 around t = 2) keeps a tenth of its weight up to about t = 11.
        assert!(split(&m, (0.0, 100.0), 10.0).0.is_empty());
        assert_eq!(split(&m, (9.5, 10.0), 10.0).0.len(), 12);
        assert!(split(&m, (13.0, 13.5), 10.0).0.is_empty());
    }

    #[test]
    fn the_drift_allowed_grows_with_the_chunk_from_five_percent_of_the_extent() {
        // The demo rig's extent, 4 m.
        assert!((max_drift(4.0, 1.0) - 0.2).abs() < 1e-12);
        assert!((max_drift(4.0, 1.5) - 0.2).abs() < 1e-12);
        assert!((max_drift(4.0, 6.0) - 0.8).abs() < 1e-12);
        // A person walking at 1 m/s for those 6 s drifts 7.5 times further.
        assert!(1.0 * 6.0 >= 7.5 * max_drift(4.0, 6.0) - 1e-12);
    }

    #[test]
    fn a_frozen_wall_draws_its_slice_at_every_time() {
        let m = model();
        let rows: Vec<usize> = (0..12).collect();
        let frozen = freeze(&m, &rows, 2.0);
        assert_eq!(frozen.len(), 12);
        let wall = gather_gaussians(&m, &rows);
        let want = render(&wall, 2.0);
        assert!(want.iter().any(|&v| v > 0.05), "the wall is not in view");
        for t in [2.0, 0.0, 3.9, 50.0] {
            let got = render(&frozen, t);
            let err = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(err < 2e-3, "t = {t}: max difference {err}");
        }
        // The original drifts: at another time it draws differently, the frozen one not.
        let drifted = render(&wall, 3.9);
        let moved = drifted
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(moved > 1e-2, "the test wall does not move ({moved})");
        // Frozen Gaussians stand still over any window.
        assert_eq!(split(&frozen, (-1e3, 1e3), 1e-3).0.len(), 12);
    }
}
