//! Checkpoints: `ckpt/NNNNNN.bin` (the model file) beside `ckpt/NNNNNN.state` (iteration,
//! Adam moments, densification statistics, hook state). Together with the per-iteration
//! RNG streams (seeded from `(seed, iteration)`) they make a resumed run bit-identical
//! (a learned backdrop is fitted after the last step, from the model alone).
//!
//! The state file carries a CRC of itself and of its model file, and a fingerprint of the
//! run's views, so a truncated, zeroed or bit-flipped pair, a pair of another format
//! version, or one copied from another capture is recognised; [`latest_good`] sets such a
//! pair aside (`*.damaged`) and falls back to the one before.

use crate::model::Gaussians;
use crate::model::file::{ModelFileError, encode_model, parse_model};
use crate::train::Dataset;
use crate::train::densify::DensifyStats;
use crate::train::optim::{Adam, ParamBuffers};

use std::path::{Path, PathBuf};

const MAGIC: [u8; 8] = *b"S4DTRAIN";
const VERSION: u32 = 2;
/// Magic, version and eight `u64` words.
const HEADER_LEN: usize = 12 + 8 * 8;

/// Why a checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("cannot access checkpoint {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Model(#[from] ModelFileError),
    #[error("{path} is not a usable training state: {reason}")]
    Corrupt { path: PathBuf, reason: String },
}

/// A checkpoint [`latest_good`] passed over: which file, why, and where it now lies.
#[derive(Clone, Debug, PartialEq)]
pub struct Skipped {
    pub path: PathBuf,
    pub reason: String,
    pub set_aside: Vec<PathBuf>,
}

impl std::fmt::Display for Skipped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "checkpoint {} skipped: {}",
            self.path.display(),
            self.reason
        )?;
        if let Some(first) = self.set_aside.first() {
            write!(f, " (kept as {}", first.display())?;
            for p in &self.set_aside[1..] {
                write!(f, ", {}", p.display())?;
            }
            write!(f, ")")?;
        }
        Ok(())
    }
}

/// Everything a resumed run needs.
pub struct Checkpoint {
    pub iteration: u64,
    pub seed: u64,
    pub model: Gaussians<f32>,
    pub adam: Adam,
    pub stats: DensifyStats,
    pub hook_state: Vec<u8>,
}

/// Paths of the checkpoint after `iteration` iterations.
pub fn paths(dir: &Path, iteration: u64) -> (PathBuf, PathBuf) {
    (
        dir.join(format!("{iteration:06}.bin")),
        dir.join(format!("{iteration:06}.state")),
    )
}

/// A fingerprint of the views a run trains on (cameras, times, image sizes): a checkpoint
/// of another capture, or of other cameras, does not carry it.
pub fn fingerprint(dataset: &Dataset) -> u64 {
    let mut h = crc32fast::Hasher::new();
    h.update(format!("{:?}", dataset.time_mapping).as_bytes());
    for v in &dataset.views {
        h.update(
            format!(
                "{:?} {} {}x{}",
                v.camera, v.time, v.image.width, v.image.height
            )
            .as_bytes(),
        );
    }
    u64::from(h.finalize()) | (dataset.views.len() as u64) << 32
}

/// Write a checkpoint of the run with `fingerprint` (state first, model last; both
/// atomically).
pub fn save(dir: &Path, c: &Checkpoint, fingerprint: u64) -> Result<PathBuf, CheckpointError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| CheckpointError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let (model_path, state_path) = paths(dir, c.iteration);
    let model_bytes = encode_model(&c.model, &model_path)?;
    let n = c.model.len() as u64;
    let k = 3 * c.model.coeffs_per_channel() as u64;
    let mut buf = Vec::new();
    buf.extend_from_slice(&MAGIC);
    buf.extend_from_slice(&VERSION.to_le_bytes());
    for v in [
        c.iteration,
        c.seed,
        c.adam.step,
        n,
        k,
        c.hook_state.len() as u64,
        fingerprint,
        u64::from(crc32fast::hash(&model_bytes)),
    ] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    debug_assert_eq!(buf.len(), HEADER_LEN);
    for v in c
        .adam
        .m
        .values()
        .chain(c.adam.v.values())
        .chain(c.stats.grad_sum.iter().copied())
    {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    c.stats
        .count
        .iter()
        .for_each(|v| buf.extend_from_slice(&v.to_le_bytes()));
    c.stats
        .max_radius
        .iter()
        .for_each(|v| buf.extend_from_slice(&v.to_le_bytes()));
    buf.extend_from_slice(&c.hook_state);
    let crc = crc32fast::hash(&buf);
    buf.extend_from_slice(&crc.to_le_bytes());
    crate::atomic::write_atomic(&state_path, &buf).map_err(io(&state_path))?;
    crate::atomic::write_atomic(&model_path, &model_bytes).map_err(io(&model_path))?;
    Ok(model_path)
}

/// Iterations of the complete checkpoints in `dir`, ascending.
pub fn list(dir: &Path) -> Vec<u64> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut its: Vec<u64> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let it = name.strip_suffix(".bin")?.parse::<u64>().ok()?;
            paths(dir, it).1.exists().then_some(it)
        })
        .collect();
    its.sort_unstable();
    its
}

/// Delete all but the newest `keep` checkpoints.
pub fn prune(dir: &Path, keep: usize) {
    let its = list(dir);
    for &it in its.iter().take(its.len().saturating_sub(keep.max(1))) {
        let (a, b) = paths(dir, it);
        let _ = std::fs::remove_file(a);
        let _ = std::fs::remove_file(b);
    }
}

