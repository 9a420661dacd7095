//! A full disk, on a real one: a small tmpfs holds a capture, and `frames`, `train` and
//! `export` run out of space on it. Each stops with an error naming the path, the free
//! space and what it needs; no half-written file is left where a later run reads it; the
//! earlier outputs survive; a training continues from its last checkpoint once there is
//! room, and ends with the model a run on a large disk trains. Needs root (or a mount
//! namespace) for `mount -t tmpfs`.

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A tmpfs mounted at a folder, unmounted when dropped.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(at: &Path, bytes: u64) -> Option<Self> {
        fs::create_dir_all(at).unwrap();
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={bytes}"), "tmpfs"])
            .arg(at)
            .output()
            .ok()?;
        out.status
            .success()
            .then(|| Self(at.to_path_buf()))
            .or_else(|| {
                let why = format!(
                    "cannot mount a tmpfs ({}): this test needs root",
                    String::from_utf8_lossy(&out.stderr).trim()
                );
                assert!(
                    std::env::var("CI").as_deref() != Ok("true"),
                    "under CI=true: {why}"
                );
                eprintln!("SKIPPED: {why}");
                None
            })
    }

    /// Give the filesystem `free` bytes beyond what it holds now.
    fn leave_free(&self, free: u64) {
        let used = common_used(&self.0);
        let out = Command::new("mount")
            .args(["-o", &format!("remount,size={}", used + free)])
            .arg(&self.0)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// Bytes in use on the filesystem at `path` (whole pages, as tmpfs counts them).
fn common_used(path: &Path) -> u64 {
    let (free, total) = pipeline::disk::space(path).unwrap();
    total - free
}

fn pipeline(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(args)
        .env_remove("CI")
        .output()
        .unwrap()
}

/// Every file under `dir` with its bytes, sorted by path (relative).
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    pipeline::manifest::list_files(dir)
        .unwrap()
        .into_iter()
        .map(|rel| {
            let bytes = fs::read(dir.join(&rel)).unwrap();
            (rel.to_string_lossy().into_owned(), bytes)
        })
        .collect()
}

/// Temporary siblings (`.name.tmp-PID.ext`) anywhere under `dir`.
fn temporaries(dir: &Path) -> Vec<String> {
    pipeline::manifest::list_files(dir)
        .unwrap()
        .into_iter()
        .map(|p| p.to_string_lossy().into_owned())
        .filter(|p| p.contains(".tmp-"))
        .collect()
}

/// A stage that ran out of space: failed, naming the disk, what it needs and the OS error.
fn assert_disk_full(out: &Output, stage: &str) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{stage} should fail: {err}");
    assert!(
        err.contains("No space left on device")
            && err.contains("is full (")
            && err.contains(" free of ")
            && err.contains(&format!("`{stage}` needs")),
        "{stage}: {err}"
    );
    println!("{stage} on a full disk said:\n{err}");
    err
}

#[test]
fn a_full_disk_stops_each_stage_cleanly_and_training_continues_once_there_is_room() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(disk) = Tmpfs::mount(&tmp.path().join("small"), 1 << 20) else {
        return;
    };
    let settings = common::CHEAP
        .replace("iterations = 10", "iterations = 60")
        .replace("checkpoint_every = 0", "checkpoint_every = 10");
    // The whole run on a large disk: the reference outputs and sizes.
    let reference = common::tiny_capture(&tmp.path().join("ref"), &settings);
    let out = pipeline(&["--quiet", "run", reference.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ref_work = reference.join("work");
    println!(
        "reference capture: {} bytes",
        pipeline::disk::size_of(&reference)
    );
    disk.leave_free(2 * pipeline::disk::size_of(&reference) + (64 << 20));

    let root = disk.0.join("take");
    common::copy_dir(&reference, &root);
    let work = root.join("work");
    let capture = root.to_str().unwrap();

    // Rerunning a stage whose new outputs fit only half-way.
    for stage in ["frames", "export"] {
        let before = files(&work.join(stage));
        disk.leave_free(pipeline::disk::size_of(&work.join(stage)) / 2);
        let out = pipeline(&["run", capture, "--only", stage, "--force"]);
        let err = assert_disk_full(&out, stage);
        assert!(
            err.contains("untouched until the new ones are whole"),
            "{err}"
        );
        assert_eq!(
            files(&work.join(stage)),
            before,
            "{stage}'s outputs changed"
        );
        assert!(!work.join(format!(".{stage}.partial")).exists());
        assert_eq!(temporaries(&work), Vec::<String>::new());
        let status = pipeline(&["status", capture]);
        let table = String::from_utf8_lossy(&status.stdout);
        assert!(table.contains("failed"), "{table}");
    }

    // A first training with room for about two checkpoints.
    fs::remove_dir_all(work.join("train")).unwrap();
    let ckpt = ref_work.join("train/ckpt");
    let pair = fs::read_dir(&ckpt)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .max()
        .unwrap()
        * 2;
    disk.leave_free(pair * 5 / 2);
    let out = pipeline(&["run", capture, "--only", "train"]);
    let err = assert_disk_full(&out, "train");
    assert!(err.contains("continues from its last checkpoint"), "{err}");
    let partial = work.join(".train.partial/ckpt");
    let kept = splat4d::train::checkpoint::list(&partial);
    assert!(!kept.is_empty(), "no checkpoint survived: {err}");
    assert_eq!(temporaries(&work), Vec::<String>::new());
    assert!(!work.join("train").exists());

    // Room again: it continues from its last checkpoint, to the large disk's model.
    disk.leave_free(4 * pair + (32 << 20));
    let out = pipeline(&["run", capture, "--only", "train"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    assert!(said.contains("resuming"), "{said}");
    assert!(
        fs::read(work.join("train/model.bin")).unwrap()
            == fs::read(ref_work.join("train/model.bin")).unwrap(),
        "the training continued after a full disk ends with another model"
    );
}
