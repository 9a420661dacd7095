//! `.splatv`, the dynamic-splat format of antimatter15's splaTV (also read by gsplat.js's
//! `SplatvLoader`). Layout:
//!
//! - `u32` magic `0x674b` (26443), `u32` byte length `J` of the JSON that follows;
//! - `J` bytes of JSON: `[{"type":"splat","size":S,"texwidth":4096,"texheight":H,
//!   "cameras":[…]}]` (cameras as in 3DGS `cameras.json`: `position` = camera centre,
//!   `rotation` = camera-to-world rotation, rows);
//! - `S = 4096·H·16` bytes: an RGBA32UI texture, 4 texels (16 `u32`) per splat:
//!   `[0..3]` position as `f32` bits, `[3]` half2(qw, qx), `[4]` half2(qy, qz),
//!   `[5]` half2(sx, sy), `[6]` half2(sz, 0), `[7]` RGBA8; `[8..11]` motion: half2(vx, vy),
//!   half2(vz, 0) then zero acceleration/jerk terms; `[12]` zero, `[13..14]` zero angular
//!   velocity, `[15]` half2(t_centre, t_scale). Scales are linear σ, the quaternion is
//!   `(w, x, y, z)`; half2(a, b) puts `a` in the low 16 bits.
//!
//! The viewer draws a splat at `position + velocity·(τ − t_centre)` with opacity
//! `a · exp(−((τ − t_centre)/t_scale)²)`, and plays `τ` over `[0, 1]` (splaTV and gsplat.js
//! drive it with `sin(clock)/2 + 1/2`). Times are therefore stored as fractions of the
//! model's sequence, `τ = t / T` for model time `t ∈ [0, T]` (`T` = the model's duration),
//! so that the player's `[0, 1]` is the whole clip: `t_centre = μt / T`,
//! `t_scale = √(2 Σ44) / T` and velocities in world units per `τ` (`T · Σ12/Σ44`).
//! A 4D Gaussian maps onto this exactly (its conditional mean is linear in t, its
//! conditional covariance constant) except for colour, which is reduced to one RGB: the
//! spherindrical colour at the Gaussian's own time centre, seen from `colour_view`.

use super::bake::{colour_period, folded_sh, linear_motion};
use super::{ExportError, write_atomic};
use crate::math::numerics::sigmoid;
use crate::math::sh::{ColourInput, colour};
use crate::model::{ColourDegrees, Gaussians};
use half::f16;
use std::path::Path;

/// The splaTV magic number (`"Kg"` little-endian).
pub const MAGIC: u32 = 0x674b;
/// Splats per texture row.
const PER_ROW: usize = 1024;

/// One dynamic splat as stored (after half-float rounding when decoded).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplatvSplat {
    pub position: [f32; 3],
    /// `(w, x, y, z)`.
    pub rotation: [f32; 4],
    /// Linear standard deviations.
    pub scale: [f32; 3],
    pub rgba: [u8; 4],
    /// World units per unit of `τ` (the sequence played as `[0, 1]`).
    pub velocity: [f32; 3],
    /// Time centre as a fraction `τ` of the sequence.
    pub t_centre: f32,
    /// Opacity falls as `exp(−((τ − t_centre)/t_scale)²)` (`τ` units).
    pub t_scale: f32,
}

/// A camera in the JSON header (3DGS `cameras.json` convention).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SplatvCamera {
    pub id: usize,
    pub img_name: String,
    pub width: u32,
    pub height: u32,
    /// Camera centre in world coordinates.
    pub position: [f64; 3],
    /// Camera-to-world rotation, rows.
    pub rotation: [[f64; 3]; 3],
    pub fx: f64,
    pub fy: f64,
}

