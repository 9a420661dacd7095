//! Every bad capture layout gets one clear error naming the path and what is expected,
//! from the library and from the `pipeline` binary (non-zero exit, nothing written).

use crate::common;

use std::fs;
use std::path::Path;
use std::process::Command;

use common::{MP4_HEADER, make_capture, tree};
use pipeline::open_capture;

fn error_of(dir: &Path) -> String {
    format!(
        "{:#}",
        open_capture(dir).expect_err("layout should be rejected")
    )
}

/// Run the binary on `dir`, check it fails, wrote nothing, and return its stderr.
fn cli_error(dir: &Path) -> String {
    let before = tree(dir);
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("run")
        .arg(dir)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(!out.status.success(), "exit code should be non-zero");
    assert_eq!(
        tree(dir),
        before,
        "a rejected capture must not be written to"
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn a_good_layout_is_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(root.join("raw/cam1/GX020001.MP4"), MP4_HEADER).unwrap();
    fs::write(root.join("raw/cam1/GX010001.THM"), b"thumbnail").unwrap();
    fs::write(root.join("raw/cam2/.DS_Store"), b"junk").unwrap();
    let (capture, config) = open_capture(&root).unwrap();
    assert_eq!(config.capture.cameras, 4);
    assert_eq!(capture.cameras.len(), 4);
    assert_eq!(capture.stills.len(), 8);
    let names: Vec<_> = capture.cameras[1]
        .videos
        .iter()
        .map(|p| p.file_name().unwrap().to_owned())
        .collect();
    assert_eq!(names, ["GX010001.MP4", "GX020001.MP4"]);
}

#[test]
fn missing_capture_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("nope");
    let err = error_of(&missing);
    assert!(
        err.contains("does not exist") && err.contains("nope"),
        "{err}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .arg("run")
        .arg(&missing)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(!missing.exists(), "nothing may be created");
}

#[test]
fn missing_raw_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let err = cli_error(tmp.path());
    assert!(
        err.contains("raw") && err.contains("is missing") && err.contains("cam0"),
        "{err}"
    );
}

#[test]
fn a_missing_camera_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::remove_dir_all(root.join("raw/cam2")).unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("expected 4 camera folders") && err.contains("found 3"),
        "{err}"
    );
    assert!(err.contains("cam0, cam1, cam3"), "{err}");
}

#[test]
fn more_cameras_than_expected() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 5, 8);
    let err = cli_error(&root);
    assert!(
        err.contains("expected 4 camera folders") && err.contains("found 5"),
        "{err}"
    );
    assert!(err.contains("cameras = 5"), "the fix is named: {err}");
}

#[test]
fn camera_count_from_capture_toml() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 3, 0);
    fs::write(root.join("capture.toml"), "[capture]\ncameras = 3\n").unwrap();
    assert_eq!(open_capture(&root).unwrap().0.cameras.len(), 3);
}

#[test]
fn an_empty_camera_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::remove_file(root.join("raw/cam3/GX010001.MP4")).unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("cam3") && err.contains("holds no video"),
        "{err}"
    );
}

#[test]
fn image_sequence_cameras_are_accepted_but_not_mixed_with_videos() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    let cam2 = root.join("raw/cam2");
    fs::remove_file(cam2.join("GX010001.MP4")).unwrap();
    for k in 0..3 {
        fs::write(cam2.join(format!("{k:06}.jpg")), b"\xff\xd8\xff\xe0").unwrap();
    }
    let (capture, _) = open_capture(&root).unwrap();
    assert_eq!(capture.cameras[2].videos.len(), 3);
    // Images beside a video are refused, naming the image.
    fs::write(root.join("raw/cam1/000000.png"), b"png").unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("000000.png") && err.contains("not both"),
        "{err}"
    );
}

/// Camcorder AVCHD files (`00001.MTS`, MPEG-TS with 192-byte packets) and a container
/// whatever its name are videos: told by content, as FFmpeg demuxes them.
#[test]
fn camcorder_transport_streams_and_unnamed_containers_are_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    let mut mts = vec![0u8; 2 * 192];
    mts[4] = 0x47;
    mts[196] = 0x47;
    fs::remove_file(root.join("raw/cam1/GX010001.MP4")).unwrap();
    fs::write(root.join("raw/cam1/00001.MTS"), &mts).unwrap();
    fs::remove_file(root.join("raw/cam2/GX010001.MP4")).unwrap();
    fs::write(root.join("raw/cam2/take"), MP4_HEADER).unwrap();
    let (capture, _) = open_capture(&root).unwrap();
    assert_eq!(capture.cameras[1].videos, [root.join("raw/cam1/00001.MTS")]);
    assert_eq!(capture.cameras[2].videos, [root.join("raw/cam2/take")]);
}

#[test]
fn a_file_that_is_not_a_video() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(root.join("raw/cam1/notes.txt"), b"hello").unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("notes.txt") && err.contains("is not a video"),
        "{err}"
    );
}

#[test]
fn a_text_file_named_like_a_video() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(
        root.join("raw/cam0/GX010002.MP4"),
        b"this is text, not an mp4 file",
    )
    .unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("GX010002.MP4") && err.contains("not an MP4"),
        "{err}"
    );
}

#[test]
fn an_empty_video_file() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(root.join("raw/cam0/GX010002.MP4"), b"").unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("GX010002.MP4") && err.contains("empty"),
        "{err}"
    );
}

#[test]
fn a_stray_entry_in_raw() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(root.join("raw/GX010001.MP4"), MP4_HEADER).unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("raw/GX010001.MP4") && err.contains("camN"),
        "{err}"
    );
}

#[test]
fn a_non_image_in_stills() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(root.join("stills/readme.md"), b"#").unwrap();
    let err = cli_error(&root);
    assert!(
        err.contains("readme.md") && err.contains("not an image"),
        "{err}"
    );
}

#[test]
fn an_unknown_setting() {
    let tmp = tempfile::tempdir().unwrap();
    let root = make_capture(tmp.path(), 4, 8);
    fs::write(
        root.join("capture.toml"),
        "[capture]\ncameras = 4\nfps = 30\n",
    )
    .unwrap();
    let err = cli_error(&root);
    assert!(err.contains("fps") && err.contains("capture.toml"), "{err}");
}
