//! The native 4D model as PLY: every parameter of [`Gaussians`] in float32, so a re-import
//! is bit-exact. Layout (binary little-endian, one `vertex` element):
//!
//! `x y z t nx ny nz f_dc_0..2 f_rest_0..(3K−4) opacity scale_0 scale_1 scale_2 scale_t
//! rot_0..3 rot_r_0..3`
//!
//! - `t` is the temporal mean, `scale_t` the log temporal scale;
//! - `rot_0..3` is the left quaternion `(a, b, c, d)` of the 4D rotation, `rot_r_0..3` the
//!   right one `(p, q, r, s)`, not normalised;
//! - colour: `K = (spatial+1)²·(temporal+1)` coefficients per channel at the storage
//!   capacity, coefficient `k = j·(spatial+1)² + s` for temporal basis `j` and spatial SH
//!   basis `s`; `f_dc_c` is `k = 0`, `f_rest` is channel-major over `k = 1..K−1`
//!   (`f_rest_{c·(K−1) + k−1}`), as in 3DGS;
//! - header comments `colour_capacity S T`, `colour_active S T` and
//!   `time_mapping START_SECONDS UNITS_PER_SECOND DURATION` carry the rest.

use super::{ExportError, write_atomic};
use crate::model::{ColourDegrees, Gaussians, TimeMapping};
use shared_types::ply::PlyTable;
use std::path::Path;

/// Property names for a model whose colour has `k` coefficients per channel.
pub fn property_names(k: usize) -> Vec<String> {
    let mut n: Vec<String> = ["x", "y", "z", "t", "nx", "ny", "nz"]
        .map(String::from)
        .to_vec();
    n.extend((0..3).map(|c| format!("f_dc_{c}")));
    n.extend((0..3 * (k - 1)).map(|i| format!("f_rest_{i}")));
    n.push("opacity".into());
    n.extend(["scale_0", "scale_1", "scale_2", "scale_t"].map(String::from));
    n.extend((0..4).map(|i| format!("rot_{i}")));
    n.extend((0..4).map(|i| format!("rot_r_{i}")));
    n
}

/// The PLY table of a 4D model.
pub fn model_table(model: &Gaussians<f32>) -> PlyTable {
    let k = model.coeffs_per_channel();
    let names = property_names(k);
    let mut data = Vec::with_capacity(model.len() * names.len());
    for i in 0..model.len() {
        let m = model.means[i];
        data.extend_from_slice(&m);
        data.extend_from_slice(&[0.0; 3]);
        let col = model.colour_of(i);
        data.extend((0..3).map(|c| col[c]));
        for c in 0..3 {
            data.extend((1..k).map(|j| col[j * 3 + c]));
        }
        data.push(model.opacity_logits[i]);
        data.extend_from_slice(&model.log_scales[i]);
        data.extend_from_slice(&model.rot_left[i]);
        data.extend_from_slice(&model.rot_right[i]);
    }
    let (cap, act, tm) = (model.capacity, model.active, model.time);
    PlyTable::floats(
        vec![
            "splat4d model4d 1".into(),
            format!("colour_capacity {} {}", cap.spatial, cap.temporal),
            format!("colour_active {} {}", act.spatial, act.temporal),
            format!(
                "time_mapping {} {} {}",
                tm.start_seconds, tm.units_per_second, tm.duration
            ),
        ],
        names,
        data,
    )
}

/// Write the 4D model as PLY, atomically.
pub fn write_model_ply(model: &Gaussians<f32>, path: &Path) -> Result<(), ExportError> {
    write_atomic(path, &model_table(model).encode())
}

/// Read a 4D model PLY written by [`write_model_ply`]; the result is bit-identical.
pub fn read_model_ply(path: &Path) -> Result<Gaussians<f32>, ExportError> {
    let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
        path: path.into(),
        source,
    })?;
    let bad = |reason: String| ExportError::Format {
        path: path.into(),
        reason,
    };
    let table = PlyTable::decode(&bytes).map_err(|e| bad(e.to_string()))?;
    let degrees = |key: &str| -> Result<ColourDegrees, ExportError> {
        let v = table
            .comment_value(key)
            .ok_or_else(|| bad(format!("no `comment {key}` line")))?;
        let n: Vec<u32> = v
            .split_whitespace()
            .filter_map(|x| x.parse().ok())
            .collect();
        match n.as_slice() {
            [s, t] => Ok(ColourDegrees {
                spatial: *s,
                temporal: *t,
            }),
            _ => Err(bad(format!("bad `{key}` comment `{v}`"))),
        }
    };
    let capacity = degrees("colour_capacity")?;
    let active = degrees("colour_active")?;
    if !capacity.is_valid() || !active.is_valid() {
        return Err(bad(format!(
            "colour degrees out of range: {capacity:?} / {active:?}"
        )));
    }
    let tm = table
        .comment_value("time_mapping")
        .ok_or_else(|| bad("no `comment time_mapping` line".into()))?;
    let tv: Vec<f64> = tm
        .split_whitespace()
        .filter_map(|x| x.parse().ok())
        .collect();
    let [start_seconds, units_per_second, duration] = tv[..] else {
        return Err(bad(format!("bad `time_mapping` comment `{tm}`")));
    };
    let k = capacity.coeff_count();
    if table.names != property_names(k) {
        return Err(bad(format!(
            "properties do not match the splat4d 4D layout for {k} colour coefficients"
        )));
    }
    let mut model = Gaussians::new(
        capacity,
        TimeMapping {
            start_seconds,
            units_per_second,
            duration,
        },
    );
    model.active = active;
    let w = table.names.len();
    let rest = 10;
    let after = rest + 3 * (k - 1);
    for row in table.data.chunks_exact(w) {
        model.means.push([row[0], row[1], row[2], row[3]]);
        let start = model.colours.len();
        model.colours.resize(start + 3 * k, 0.0);
        let dst = &mut model.colours[start..];
        for c in 0..3 {
            dst[c] = row[7 + c];
            for j in 1..k {
                dst[j * 3 + c] = row[rest + c * (k - 1) + (j - 1)];
            }
        }
        model.opacity_logits.push(row[after]);
        let v4 = |o: usize| [row[o], row[o + 1], row[o + 2], row[o + 3]];
        model.log_scales.push(v4(after + 1));
        model.rot_left.push(v4(after + 5));
        model.rot_right.push(v4(after + 9));
    }
    Ok(model)
}