impl SplatvCamera {
    /// From an engine camera.
    pub fn from_camera(id: usize, cam: &crate::Camera) -> Self {
        let c2w = cam.world_to_camera.rotation().transpose();
        Self {
            id,
            img_name: cam.name.clone(),
            width: cam.intrinsics.width,
            height: cam.intrinsics.height,
            position: cam.world_to_camera.centre().to_array(),
            rotation: std::array::from_fn(|r| std::array::from_fn(|c| c2w.col(c)[r])),
            fx: cam.intrinsics.fx,
            fy: cam.intrinsics.fy,
        }
    }
}

/// RGB in `[0, 1]` of Gaussian `i` at model time `t`, seen from `view_from` (or DC only
/// when `None`), using the engine's colour function.
pub fn baked_rgb(
    model: &Gaussians<f32>,
    i: usize,
    t: f64,
    view_from: Option<[f64; 3]>,
) -> [f64; 3] {
    let sh = folded_sh(model, i, t);
    let flat: Vec<f64> = sh.iter().flat_map(|c| c.map(|v| v as f64)).collect();
    let m = model.means[i].map(|v| v as f64);
    let spatial = if view_from.is_some() {
        model.active.min(model.capacity).spatial
    } else {
        0
    };
    let deg = ColourDegrees {
        spatial: 3,
        temporal: 0,
    };
    let rgb = colour(&ColourInput {
        mean: m,
        coeffs: &flat,
        capacity: deg,
        active: ColourDegrees {
            spatial,
            temporal: 0,
        },
        camera_centre: view_from.unwrap_or([m[0], m[1], m[2] - 1.0]),
        t,
        period: colour_period(model),
    });
    rgb.map(|v| v.clamp(0.0, 1.0))
}

/// The dynamic splats of a 4D model (one per Gaussian; fully transparent ones dropped),
/// with times as fractions of the model's sequence (see the module docs).
pub fn splats_from_model(
    model: &Gaussians<f32>,
    colour_view: Option<[f64; 3]>,
) -> Vec<SplatvSplat> {
    use rayon::prelude::*;
    let duration = colour_period(model);
    (0..model.len())
        .into_par_iter()
        .with_min_len(512)
        .filter_map(|i| {
            let alpha = sigmoid(model.opacity_logits[i] as f64);
            let a8 = (alpha * 255.0).round().clamp(0.0, 255.0) as u8;
            if a8 == 0 {
                return None;
            }
            let (pos, vel, s44, cov) = linear_motion(model, i);
            if !pos.iter().chain(&vel).all(|v| v.is_finite()) {
                return None;
            }
            let (log_scale, q) = super::bake::covariance_to_scale_rotation(cov);
            let t_centre = model.means[i][3] as f64;
            let rgb = baked_rgb(model, i, t_centre, colour_view);
            let c8 = rgb.map(|v| (v * 255.0).round() as u8);
            Some(SplatvSplat {
                position: pos.map(|v| v as f32),
                rotation: q.map(|v| v as f32),
                scale: log_scale.map(|v| v.exp() as f32),
                rgba: [c8[0], c8[1], c8[2], a8],
                velocity: vel.map(|v| (v * duration) as f32),
                t_centre: (t_centre / duration) as f32,
                t_scale: ((2.0 * s44).sqrt() / duration) as f32,
            })
        })
        .collect()
}

pub(super) fn half2(a: f32, b: f32) -> u32 {
    f16::from_f32(a).to_bits() as u32 | ((f16::from_f32(b).to_bits() as u32) << 16)
}

pub(super) fn unhalf2(v: u32) -> (f32, f32) {
    (
        f16::from_bits(v as u16).to_f32(),
        f16::from_bits((v >> 16) as u16).to_f32(),
    )
}

