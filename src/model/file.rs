//! The versioned binary model file (`.s4d`): a fixed little-endian header (magic, version,
//! count, colour degrees, time mapping) followed by the structure-of-arrays payload in
//! `f32`. Reading never panics: a truncated, oversized or foreign file is a typed error.
//! Writing goes to a temporary sibling and is renamed into place when complete.

use crate::model::{ColourDegrees, Gaussians, TimeMapping};
use std::path::{Path, PathBuf};

/// First 8 bytes of every model file.
pub const MAGIC: [u8; 8] = *b"S4DMODEL";
/// Current format version.
pub const VERSION: u32 = 1;
/// Size of the header in bytes.
pub const HEADER_LEN: usize = 56;

/// Why a model file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum ModelFileError {
    #[error("cannot access model file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not a splat4d model file (bad magic); pass a file written by `save_model`")]
    NotAModel { path: PathBuf },
    #[error(
        "{path} has model format version {version}, this build reads version {VERSION}; re-export it with a matching build"
    )]
    UnsupportedVersion { path: PathBuf, version: u32 },
    #[error(
        "{path} is truncated or corrupt: expected {expected} bytes, found {found}; re-save or re-copy the model"
    )]
    SizeMismatch {
        path: PathBuf,
        expected: u64,
        found: u64,
    },
    #[error("{path} has an invalid header: {reason}")]
    BadHeader { path: PathBuf, reason: String },
    #[error("cannot save an inconsistent model to {path}: {reason}")]
    Inconsistent { path: PathBuf, reason: String },
}

fn payload_floats(n: u64, capacity: ColourDegrees) -> Option<u64> {
    let per = 17u64.checked_add(3 * capacity.coeff_count() as u64)?;
    n.checked_mul(per)
}

/// Write `model` to `path` (atomically, through a temporary file).
pub fn save_model(model: &Gaussians<f32>, path: &Path) -> Result<(), ModelFileError> {
    let buf = encode_model(model, path)?;
    crate::atomic::write_atomic(path, &buf).map_err(|source| ModelFileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The bytes [`save_model`] writes; `path` is only used in error messages.
pub fn encode_model(model: &Gaussians<f32>, path: &Path) -> Result<Vec<u8>, ModelFileError> {
    model
        .check_consistent()
        .map_err(|reason| ModelFileError::Inconsistent {
            path: path.to_path_buf(),
            reason,
        })?;
    let n = model.len() as u64;
    let floats = payload_floats(n, model.capacity).unwrap_or(u64::MAX) as usize;
    let mut buf = Vec::with_capacity(HEADER_LEN + 4 * floats);
    buf.extend_from_slice(&MAGIC);
    buf.extend_from_slice(&VERSION.to_le_bytes());
    buf.extend_from_slice(&(HEADER_LEN as u32).to_le_bytes());
    buf.extend_from_slice(&n.to_le_bytes());
    let (c, a) = (model.capacity, model.active);
    buf.extend_from_slice(&[
        c.spatial as u8,
        c.temporal as u8,
        a.spatial as u8,
        a.temporal as u8,
    ]);
    buf.extend_from_slice(&0u32.to_le_bytes());
    for v in [
        model.time.start_seconds,
        model.time.units_per_second,
        model.time.duration,
    ] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    debug_assert_eq!(buf.len(), HEADER_LEN);
    let mut put = |v: f32| buf.extend_from_slice(&v.to_le_bytes());
    for arr in [
        &model.means,
        &model.log_scales,
        &model.rot_left,
        &model.rot_right,
    ] {
        arr.iter().flatten().for_each(|&v| put(v));
    }
    model.opacity_logits.iter().for_each(|&v| put(v));
    model.colours.iter().for_each(|&v| put(v));
    Ok(buf)
}

/// Read a model written by [`save_model`].
pub fn load_model(path: &Path) -> Result<Gaussians<f32>, ModelFileError> {
    let bytes = std::fs::read(path).map_err(|source| ModelFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_model(&bytes, path)
}

/// Parse model file bytes; `path` is only used in error messages.
pub fn parse_model(bytes: &[u8], path: &Path) -> Result<Gaussians<f32>, ModelFileError> {
    let p = || path.to_path_buf();
    if bytes.len() < 12 || bytes[..8] != MAGIC {
        if bytes.len() < 8 && MAGIC.starts_with(bytes) {
            return Err(ModelFileError::SizeMismatch {
                path: p(),
                expected: HEADER_LEN as u64,
                found: bytes.len() as u64,
            });
        }
        if bytes.len() >= 8 && bytes[..8] == MAGIC {
            return Err(ModelFileError::SizeMismatch {
                path: p(),
                expected: HEADER_LEN as u64,
                found: bytes.len() as u64,
            });
        }
        return Err(ModelFileError::NotAModel { path: p() });
    }
    let u32_at =
        |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let version = u32_at(8);
    if version != VERSION {
        return Err(ModelFileError::UnsupportedVersion { path: p(), version });
    }
    if bytes.len() < HEADER_LEN {
        return Err(ModelFileError::SizeMismatch {
            path: p(),
            expected: HEADER_LEN as u64,
            found: bytes.len() as u64,
        });
    }
    let header_len = u32_at(12) as usize;
    if header_len != HEADER_LEN {
        return Err(ModelFileError::BadHeader {
            path: p(),
            reason: format!("header length {header_len}, expected {HEADER_LEN}"),
        });
    }
    let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().unwrap_or([0; 8]));
    let n = u64::from_le_bytes(bytes[16..24].try_into().unwrap_or([0; 8]));
    let capacity = ColourDegrees {
        spatial: bytes[24] as u32,
        temporal: bytes[25] as u32,
    };
    let active = ColourDegrees {
        spatial: bytes[26] as u32,
        temporal: bytes[27] as u32,
    };
    if !capacity.is_valid() || !active.is_valid() {
        return Err(ModelFileError::BadHeader {
            path: p(),
            reason: format!("colour degrees {capacity:?} / {active:?} out of range"),
        });
    }
    let time = TimeMapping {
        start_seconds: f64_at(32),
        units_per_second: f64_at(40),
        duration: f64_at(48),
    };
    if !(time.start_seconds.is_finite()
        && time.units_per_second.is_finite()
        && time.units_per_second > 0.0
        && time.duration.is_finite())
    {
        return Err(ModelFileError::BadHeader {
            path: p(),
            reason: format!("invalid time mapping {time:?}"),
        });
    }
    let expected = payload_floats(n, capacity)
        .and_then(|f| f.checked_mul(4))
        .and_then(|b| b.checked_add(HEADER_LEN as u64))
        .unwrap_or(u64::MAX);
    if expected != bytes.len() as u64 {
        return Err(ModelFileError::SizeMismatch {
            path: p(),
            expected,
            found: bytes.len() as u64,
        });
    }
    let n = n as usize;
    let mut at = HEADER_LEN;
    let mut take = |count: usize| -> Vec<f32> {
        let v = bytes[at..at + 4 * count]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        at += 4 * count;
        v
    };
    let quad = |v: Vec<f32>| -> Vec<[f32; 4]> {
        v.chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect()
    };
    let means = quad(take(4 * n));
    let log_scales = quad(take(4 * n));
    let rot_left = quad(take(4 * n));
    let rot_right = quad(take(4 * n));
    let opacity_logits = take(n);
    let colours = take(n * 3 * capacity.coeff_count());
    Ok(Gaussians {
        means,
        log_scales,
        rot_left,
        rot_right,
        opacity_logits,
        colours,
        capacity,
        active,
        time,
    })
}
