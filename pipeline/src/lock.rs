//! One run at a time per capture directory: an exclusive OS lock on `work/.lock`.
//! The OS releases it when the process ends, however it ends, so a crash never leaves a
//! stale lock behind. On a cluster the jobs of a capture take it on the shared
//! filesystem: NFS carries such locks between clients, Lustre only with its `flock` mount
//! option (without it taking the lock fails, naming the file).

use std::fs::{self, File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use thiserror::Error;

#[derive(Debug, Error)]
pub enum LockError {
    #[error(
        "{path} is locked by another `pipeline` run ({holder}); wait for it to finish, or stop it"
    )]
    Busy { path: PathBuf, holder: String },
    #[error("cannot create the lock file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Held while a run works on a capture directory; released on drop.
#[derive(Debug)]
pub struct CaptureLock {
    _file: File,
    path: PathBuf,
}

impl CaptureLock {
    pub fn path(work_dir: &Path) -> PathBuf {
        work_dir.join(".lock")
    }

    /// Take the lock of `work_dir` (created if needed) or fail at once if it is held.
    pub fn acquire(work_dir: &Path) -> Result<Self, LockError> {
        Self::take(work_dir, false)
    }

    /// Take the lock of `work_dir` shared with other runs that take it shared (the runs of
    /// one time chunk each, which write only their own chunk's folder), or fail at once if
    /// a whole run holds it.
    pub fn acquire_shared(work_dir: &Path) -> Result<Self, LockError> {
        Self::take(work_dir, true)
    }

    /// The lock file of `work_dir` (created if needed), locked exclusively or shared.
    fn take(work_dir: &Path, shared: bool) -> Result<Self, LockError> {
        let path = Self::path(work_dir);
        let io = |source| LockError::Io {
            path: path.clone(),
            source,
        };
        fs::create_dir_all(work_dir).map_err(io)?;
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io)?;
        let taken = if shared {
            file.try_lock_shared()
        } else {
            file.try_lock()
        };
        match taken {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let holder = if holder.trim().is_empty() {
                    "unknown process".into()
                } else {
                    holder.trim().to_string()
                };
                return Err(LockError::Busy { path, holder });
            }
            Err(fs::TryLockError::Error(e)) => return Err(io(e)),
        }
        // Who holds it, for the message another run gets (the last of several sharing it):
        // on a cluster's shared filesystem the holder may be on another node.
        let job = std::env::var("SLURM_JOB_ID")
            .map(|id| format!(", Slurm job {id}"))
            .unwrap_or_default();
        let note = format!(
            "pid {} on {}{job}{}, started {}",
            std::process::id(),
            host_name(),
            if shared { ", one time chunk" } else { "" },
            chrono::Utc::now().format("%Y-%m-%d %H:%M:%S UTC")
        );
        file.set_len(0).map_err(io)?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        file.write_all(note.as_bytes()).map_err(io)?;
        Ok(Self { _file: file, path })
    }

    /// Whether some process holds the lock right now (used by `status` to tell a running
    /// stage from an interrupted one).
    pub fn is_held(work_dir: &Path) -> bool {
        let Ok(file) = File::open(Self::path(work_dir)) else {
            return false;
        };
        match file.try_lock() {
            Ok(()) => {
                let _ = file.unlock();
                false
            }
            Err(_) => true,
        }
    }

    pub fn file(&self) -> &Path {
        &self.path
    }
}

/// This machine's host name (in the lock's holder note and the jobs' error messages).
pub(crate) fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .ok()
        .filter(|h| !h.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "an unnamed host".into())
}
