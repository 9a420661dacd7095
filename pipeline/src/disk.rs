//! A full disk, said plainly: when a stage fails because its filesystem is full (ENOSPC,
//! or a quota), the error says how much is free there, how much the stage needs, and that
//! its earlier outputs are untouched. Stages write into their partial folder and swap it
//! in only when complete, so a full disk never leaves a half-written output where a later
//! run reads it.

use std::path::Path;

/// Whether `error` (any cause in its chain) is a full filesystem or an exceeded quota.
pub fn is_full(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        let io = cause.downcast_ref::<std::io::Error>().is_some_and(|e| {
            matches!(
                e.kind(),
                std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
            )
        });
        // Errors that carry the OS's words rather than the `io::Error` (FFmpeg's, or a
        // library's own error that formats its cause).
        let text = cause.to_string();
        io || text.contains("No space left on device") || text.contains("Disk quota exceeded")
    })
}

/// Free and total bytes of the filesystem holding `path` (`None` where it cannot be asked).
pub fn space(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    let mut s = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: `c` is a NUL-terminated path and `s` a buffer statvfs fills on success.
    if unsafe { libc::statvfs(c.as_ptr(), s.as_mut_ptr()) } != 0 {
        return None;
    }
    // SAFETY: statvfs returned 0, so it filled `s`.
    let s = unsafe { s.assume_init() };
    // The fields' types differ between platforms (u32 on some), hence the casts.
    #[allow(clippy::unnecessary_cast)]
    let (unit, free, total) = (s.f_frsize as u64, s.f_bavail as u64, s.f_blocks as u64);
    Some((free * unit, total * unit))
}

/// Bytes of the files under `dir` (0 when it does not exist).
pub fn size_of(dir: &Path) -> u64 {
    crate::manifest::list_files(dir)
        .unwrap_or_default()
        .iter()
        .filter_map(|rel| std::fs::metadata(dir.join(rel)).ok())
        .map(|m| m.len())
        .sum()
}

/// `bytes` for a person: `512 B`, `3.4 MB`, `1.20 GB`.
pub fn human(bytes: u64) -> String {
    let b = bytes as f64;
    match bytes {
        0..1_000 => format!("{bytes} B"),
        1_000..1_000_000 => format!("{:.1} kB", b / 1e3),
        1_000_000..1_000_000_000 => format!("{:.1} MB", b / 1e6),
        _ => format!("{:.2} GB", b / 1e9),
    }
}

/// How much more room a stage that stopped on a full disk needs, at least. `partial`: its
/// partial folder as it stopped; `previous`: its last complete outputs; `resumable`: the
/// partial folder stays to continue from (a training: one more checkpoint, its two largest
/// files, must fit), else it was removed and everything must be written again (what it
/// had written, or the last complete outputs' size where larger).
pub fn needed(partial: &Path, previous: &Path, resumable: bool) -> u64 {
    if resumable {
        let mut sizes: Vec<u64> = crate::manifest::list_files(partial)
            .unwrap_or_default()
            .iter()
            .filter_map(|rel| std::fs::metadata(partial.join(rel)).ok())
            .map(|m| m.len())
            .collect();
        sizes.sort_unstable_by(|a, b| b.cmp(a));
        sizes.iter().take(2).sum()
    } else {
        size_of(partial).max(size_of(previous))
    }
}

/// What a stage that stopped on a full disk says beside the OS's error: the free space
/// where the capture's `work` folder is, what the stage needs ([`needed`]), that its last
/// complete outputs (`previous` bytes) are untouched, and how to go on.
pub fn advice(work: &Path, stage: &str, needed: u64, previous: u64, resumable: bool) -> String {
    let free = match space(work) {
        Some((free, total)) => format!("{} free of {}", human(free), human(total)),
        None => "no free space".into(),
    };
    let beside = if previous > 0 {
        format!(
            " beside its last complete outputs ({}, untouched until the new ones are whole)",
            human(previous)
        )
    } else {
        String::new()
    };
    let then = if resumable {
        "run again: it continues from its last checkpoint"
    } else {
        "run again (what it had written was removed)"
    };
    format!(
        "the disk holding {} is full ({free}): `{stage}` needs at least {} free{beside}; make that much room (or move the capture to a larger disk) and {then}",
        work.display(),
        human(needed)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_is_told_from_other_errors_through_the_chain() {
        let full = anyhow::Error::from(std::io::Error::from_raw_os_error(libc::ENOSPC))
            .context("cannot write work/.frames.partial/cam0/0001.png");
        assert!(is_full(&full));
        let quota = anyhow::Error::from(std::io::Error::from_raw_os_error(libc::EDQUOT));
        assert!(is_full(&quota));
        let ffmpeg = anyhow::anyhow!("encoding render.mp4: No space left on device");
        assert!(is_full(&ffmpeg));
        let denied = anyhow::Error::from(std::io::Error::from_raw_os_error(libc::EACCES));
        assert!(!is_full(&denied.context("cannot write x")));
    }

    #[test]
    fn sizes_and_space_are_measured() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("a/b")).unwrap();
        std::fs::write(dir.path().join("a/one"), [0u8; 1000]).unwrap();
        std::fs::write(dir.path().join("a/b/two"), [0u8; 234]).unwrap();
        assert_eq!(size_of(dir.path()), 1234);
        assert_eq!(size_of(&dir.path().join("none")), 0);
        let (free, total) = space(dir.path()).unwrap();
        assert!(free > 0 && free <= total);
        assert_eq!(
            [
                human(999),
                human(1234),
                human(3_400_000),
                human(1_200_000_000)
            ],
            ["999 B", "1.2 kB", "3.4 MB", "1.20 GB"]
        );
        // Not resumable: all of it again. Resumable: one more checkpoint (its two largest).
        std::fs::write(dir.path().join("a/three"), [0u8; 500]).unwrap();
        let none = dir.path().join("none");
        assert_eq!(needed(&dir.path().join("a"), &none, false), 1734);
        assert_eq!(needed(&none, &dir.path().join("a"), false), 1734);
        assert_eq!(needed(&dir.path().join("a"), &none, true), 1500);
        let said = advice(dir.path(), "frames", 1234, 0, false);
        assert!(
            said.contains("free of") && said.contains("at least 1.2 kB free;"),
            "{said}"
        );
        let said = advice(dir.path(), "train", 10, 3_400_000, true);
        assert!(
            said.contains("(3.4 MB, untouched") && said.contains("last checkpoint"),
            "{said}"
        );
    }
}