/// Encode splats (and optional cameras) as a `.splatv` file.
pub fn encode(splats: &[SplatvSplat], cameras: &[SplatvCamera]) -> Vec<u8> {
    let rows = splats.len().div_ceil(PER_ROW).max(1);
    let mut tex = vec![0u32; rows * PER_ROW * 16];
    for (i, s) in splats.iter().enumerate() {
        let o = &mut tex[16 * i..16 * i + 16];
        o[0] = s.position[0].to_bits();
        o[1] = s.position[1].to_bits();
        o[2] = s.position[2].to_bits();
        o[3] = half2(s.rotation[0], s.rotation[1]);
        o[4] = half2(s.rotation[2], s.rotation[3]);
        o[5] = half2(s.scale[0], s.scale[1]);
        o[6] = half2(s.scale[2], 0.0);
        o[7] = u32::from_le_bytes(s.rgba);
        o[8] = half2(s.velocity[0], s.velocity[1]);
        o[9] = half2(s.velocity[2], 0.0);
        o[15] = half2(s.t_centre, s.t_scale);
    }
    let json = serde_json::json!([{
        "type": "splat",
        "size": tex.len() * 4,
        "texwidth": PER_ROW * 4,
        "texheight": rows,
        "cameras": cameras,
    }])
    .to_string();
    let mut out = Vec::with_capacity(8 + json.len() + tex.len() * 4);
    out.extend_from_slice(&MAGIC.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(json.as_bytes());
    for v in tex {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Decode a `.splatv` file: `count` splats (the texture may hold padding rows) and the
/// cameras of the header. Padding splats (all zero) after the last real one are dropped.
pub fn decode(bytes: &[u8]) -> Result<(Vec<SplatvSplat>, Vec<SplatvCamera>), String> {
    let u32_at = |o: usize| -> Result<u32, String> {
        bytes
            .get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| "truncated".to_string())
    };
    if u32_at(0)? != MAGIC {
        return Err("bad magic, not a .splatv file".into());
    }
    let jlen = u32_at(4)? as usize;
    let json = bytes.get(8..8 + jlen).ok_or("truncated JSON header")?;
    let chunks: serde_json::Value = serde_json::from_slice(json).map_err(|e| e.to_string())?;
    let chunk = chunks.get(0).ok_or("no chunk in the header")?;
    if chunk["type"] != "splat" {
        return Err("first chunk is not of type splat".into());
    }
    let size = chunk["size"].as_u64().ok_or("chunk without size")? as usize;
    let cameras: Vec<SplatvCamera> = match chunk.get("cameras") {
        Some(c) => serde_json::from_value(c.clone()).map_err(|e| e.to_string())?,
        None => Vec::new(),
    };
    let body = bytes
        .get(8 + jlen..8 + jlen + size)
        .ok_or("truncated texture")?;
    let mut splats: Vec<SplatvSplat> = body
        .chunks_exact(64)
        .map(|c| {
            let w: Vec<u32> = c
                .chunks_exact(4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            let (qw, qx) = unhalf2(w[3]);
            let (qy, qz) = unhalf2(w[4]);
            let (sx, sy) = unhalf2(w[5]);
            let (sz, _) = unhalf2(w[6]);
            let (vx, vy) = unhalf2(w[8]);
            let (vz, _) = unhalf2(w[9]);
            let (tc, ts) = unhalf2(w[15]);
            SplatvSplat {
                position: [w[0], w[1], w[2]].map(f32::from_bits),
                rotation: [qw, qx, qy, qz],
                scale: [sx, sy, sz],
                rgba: w[7].to_le_bytes(),
                velocity: [vx, vy, vz],
                t_centre: tc,
                t_scale: ts,
            }
        })
        .collect();
    while splats
        .last()
        .is_some_and(|s| s.t_scale == 0.0 && s.rgba == [0; 4])
    {
        splats.pop();
    }
    Ok((splats, cameras))
}

/// Write a model as `.splatv`, atomically.
pub fn write_splatv(
    model: &Gaussians<f32>,
    cameras: &[SplatvCamera],
    colour_view: Option<[f64; 3]>,
    path: &Path,
) -> Result<usize, ExportError> {
    let splats = splats_from_model(model, colour_view);
    write_atomic(path, &encode(&splats, cameras))?;
    Ok(splats.len())
}
