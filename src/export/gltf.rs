//! One time step as binary glTF with the Khronos `KHR_gaussian_splatting` extension
//! (three.js, Babylon.js, PlayCanvas, CesiumJS): a `POINTS` primitive whose attributes are
//! the splats' position, rotation (xyzw), linear scale, opacity after the sigmoid, the
//! spherical-harmonic coefficients degree by degree (`SH_DEGREE_ℓ_COEF_n`, RGB, the 3DGS
//! basis and its `+0.5` bias) and a `COLOR_0` fallback for viewers without splats.
//!
//! glTF is y-up; the capture's frame has OpenCV's cameras (y down, z forward). The file
//! holds the scene turned 180° about x, which sets a scene filmed by level cameras
//! upright: positions `(x, −y, −z)`, each rotation composed with that turn, and every
//! spherical-harmonic coefficient whose basis function is odd in `y` and `z` negated.
//! [`read_glb`] undoes it, so a file reads back as the splats it was written from.

use super::bake::{Frame3d, SH_COEFFS, Splat3d};
use super::{ExportError, write_atomic};
use crate::math::numerics::{logit, sigmoid};
use crate::math::sh::SH_C0;
use serde_json::{Value, json};
use std::path::Path;

/// The extension's name, also the prefix of its attribute names.
pub const EXTENSION: &str = "KHR_gaussian_splatting";

/// Sign of each 3DGS SH basis function under `(x, y, z) → (x, −y, −z)`.
const SH_SIGNS: [f32; SH_COEFFS] = [
    1.0, -1.0, -1.0, 1.0, -1.0, 1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, -1.0, 1.0, -1.0, 1.0,
];

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
const FLOAT: u32 = 5126;
const ARRAY_BUFFER: u32 = 34962;

/// The turn about x applied to a position.
fn turn(p: [f32; 3]) -> [f32; 3] {
    [p[0], -p[1], -p[2]]
}

/// `(w, x, y, z)` composed with the turn about x, as glTF's `(x, y, z, w)`.
fn turn_rotation([w, x, y, z]: [f32; 4]) -> [f32; 4] {
    // (0, 1, 0, 0) ⊗ (w, x, y, z) = (−x, w, −z, y).
    [w, -z, y, -x]
}

/// glTF's `(x, y, z, w)` turned back, as `(w, x, y, z)` with `w ≥ 0`.
fn unturn_rotation([a, b, c, d]: [f32; 4]) -> [f32; 4] {
    // Inverse of `turn_rotation`: a = w, b = −z, c = y, d = −x.
    let q = [a, -d, c, -b];
    if q[0] < 0.0 { q.map(|v| -v) } else { q }
}

/// Attribute name of SH coefficient `n` of degree `l`.
fn sh_attribute(l: usize, n: usize) -> String {
    format!("{EXTENSION}:SH_DEGREE_{l}_COEF_{n}")
}

