//! A straightforward `f64` reference renderer for tests: explicit 4×4 covariance,
//! the textbook conditional `Σ11 − Σ12 Σ12ᵀ / Σ44`, explicit `J W Σ Wᵀ Jᵀ`, and per-pixel
//! blending over all Gaussians sorted by depth — no tiles, no factored forms, no caches.
//! Slow by design; it must never be used outside checks.

use crate::Camera;
use crate::math::numerics::{MIN_TIME_VARIANCE, scale_from_log, sigmoid};
use crate::math::project::{EXTENT_SIGMAS, JACOBIAN_GUARD_BAND, LOW_PASS};
use crate::math::rotation4d::rotation;
use crate::math::sh::{ColourInput, colour};
use crate::math::slice::TEMPORAL_CUTOFF;
use crate::model::Gaussians;
use crate::render::cpu::blend::{ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN};
use crate::render::{RenderError, RenderOptions};

/// Output of the reference renderer (same layout as [`crate::Rendered`]).
#[derive(Clone, Debug)]
pub struct ReferenceImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<f64>,
    pub alpha: Vec<f64>,
    pub depth: Vec<f64>,
}

struct RefSplat {
    mean: [f64; 2],
    conic: [f64; 3],
    opacity: f64,
    colour: [f64; 3],
    depth: f64,
}

/// Render `model` per pixel in `f64`.
pub fn render_reference(
    model: &Gaussians<f64>,
    camera: &Camera,
    t: f64,
    options: &RenderOptions<f64>,
) -> Result<ReferenceImage, RenderError> {
    if !camera.distortion.is_none() {
        return Err(RenderError::DistortedCamera {
            camera: camera.name.clone(),
        });
    }
    model
        .check_consistent()
        .map_err(RenderError::InconsistentModel)?;
    let intr = camera.intrinsics;
    let (width, height) = (intr.width, intr.height);
    let w2c = camera.world_to_camera;
    let wr = w2c.rotation;
    let centre = w2c.centre();
    let period = if model.time.duration > 0.0 {
        model.time.duration
    } else {
        1.0
    };
    let mut splats = Vec::new();
    for i in 0..model.len() {
        let (r, _) = rotation(model.rot_left[i], model.rot_right[i]);
        let s2: Vec<f64> = (0..4)
            .map(|k| scale_from_log(model.log_scales[i][k]).0.powi(2))
            .collect();
        let mut sig = [[0.0; 4]; 4];
        for a in 0..4 {
            for b in 0..4 {
                sig[a][b] = (0..4).map(|k| r[a][k] * s2[k] * r[b][k]).sum();
            }
        }
        let s44 = sig[3][3].max(MIN_TIME_VARIANCE);
        let mu = model.means[i];
        let dt = t - mu[3];
        let omega = (-0.5 * dt * dt / s44).exp();
        if omega <= TEMPORAL_CUTOFF {
            continue;
        }
        let factor = options.opacity_factor.map_or(1.0, |f| f[i]);
        let opacity = sigmoid(model.opacity_logits[i]) * omega * factor;
        if opacity < ALPHA_MIN {
            continue;
        }
        let m3: Vec<f64> = (0..3).map(|a| mu[a] + sig[a][3] / s44 * dt).collect();
        let mut c3 = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                c3[a][b] = sig[a][b] - sig[a][3] * sig[b][3] / s44;
            }
        }
        let p: Vec<f64> = (0..3)
            .map(|a| (0..3).map(|b| wr[a][b] * m3[b]).sum::<f64>() + w2c.translation[a])
            .collect();
        let z = p[2];
        if !(z >= options.near_plane) {
            continue;
        }
        let clamp = |u: f64, c: f64, f: f64, n: u32| {
            let n = n as f64;
            u.clamp(
                (-JACOBIAN_GUARD_BAND * n - c) / f,
                ((1.0 + JACOBIAN_GUARD_BAND) * n - c) / f,
            )
        };
        let ux = clamp(p[0] / z, intr.cx, intr.fx, width);
        let uy = clamp(p[1] / z, intr.cy, intr.fy, height);
        let j = [
            [intr.fx / z, 0.0, -intr.fx * ux / z],
            [0.0, intr.fy / z, -intr.fy * uy / z],
        ];
        // cov_cam = W Σ3 Wᵀ, then J cov_cam Jᵀ.
        let mut cc = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                cc[a][b] = (0..3)
                    .flat_map(|k| (0..3).map(move |l| (k, l)))
                    .map(|(k, l)| wr[a][k] * c3[k][l] * wr[b][l])
                    .sum();
            }
        }
        let mut c2 = [[0.0; 2]; 2];
        for a in 0..2 {
            for b in 0..2 {
                c2[a][b] = (0..3)
                    .flat_map(|k| (0..3).map(move |l| (k, l)))
                    .map(|(k, l)| j[a][k] * cc[k][l] * j[b][l])
                    .sum();
            }
        }
        c2[0][0] += LOW_PASS;
        c2[1][1] += LOW_PASS;
        let det = c2[0][0] * c2[1][1] - c2[0][1] * c2[1][0];
        if !(det > 0.0) {
            continue;
        }
        let conic = [c2[1][1] / det, -c2[0][1] / det, c2[0][0] / det];
        let input = ColourInput {
            mean: mu,
            coeffs: model.colour_of(i),
            capacity: model.capacity,
            active: model.active,
            camera_centre: [centre.x, centre.y, centre.z],
            t,
            period,
        };
        splats.push((
            i,
            RefSplat {
                mean: [intr.fx * p[0] / z + intr.cx, intr.fy * p[1] / z + intr.cy],
                conic,
                opacity,
                colour: colour(&input),
                depth: z,
            },
        ));
    }
    splats.sort_by(|a, b| {
        (a.1.depth as f32)
            .total_cmp(&(b.1.depth as f32))
            .then(a.0.cmp(&b.0))
    });
    let npix = (width * height) as usize;
    let mut out = ReferenceImage {
        width,
        height,
        rgb: vec![0.0; 3 * npix],
        alpha: vec![0.0; npix],
        depth: vec![0.0; npix],
    };
    let max_d2 = EXTENT_SIGMAS * EXTENT_SIGMAS;
    for py in 0..height {
        for px in 0..width {
            let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
            let mut tr = 1.0;
            let mut c = [0.0; 3];
            let mut d = 0.0;
            for (_, s) in &splats {
                let (dx, dy) = (x - s.mean[0], y - s.mean[1]);
                let d2 = s.conic[0] * dx * dx + 2.0 * s.conic[1] * dx * dy + s.conic[2] * dy * dy;
                if d2 > max_d2 || d2 < 0.0 {
                    continue;
                }
                let alpha = (s.opacity * (-0.5 * d2).exp()).min(ALPHA_MAX);
                if alpha < ALPHA_MIN {
                    continue;
                }
                if tr * (1.0 - alpha) < TRANSMITTANCE_MIN {
                    break;
                }
                for ch in 0..3 {
                    c[ch] += s.colour[ch] * alpha * tr;
                }
                d += s.depth * alpha * tr;
                tr *= 1.0 - alpha;
            }
            let p = (py * width + px) as usize;
            for ch in 0..3 {
                out.rgb[3 * p + ch] = c[ch] + tr * options.background[ch];
            }
            out.alpha[p] = 1.0 - tr;
            out.depth[p] = d;
        }
    }
    Ok(out)
}
