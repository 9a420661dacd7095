//! Folders that appear only when complete: a folder `dir/NAME` is built in the hidden
//! sibling `dir/.NAME.partial` and renamed into place once finished, so a reader never
//! sees half of it (a stage's `work/<stage>/`, `pipeline render --out`). While a finished
//! folder replaces an older one, the older one waits in `dir/.NAME.old`; after a crash
//! between the two renames, [`recover_interrupted_swap`] puts it back.
//!
//! Single files are written with `shared_types::atomic` (temporary sibling, then rename).

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::Context;

/// `dir/NAME` → `dir/.NAME.partial`: where `dir/NAME` is built.
pub fn partial_path(target: &Path) -> PathBuf {
    hidden_sibling(target, "partial")
}

/// `dir/NAME` → `dir/.NAME.old`: where the previous `dir/NAME` waits during a swap.
fn old_path(target: &Path) -> PathBuf {
    hidden_sibling(target, "old")
}

fn hidden_sibling(target: &Path, suffix: &str) -> PathBuf {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    target.with_file_name(format!(".{name}.{suffix}"))
}

/// Run `build` on the folder `partial` cleared of any earlier attempt; when it fails,
/// remove what it left. `build` creates the folder itself.
pub fn build_fresh<T>(
    partial: &Path,
    build: impl FnOnce(&Path) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    if partial.exists() {
        fs::remove_dir_all(partial)
            .with_context(|| format!("cannot clear {}", partial.display()))?;
    }
    build(partial).inspect_err(|_| {
        let _ = fs::remove_dir_all(partial);
    })
}

/// Replace the folder `target` (if any) with the finished folder `partial`. On failure
/// the previous `target` is put back.
pub fn swap_in(partial: &Path, target: &Path) -> anyhow::Result<()> {
    let old = old_path(target);
    if old.exists() {
        fs::remove_dir_all(&old).with_context(|| format!("cannot remove {}", old.display()))?;
    }
    if target.exists() {
        fs::rename(target, &old)
            .with_context(|| format!("cannot move {} aside", target.display()))?;
    }
    if let Err(e) = fs::rename(partial, target) {
        if old.exists() {
            let _ = fs::rename(&old, target);
        }
        return Err(e)
            .with_context(|| format!("cannot move the new outputs to {}", target.display()));
    }
    if old.exists() {
        let _ = fs::remove_dir_all(&old);
    }
    Ok(())
}

/// After a crash between the two renames of [`swap_in`], put the old `target` back (or
/// drop it when the new one made it in).
pub fn recover_interrupted_swap(target: &Path) {
    let old = old_path(target);
    if old.exists() {
        if target.exists() {
            let _ = fs::remove_dir_all(&old);
        } else {
            let _ = fs::rename(&old, target);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_and_old_folders_are_hidden_siblings() {
        let target = Path::new("/c/work/train");
        assert_eq!(partial_path(target), Path::new("/c/work/.train.partial"));
        assert_eq!(old_path(target), Path::new("/c/work/.train.old"));
    }

    #[test]
    fn a_swap_replaces_the_folder_and_a_failed_build_leaves_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        for text in ["one", "two"] {
            let partial = partial_path(&target);
            build_fresh(&partial, |dir| {
                fs::create_dir_all(dir)?;
                Ok(fs::write(dir.join("a.txt"), text)?)
            })
            .unwrap();
            swap_in(&partial, &target).unwrap();
            assert_eq!(fs::read_to_string(target.join("a.txt")).unwrap(), text);
        }
        let partial = partial_path(&target);
        let failed: anyhow::Result<()> = build_fresh(&partial, |dir| {
            fs::create_dir_all(dir)?;
            fs::write(dir.join("half.txt"), "half")?;
            anyhow::bail!("failed midway")
        });
        assert!(failed.is_err());
        assert!(!partial.exists());
        let names: Vec<_> = fs::read_dir(tmp.path())
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names, ["out"]);
    }

    #[test]
    fn an_interrupted_swap_puts_the_old_folder_back() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        fs::create_dir_all(old_path(&target)).unwrap();
        recover_interrupted_swap(&target);
        assert!(target.is_dir() && !old_path(&target).exists());
    }
}
