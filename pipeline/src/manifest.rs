//! `work/<stage>/stage.json`: what a finished stage ran with and what it wrote, and
//! `work/.status/<stage>.json`: a stage that is running or failed.
//!
//! A stage is up to date when its parameters and the hashes of its inputs equal those in
//! its manifest and its outputs are still there.

use std::collections::BTreeMap;
use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use shared_types::atomic::write_json;

/// Manifest format version.
pub const MANIFEST_VERSION: u32 = 1;
/// Name of the manifest file in a stage's output folder.
pub const MANIFEST_FILE: &str = "stage.json";

/// Content hash of a file or of a stage's outputs (BLAKE3, hex).
pub type Hash = String;

/// One input of a stage as seen when it ran.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputRecord {
    pub hash: Hash,
    /// Size and modification time (ns since the epoch) of a file input: when both are
    /// unchanged the file is not hashed again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modified_ns: Option<u128>,
}

/// One output file of a stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OutputRecord {
    pub size: u64,
    pub hash: Hash,
}

/// Contents of `work/<stage>/stage.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub version: u32,
    pub stage: String,
    /// The stage's settings (its `capture.toml` section with defaults filled in).
    pub parameters: serde_json::Value,
    /// Inputs by name: capture-relative file paths, or `stage:<name>` for an upstream
    /// stage's outputs (hash = that stage's `outputs_digest`).
    pub inputs: BTreeMap<String, InputRecord>,
    /// Output files, relative to `work/<stage>/` (the manifest itself excluded).
    pub outputs: BTreeMap<String, OutputRecord>,
    /// Hash over all outputs: what downstream stages record as their input.
    pub outputs_digest: Hash,
    pub started: DateTime<Utc>,
    pub duration_s: f64,
    /// Versions of the programs and libraries that produced the outputs.
    pub tool_versions: BTreeMap<String, String>,
}

impl Manifest {
    pub fn path(stage_dir: &Path) -> PathBuf {
        stage_dir.join(MANIFEST_FILE)
    }

    /// Read a stage's manifest; `None` when absent or unreadable (then the stage is
    /// treated as never run).
    pub fn read(stage_dir: &Path) -> Option<Self> {
        let text = fs::read_to_string(Self::path(stage_dir)).ok()?;
        let m: Self = serde_json::from_str(&text).ok()?;
        (m.version == MANIFEST_VERSION).then_some(m)
    }

    pub fn write(&self, stage_dir: &Path) -> std::io::Result<()> {
        write_json(&Self::path(stage_dir), self)
    }
}

/// State of a stage that did not finish (`work/.status/<stage>.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub state: RunState,
    pub pid: u32,
    pub started: DateTime<Utc>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunState {
    Running,
    Failed,
}

impl RunRecord {
    pub fn path(work_dir: &Path, stage: &str) -> PathBuf {
        work_dir.join(".status").join(format!("{stage}.json"))
    }

    pub fn read(work_dir: &Path, stage: &str) -> Option<Self> {
        serde_json::from_str(&fs::read_to_string(Self::path(work_dir, stage)).ok()?).ok()
    }

    pub fn write(&self, work_dir: &Path, stage: &str) -> std::io::Result<()> {
        let path = Self::path(work_dir, stage);
        write_json(&path, self)
    }

    pub fn clear(work_dir: &Path, stage: &str) {
        let _ = fs::remove_file(Self::path(work_dir, stage));
    }
}

/// BLAKE3 of a file's contents.
pub fn hash_file(path: &Path) -> std::io::Result<Hash> {
    let mut hasher = blake3::Hasher::new();
    let mut file = fs::File::open(path)?;
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher.finalize().to_hex().to_string())
}

/// BLAKE3 of some bytes.
pub fn hash_bytes(bytes: &[u8]) -> Hash {
    blake3::hash(bytes).to_hex().to_string()
}

/// Size and modification time (ns) of a file.
pub fn file_stamp(path: &Path) -> std::io::Result<(u64, u128)> {
    let meta = fs::metadata(path)?;
    let modified = meta
        .modified()?
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    Ok((meta.len(), modified))
}

/// Hash a file input, reusing `previous` when its size and modification time match.
pub fn record_input(path: &Path, previous: Option<&InputRecord>) -> std::io::Result<InputRecord> {
    let (size, modified) = file_stamp(path)?;
    if let Some(p) = previous
        && p.size == Some(size)
        && p.modified_ns == Some(modified)
    {
        return Ok(p.clone());
    }
    Ok(InputRecord {
        hash: hash_file(path)?,
        size: Some(size),
        modified_ns: Some(modified),
    })
}

/// All files under `dir`, relative, sorted (the manifest itself excluded).
pub fn list_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
        for entry in fs::read_dir(dir)? {
            let path = entry?.path();
            if path.is_dir() {
                walk(root, &path, out)?;
            } else if let Ok(rel) = path.strip_prefix(root) {
                out.push(rel.to_path_buf());
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out)?;
    out.retain(|p| p != Path::new(MANIFEST_FILE));
    out.sort();
    Ok(out)
}

/// Hash every output file of a finished stage folder; returns the records and their digest.
pub fn record_outputs(dir: &Path) -> std::io::Result<(BTreeMap<String, OutputRecord>, Hash)> {
    let files = list_files(dir)?;
    let records: Vec<(String, OutputRecord)> = {
        use rayon::prelude::*;
        files
            .par_iter()
            .map(|rel| {
                let path = dir.join(rel);
                let size = fs::metadata(&path)?.len();
                Ok((
                    rel.to_string_lossy().replace('\\', "/"),
                    OutputRecord {
                        size,
                        hash: hash_file(&path)?,
                    },
                ))
            })
            .collect::<std::io::Result<_>>()?
    };
    let mut digest = blake3::Hasher::new();
    for (name, rec) in &records {
        digest.update(name.as_bytes());
        digest.update(&[0]);
        digest.update(rec.hash.as_bytes());
        digest.update(&[0]);
    }
    Ok((
        records.into_iter().collect(),
        digest.finalize().to_hex().to_string(),
    ))
}
