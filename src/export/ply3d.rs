//! Per-timestep 3DGS PLY: the property layout of the original 3DGS code,
//! `x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3`, binary
//! little-endian float32, which SuperSplat, Brush and most 3DGS viewers open. `f_rest` is
//! channel-major (all 15 higher-order coefficients of red, then green, then blue);
//! opacity is a logit, scales are logs, the quaternion is `w, x, y, z`.

use super::bake::{Frame3d, SH_COEFFS, Splat3d};
use super::{ExportError, write_atomic};
use shared_types::ply::PlyTable;
use std::path::Path;

const REST: usize = SH_COEFFS - 1;

/// Property names of a 3DGS PLY row, in file order.
pub fn property_names() -> Vec<String> {
    let mut n: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"].map(String::from).to_vec();
    n.extend((0..3).map(|c| format!("f_dc_{c}")));
    n.extend((0..3 * REST).map(|k| format!("f_rest_{k}")));
    n.push("opacity".into());
    n.extend((0..3).map(|k| format!("scale_{k}")));
    n.extend((0..4).map(|k| format!("rot_{k}")));
    n
}

/// The PLY table of a baked frame.
pub fn frame_table(frame: &Frame3d) -> PlyTable {
    let names = property_names();
    let mut data = Vec::with_capacity(frame.splats.len() * names.len());
    for s in &frame.splats {
        data.extend_from_slice(&s.position);
        data.extend_from_slice(&[0.0; 3]);
        data.extend_from_slice(&s.sh[0]);
        for c in 0..3 {
            data.extend((1..SH_COEFFS).map(|k| s.sh[k][c]));
        }
        data.push(s.opacity_logit);
        data.extend_from_slice(&s.log_scale);
        data.extend_from_slice(&s.rotation);
    }
    PlyTable::floats(
        vec![
            "splat4d 3dgs frame".into(),
            format!("model_time {}", frame.t),
            format!("sh_degree {}", frame.sh_degree),
        ],
        names,
        data,
    )
}

/// Write a baked frame as a 3DGS PLY, atomically.
pub fn write_frame_ply(frame: &Frame3d, path: &Path) -> Result<(), ExportError> {
    write_atomic(path, &frame_table(frame).encode())
}

/// Read a 3DGS PLY with the standard layout back into splats (for checks and tools).
/// Files with fewer `f_rest` properties (lower SH degree) are accepted.
pub fn read_frame_ply(path: &Path) -> Result<Vec<Splat3d>, ExportError> {
    let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
        path: path.into(),
        source,
    })?;
    let bad = |reason: String| ExportError::Format {
        path: path.into(),
        reason,
    };
    let table = PlyTable::decode(&bytes).map_err(|e| bad(e.to_string()))?;
    let col = |name: &str| {
        table
            .column(name)
            .ok_or_else(|| bad(format!("no `{name}` property")))
    };
    let pos = [col("x")?, col("y")?, col("z")?];
    let dc = [col("f_dc_0")?, col("f_dc_1")?, col("f_dc_2")?];
    let opacity = col("opacity")?;
    let scale = [col("scale_0")?, col("scale_1")?, col("scale_2")?];
    let rot = [col("rot_0")?, col("rot_1")?, col("rot_2")?, col("rot_3")?];
    let rest: Vec<usize> = (0..)
        .map_while(|k| table.column(&format!("f_rest_{k}")))
        .collect();
    let per = rest.len() / 3;
    if per > REST || !rest.len().is_multiple_of(3) {
        return Err(bad(format!("{} f_rest properties", rest.len())));
    }
    let w = table.names.len();
    Ok(table
        .data
        .chunks_exact(w)
        .map(|row| {
            let mut sh = [[0f32; 3]; SH_COEFFS];
            sh[0] = dc.map(|i| row[i]);
            for c in 0..3 {
                for k in 0..per {
                    sh[k + 1][c] = row[rest[c * per + k]];
                }
            }
            Splat3d {
                position: pos.map(|i| row[i]),
                sh,
                opacity_logit: row[opacity],
                log_scale: scale.map(|i| row[i]),
                rotation: rot.map(|i| row[i]),
            }
        })
        .collect())
}