/// The GLB bytes of one baked time step (at the frame's SH degree).
pub fn encode_glb(frame: &Frame3d) -> Vec<u8> {
    let count = frame.splats.len();
    let degree = frame.sh_degree.min(3) as usize;
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut attributes = serde_json::Map::new();
    // One tightly packed float buffer view and accessor per attribute.
    let mut add = |name: String, kind: &str, values: Vec<f32>, bounds: bool| {
        let offset = bin.len();
        for v in &values {
            bin.extend_from_slice(&v.to_le_bytes());
        }
        views.push(json!({
            "buffer": 0, "byteOffset": offset, "byteLength": values.len() * 4,
            "target": ARRAY_BUFFER,
        }));
        let mut accessor = json!({
            "bufferView": views.len() - 1, "componentType": FLOAT, "count": count, "type": kind,
        });
        if bounds {
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for p in values.chunks_exact(3) {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
            if count > 0 {
                accessor["min"] = json!(lo);
                accessor["max"] = json!(hi);
            }
        }
        accessors.push(accessor);
        attributes.insert(name, json!(accessors.len() - 1));
    };
    let splats = &frame.splats;
    let flat = |f: &dyn Fn(&Splat3d) -> Vec<f32>| splats.iter().flat_map(f).collect::<Vec<f32>>();
    add(
        "POSITION".into(),
        "VEC3",
        flat(&|s| turn(s.position).to_vec()),
        true,
    );
    add(
        format!("{EXTENSION}:ROTATION"),
        "VEC4",
        flat(&|s| turn_rotation(s.rotation).to_vec()),
        false,
    );
    add(
        format!("{EXTENSION}:SCALE"),
        "VEC3",
        flat(&|s| s.log_scale.map(f32::exp).to_vec()),
        false,
    );
    add(
        format!("{EXTENSION}:OPACITY"),
        "SCALAR",
        flat(&|s| vec![sigmoid(s.opacity_logit)]),
        false,
    );
    for l in 0..=degree {
        for n in 0..=2 * l {
            let k = l * l + n;
            add(
                sh_attribute(l, n),
                "VEC3",
                flat(&|s| s.sh[k].map(|c| c * SH_SIGNS[k]).to_vec()),
                false,
            );
        }
    }
    add(
        "COLOR_0".into(),
        "VEC4",
        flat(&|s| {
            let rgb = s.sh[0].map(|c| (0.5 + SH_C0 as f32 * c).clamp(0.0, 1.0));
            vec![rgb[0], rgb[1], rgb[2], sigmoid(s.opacity_logit)]
        }),
        false,
    );
    let document = json!({
        "asset": {"version": "2.0", "generator": "4C4D pipeline (splat4d::export::gltf)"},
        "extensionsUsed": [EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": format!("t = {:.6}", frame.t)}],
        "meshes": [{"primitives": [{
            "attributes": attributes,
            "mode": 0,
            "extensions": {EXTENSION: {
                "kernel": "ellipse",
                "colorSpace": "srgb_rec709_display",
                "projection": "perspective",
                "sortingMethod": "cameraDistance",
            }},
        }]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
    });
    let mut text = serde_json::to_vec(&document).expect("a JSON value serialises");
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(GLB_MAGIC);
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    for (kind, chunk) in [(CHUNK_JSON, &text), (CHUNK_BIN, &bin)] {
        out.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(chunk);
    }
    out
}

/// Write one baked time step as a `.glb`, atomically.
pub fn write_glb(frame: &Frame3d, path: &Path) -> Result<(), ExportError> {
    write_atomic(path, &encode_glb(frame))
}

/// Read a `.glb` this module wrote (float attributes of a `KHR_gaussian_splatting`
/// primitive) back into splats in the capture's frame; for checks and tools.
pub fn read_glb(bytes: &[u8], path: &Path) -> Result<Vec<Splat3d>, ExportError> {
    let bad = |reason: String| ExportError::Format {
        path: path.into(),
        reason,
    };
    let u32_at = |at: usize| -> Result<u32, ExportError> {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| bad(format!("cut short at byte {at}")))
    };
    if bytes.get(..4) != Some(GLB_MAGIC.as_slice()) || u32_at(4)? != 2 {
        return Err(bad("not a version-2 binary glTF (.glb)".into()));
    }
    let mut chunks = Vec::new();
    let mut at = 12;
    while at + 8 <= bytes.len() {
        let (len, kind) = (u32_at(at)? as usize, u32_at(at + 4)?);
        let body = bytes
            .get(at + 8..at + 8 + len)
            .ok_or_else(|| bad(format!("chunk at byte {at} runs past the end")))?;
        chunks.push((kind, body));
        at += 8 + len;
    }
    let chunk = |kind: u32, what: &str| {
        chunks
            .iter()
            .find(|c| c.0 == kind)
            .map(|c| c.1)
            .ok_or_else(|| bad(format!("no {what} chunk")))
    };
    let doc: Value =
        serde_json::from_slice(chunk(CHUNK_JSON, "JSON")?).map_err(|e| bad(e.to_string()))?;
    let bin = chunk(CHUNK_BIN, "binary")?;
    let primitive = &doc["meshes"][0]["primitives"][0];
    if primitive["extensions"][EXTENSION].is_null() {
        return Err(bad(format!("the first primitive is not {EXTENSION}")));
    }
    let count = primitive["attributes"]["POSITION"]
        .as_u64()
        .and_then(|a| doc["accessors"][a as usize]["count"].as_u64())
        .ok_or_else(|| bad("no POSITION accessor".into()))? as usize;
    let attribute = |name: &str, width: usize| -> Result<Option<Vec<f32>>, ExportError> {
        let Some(index) = primitive["attributes"][name].as_u64() else {
            return Ok(None);
        };
        let accessor = &doc["accessors"][index as usize];
        let view =
            &doc["bufferViews"][accessor["bufferView"].as_u64().unwrap_or(u64::MAX) as usize];
        let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize
            + accessor["byteOffset"].as_u64().unwrap_or(0) as usize;
        if accessor["componentType"].as_u64() != Some(u64::from(FLOAT))
            || accessor["count"].as_u64() != Some(count as u64)
        {
            return Err(bad(format!("{name} is not {count} floats")));
        }
        let len = count
            .checked_mul(width * 4)
            .ok_or_else(|| bad(format!("{name} is too long")))?;
        let data = offset
            .checked_add(len)
            .and_then(|end| bin.get(offset..end))
            .ok_or_else(|| bad(format!("{name} runs past the binary chunk")))?;
        Ok(Some(
            data.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
        ))
    };
    let need = |name: String, width: usize| {
        attribute(&name, width)?.ok_or_else(|| bad(format!("no {name} attribute")))
    };
    let position = need("POSITION".into(), 3)?;
    let rotation = need(format!("{EXTENSION}:ROTATION"), 4)?;
    let scale = need(format!("{EXTENSION}:SCALE"), 3)?;
    let opacity = need(format!("{EXTENSION}:OPACITY"), 1)?;
    let mut sh = Vec::new();
    for l in 0..=3 {
        let coefficients: Option<Vec<Vec<f32>>> = (0..=2 * l)
            .map(|n| attribute(&sh_attribute(l, n), 3))
            .collect::<Result<_, _>>()?;
        match coefficients {
            Some(c) => sh.extend(c),
            None if l == 0 => return Err(bad("no SH_DEGREE_0_COEF_0 attribute".into())),
            None => break,
        }
    }
    Ok((0..count)
        .map(|i| {
            let v3 = |a: &[f32]| [a[3 * i], a[3 * i + 1], a[3 * i + 2]];
            let mut coefficients = [[0.0f32; 3]; SH_COEFFS];
            for (k, c) in sh.iter().enumerate() {
                coefficients[k] = v3(c).map(|v| v * SH_SIGNS[k]);
            }
            let r = &rotation[4 * i..4 * i + 4];
            Splat3d {
                position: turn(v3(&position)),
                sh: coefficients,
                opacity_logit: logit(f64::from(opacity[i])) as f32,
                log_scale: v3(&scale).map(f32::ln),
                rotation: unturn_rotation([r[0], r[1], r[2], r[3]]),
            }
        })
        .collect())
}