/// Read the checkpoint after `iteration` iterations of the run with `fingerprint`.
pub fn load(dir: &Path, iteration: u64, fingerprint: u64) -> Result<Checkpoint, CheckpointError> {
    let (model_path, state_path) = paths(dir, iteration);
    let read = |path: &Path| {
        std::fs::read(path).map_err(|source| CheckpointError::Io {
            path: path.to_path_buf(),
            source,
        })
    };
    let bytes = read(&state_path)?;
    let corrupt = |reason: String| CheckpointError::Corrupt {
        path: state_path.clone(),
        reason,
    };
    if bytes.len() < HEADER_LEN + 4 || bytes[..8] != MAGIC {
        return Err(corrupt(format!(
            "not a training state ({} bytes, no `S4DTRAIN` header): truncated or overwritten",
            bytes.len()
        )));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
    if version != VERSION {
        return Err(corrupt(format!(
            "written by another version of the program (format {version}, this build reads {VERSION})"
        )));
    }
    let (body, tail) = bytes.split_at(bytes.len() - 4);
    if crc32fast::hash(body).to_le_bytes() != tail {
        return Err(corrupt(
            "its checksum does not match: the file is damaged".into(),
        ));
    }
    let word =
        |i: usize| u64::from_le_bytes(body[12 + 8 * i..20 + 8 * i].try_into().unwrap_or_default());
    let (it, seed, step, n, k, hook_len) = (word(0), word(1), word(2), word(3), word(4), word(5));
    if it != iteration {
        return Err(corrupt(format!(
            "it holds iteration {it}, not {iteration} as its name says"
        )));
    }
    if word(6) != fingerprint {
        return Err(corrupt(
            "it was made for other views (another capture, other cameras or another frame range)"
                .into(),
        ));
    }
    let model_bytes = read(&model_path)?;
    if u64::from(crc32fast::hash(&model_bytes)) != word(7) {
        return Err(CheckpointError::Corrupt {
            path: model_path.clone(),
            reason: format!(
                "it is not the model its state file {} was written with ({} bytes): truncated or damaged",
                state_path.display(),
                model_bytes.len()
            ),
        });
    }
    let model = parse_model(&model_bytes, &model_path)?;
    if n != model.len() as u64 || k != 3 * model.coeffs_per_channel() as u64 {
        return Err(corrupt("it does not match its model file".into()));
    }
    let (n, k) = (n as usize, k as usize);
    let floats = 2 * n * (17 + k) + n;
    let expected = HEADER_LEN + 4 * floats + 8 * n + hook_len as usize;
    if body.len() != expected {
        return Err(corrupt(format!(
            "{} bytes, expected {expected}",
            bytes.len()
        )));
    }
    let mut pos = HEADER_LEN;
    let mut next4 = || {
        let v: [u8; 4] = body[pos..pos + 4].try_into().unwrap_or_default();
        pos += 4;
        v
    };
    let mut f32s = std::iter::from_fn(|| Some(f32::from_le_bytes(next4())));
    let short = || corrupt("short moments".into());
    let m = ParamBuffers::from_values(n, k, &mut f32s).ok_or_else(short)?;
    let v = ParamBuffers::from_values(n, k, &mut f32s).ok_or_else(short)?;
    let grad_sum: Vec<f32> = f32s.take(n).collect();
    let mut stats = DensifyStats {
        grad_sum,
        count: Vec::with_capacity(n),
        max_radius: Vec::with_capacity(n),
    };
    for _ in 0..n {
        stats.count.push(u32::from_le_bytes(next4()));
    }
    for _ in 0..n {
        stats.max_radius.push(f32::from_le_bytes(next4()));
    }
    let hook_state = body[pos..].to_vec();
    Ok(Checkpoint {
        iteration,
        seed,
        model,
        adam: Adam {
            step,
            m,
            v,
            frozen: 0,
        },
        stats,
        hook_state,
    })
}

/// The newest checkpoint in `dir` that reads back whole and belongs to the run with
/// `fingerprint`. Each newer pair that does not is renamed to `*.damaged` (so it is neither
/// read again nor outlives the good ones in [`prune`]) and reported. An error only when a
/// file cannot be read or renamed at all.
pub fn latest_good(
    dir: &Path,
    fingerprint: u64,
) -> Result<(Option<Checkpoint>, Vec<Skipped>), CheckpointError> {
    let mut skipped = Vec::new();
    for it in list(dir).into_iter().rev() {
        let (path, reason) = match load(dir, it, fingerprint) {
            Ok(c) => return Ok((Some(c), skipped)),
            Err(e @ CheckpointError::Io { .. }) => return Err(e),
            Err(CheckpointError::Corrupt { path, reason }) => (path, reason),
            Err(CheckpointError::Model(e)) => (paths(dir, it).0, e.to_string()),
        };
        let mut set_aside = Vec::new();
        for p in <[PathBuf; 2]>::from(paths(dir, it)) {
            let mut to = p.clone().into_os_string();
            to.push(".damaged");
            let to = PathBuf::from(to);
            std::fs::rename(&p, &to).map_err(|source| CheckpointError::Io {
                path: p.clone(),
                source,
            })?;
            set_aside.push(to);
        }
        skipped.push(Skipped {
            path,
            reason,
            set_aside,
        });
    }
    Ok((None, skipped))
}
