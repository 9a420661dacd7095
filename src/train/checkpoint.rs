//! Checkpoints: `ckpt/NNNNNN.bin` (the model file) beside `ckpt/NNNNNN.state` (iteration,
//! Adam moments, densification statistics, hook state). Together with the per-iteration
//! RNG streams (seeded from `(seed, iteration)`) they make a resumed run bit-identical
//! (a learned backdrop is fitted after the last step, from the model alone).

use crate::model::Gaussians;
use crate::model::file::{ModelFileError, load_model, save_model};
use crate::train::densify::DensifyStats;
use crate::train::optim::{Adam, ParamBuffers};

use std::path::{Path, PathBuf};

const MAGIC: [u8; 8] = *b"S4DTRAIN";
const VERSION: u32 = 1;

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
    #[error(
        "{path} is not a valid training state ({reason}); delete it to resume from an earlier checkpoint"
    )]
    Corrupt { path: PathBuf, reason: String },
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

/// Write a checkpoint (state first, model last; both atomically).
pub fn save(dir: &Path, c: &Checkpoint) -> Result<PathBuf, CheckpointError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| CheckpointError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let (model_path, state_path) = paths(dir, c.iteration);
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
    ] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
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
    crate::atomic::write_atomic(&state_path, &buf).map_err(io(&state_path))?;
    save_model(&c.model, &model_path)?;
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

/// Read the checkpoint after `iteration` iterations.
pub fn load(dir: &Path, iteration: u64) -> Result<Checkpoint, CheckpointError> {
    let (model_path, state_path) = paths(dir, iteration);
    let model = load_model(&model_path)?;
    let bytes = std::fs::read(&state_path).map_err(|source| CheckpointError::Io {
        path: state_path.clone(),
        source,
    })?;
    let corrupt = |reason: &str| CheckpointError::Corrupt {
        path: state_path.clone(),
        reason: reason.into(),
    };
    if bytes.len() < 60 || bytes[..8] != MAGIC {
        return Err(corrupt("bad magic"));
    }
    if u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default()) != VERSION {
        return Err(corrupt("unsupported version"));
    }
    let word =
        |i: usize| u64::from_le_bytes(bytes[12 + 8 * i..20 + 8 * i].try_into().unwrap_or_default());
    let (it, seed, step, n, k, hook_len) = (word(0), word(1), word(2), word(3), word(4), word(5));
    if it != iteration || n != model.len() as u64 || k != 3 * model.coeffs_per_channel() as u64 {
        return Err(corrupt("does not match its model file"));
    }
    let (n, k) = (n as usize, k as usize);
    let floats = 2 * n * (17 + k) + n;
    let expected = 60 + 4 * floats + 8 * n + hook_len as usize;
    if bytes.len() != expected {
        return Err(corrupt(&format!(
            "{} bytes, expected {expected}",
            bytes.len()
        )));
    }
    let mut pos = 60;
    let mut next4 = || {
        let v: [u8; 4] = bytes[pos..pos + 4].try_into().unwrap_or_default();
        pos += 4;
        v
    };
    let mut f32s = std::iter::from_fn(|| Some(f32::from_le_bytes(next4())));
    let m = ParamBuffers::from_values(n, k, &mut f32s).ok_or_else(|| corrupt("short moments"))?;
    let v = ParamBuffers::from_values(n, k, &mut f32s).ok_or_else(|| corrupt("short moments"))?;
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
    let hook_state = bytes[pos..].to_vec();
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
