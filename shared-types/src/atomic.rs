//! Writing files so that a reader never sees a half-written one: write a temporary
//! sibling, flush it, rename it over the target. The one implementation every crate of
//! the workspace uses (each maps the `io::Error` into its own error type).

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A temporary sibling name for `path` (same folder, so the rename is atomic; hidden,
/// unique to this process, and keeping the extension so encoders that pick a format by
/// name still see it): `dir/out.mp4` → `dir/.out.tmp-<pid>.mp4`.
pub fn temp_sibling(path: &Path) -> PathBuf {
    let stem = path.file_stem().and_then(|n| n.to_str()).unwrap_or("file");
    let name = match path.extension().and_then(|e| e.to_str()) {
        Some(ext) => format!(".{stem}.tmp-{}.{ext}", std::process::id()),
        None => format!(".{stem}.tmp-{}", std::process::id()),
    };
    path.with_file_name(name)
}

/// Write `bytes` to `path` atomically, creating its folder if needed. On failure the
/// target is untouched and the temporary file removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_with(path, |tmp| {
        let mut f = fs::File::create(tmp)?;
        f.write_all(bytes)?;
        f.sync_all()
    })
}

/// Write `value` to `path` as pretty JSON with a final newline, atomically (its folder
/// created if needed): the one JSON writer of the workspace.
pub fn write_json<T: serde::Serialize + ?Sized>(path: &Path, value: &T) -> std::io::Result<()> {
    let mut text = serde_json::to_vec_pretty(value).map_err(std::io::Error::other)?;
    text.push(b'\n');
    write_atomic(path, &text)
}

/// Let `write` create the file at a temporary sibling path (for writers that open the
/// file themselves: encoders, streaming writers), then rename it over `path`. The folder
/// is created first; on any error the temporary file is removed and `path` untouched.
pub fn write_with<T, E: From<std::io::Error>>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<T, E>,
) -> Result<T, E> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        fs::create_dir_all(dir)?;
    }
    let tmp = temp_sibling(path);
    let result = write(&tmp).and_then(|v| {
        fs::rename(&tmp, path)?;
        Ok(v)
    });
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_replaces_and_leaves_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/out.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"two");
        let names: Vec<_> = fs::read_dir(dir.path().join("sub")).unwrap().collect();
        assert_eq!(names.len(), 1);
    }

    #[test]
    fn a_failed_write_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        write_atomic(&path, b"old").unwrap();
        // A folder in the way of the temporary name makes the write fail.
        fs::create_dir(temp_sibling(&path)).unwrap();
        assert!(write_atomic(&path, b"new").is_err());
        assert_eq!(fs::read(&path).unwrap(), b"old");
    }

    #[test]
    fn a_failing_writer_leaves_no_file_behind() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        let r: std::io::Result<()> = write_with(&path, |tmp| {
            fs::write(tmp, b"half")?;
            Err(std::io::Error::other("encoder failed"))
        });
        assert!(r.is_err());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
