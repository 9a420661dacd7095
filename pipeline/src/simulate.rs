//! `pipeline simulate` and `pipeline demo`: make a capture directory from a scene file
//! with the simulator (`rig::sim`), without ever overwriting an existing capture.

use std::fs;
use std::path::Path;

use anyhow::{Context, bail};

use crate::partial_dir::build_fresh;
use crate::report::Reporter;

/// The scene of `pipeline demo`, built into the binary.
pub const DEMO_SCENE: &str = include_str!("../../fixtures/demo.toml");

/// The `capture.toml` of `pipeline demo` (short training for a CPU).
pub const DEMO_SETTINGS: &str = include_str!("../../fixtures/demo-capture.toml");

/// Simulate `scene` into `capture_dir`. The capture is written to a hidden folder inside
/// `capture_dir` and moved into place when complete; an existing capture (a `raw/`
/// folder) is never touched.
pub fn simulate_into(
    scene: &rig::sim::Scene,
    capture_dir: &Path,
    reporter: &Reporter,
) -> anyhow::Result<()> {
    if capture_dir.join("raw").exists() {
        bail!(
            "{} already holds a capture (raw/); choose another folder or delete it first",
            capture_dir.display()
        );
    }
    fs::create_dir_all(capture_dir)
        .with_context(|| format!("cannot create {}", capture_dir.display()))?;
    let partial = capture_dir.join(".simulate.partial");
    build_fresh(&partial, |partial| {
        let progress = reporter.progress("simulate");
        #[cfg(not(feature = "ffmpeg"))]
        let result: anyhow::Result<()> = Err(crate::without_ffmpeg("simulating a capture"));
        #[cfg(feature = "ffmpeg")]
        let result = rig::sim::simulate(scene, partial, &progress);
        shared_types::Progress::finish(&progress);
        result.context("simulation failed")
    })?;
    for entry in fs::read_dir(&partial)? {
        let entry = entry?;
        let target = capture_dir.join(entry.file_name());
        if target.exists() {
            bail!(
                "{} already exists; not overwriting it (the new capture is in {})",
                target.display(),
                partial.display()
            );
        }
        fs::rename(entry.path(), &target)
            .with_context(|| format!("cannot move {}", target.display()))?;
    }
    fs::remove_dir(&partial).ok();
    Ok(())
}

/// The built-in demo scene, with its held-out cameras also filmed as videos
/// (`raw/heldoutN/`), so the demo is evaluated the way a real capture is (see
/// [`demo_settings`]).
pub fn demo_scene() -> anyhow::Result<rig::sim::Scene> {
    Ok(
        rig::sim::Scene::from_toml_str(DEMO_SCENE, "built-in demo scene (fixtures/demo.toml)")?
            .with_heldout_videos(true),
    )
}

/// The demo's `capture.toml`: [`DEMO_SETTINGS`] plus `[capture] heldout` listing the scene's
/// filmed held-out cameras. They are synced, aligned and posed in the same COLMAP solve as
/// the training cameras, never trained on, and measured by eval: a score of the model, not
/// of how well simulated ground-truth cameras can be placed next to solved ones
/// (BENCHMARKS.md, "Held-out cameras: filmed against simulated ground truth").
pub fn demo_settings(scene: &rig::sim::Scene) -> String {
    let names: Vec<String> = scene
        .cameras
        .iter()
        .filter(|c| c.role == rig::sim::CameraRole::Heldout)
        .map(|c| format!("{:?}", c.camera.name))
        .collect();
    if names.is_empty() || !scene.films_heldout() {
        return DEMO_SETTINGS.to_string();
    }
    format!(
        "[capture]\n# Filmed by the simulator like the rig; posed with it, never trained on, measured by eval.\nheldout = [{}]\n\n{DEMO_SETTINGS}",
        names.join(", ")
    )
}

/// The simulator's true video cameras (`groundtruth/cameras.json`, names `cam*`), with
/// the file's path.
pub fn truth_video_cameras(
    capture_dir: &Path,
) -> anyhow::Result<(std::path::PathBuf, Vec<shared_types::Camera>)> {
    let path = capture_dir.join("groundtruth/cameras.json");
    let truth: shared_types::CameraSet = serde_json::from_str(
        &fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?,
    )
    .with_context(|| format!("{} is not a camera set", path.display()))?;
    let video = truth
        .cameras
        .into_iter()
        .filter(|c| c.name.starts_with("cam"))
        .collect();
    Ok((path, video))
}

/// Write what a perfect MASt3R-style model would output for every pair of the
/// simulator's video cameras, from their true depth at their first frame
/// (`groundtruth/depth/camN.npy`), as exported point maps `pointmaps/a__b.npz` (the
/// layout of docs/init.md). Set `[init] pointmaps = "pointmaps"` to initialise from them.
pub fn write_truth_pointmaps(capture_dir: &Path) -> anyhow::Result<std::path::PathBuf> {
    use pointinit::npy;
    let (path, cameras) = truth_video_cameras(capture_dir)?;
    check_pinhole(&path, &cameras)?;
    let mut depths = Vec::new();
    for c in &cameras {
        let file = capture_dir.join(format!("groundtruth/depth/{}.npy", c.name));
        let depth = npy::read_npy(&file)?;
        let want = [c.intrinsics.height as usize, c.intrinsics.width as usize];
        if depth.shape != want {
            bail!(
                "{}: shape {:?}, expected {want:?} (the camera's image size)",
                file.display(),
                depth.shape
            );
        }
        depths.push(depth.data);
    }
    let out = capture_dir.join("pointmaps");
    write_pairs(&out, &cameras, &depths)?;
    Ok(out)
}

/// Like [`write_truth_pointmaps`], at several moments: the true depth of each camera's
/// frame of each aligned frame in `frames` (of the frames stage's `index`), rendered
/// from `scene`, as `pointmaps/NNNNNN/a__b.npz`. The folder is built under a temporary
/// name and renamed when complete; an existing `pointmaps/` is an error.
pub fn write_truth_moment_pointmaps(
    capture_dir: &Path,
    scene: &rig::sim::Scene,
    index: &rig::frames::FramesIndex,
    frames: &[usize],
) -> anyhow::Result<std::path::PathBuf> {
    let (path, truth) = truth_video_cameras(capture_dir)?;
    check_pinhole(&path, &truth)?;
    let out = capture_dir.join("pointmaps");
    if out.exists() {
        bail!("{} already exists; not overwriting it", out.display());
    }
    let partial = capture_dir.join(".pointmaps.partial");
    build_fresh(&partial, |partial| {
        for &frame in frames {
            let aligned = index
                .frames
                .iter()
                .find(|f| f.index == frame)
                .with_context(|| format!("aligned frame {frame} is not in the frames index"))?;
            let mut cameras = Vec::new();
            let mut depths = Vec::new();
            for (cam, view) in index.cameras.iter().zip(&aligned.views) {
                let camera = truth
                    .iter()
                    .find(|c| c.name == cam.name)
                    .with_context(|| format!("{}: no camera {}", path.display(), cam.name))?;
                let t = scene_time(scene, &cam.name, view.source_frame)?;
                let img = rig::sim::render_clean(scene, &cam.name, t)
                    .with_context(|| format!("the scene has no camera {}", cam.name))?;
                let depth = img
                    .depth
                    .iter()
                    .map(|&d| if d.is_finite() { d } else { 0.0 });
                cameras.push(camera.clone());
                depths.push(depth.collect());
            }
            let dir = pointinit::moment_maps::frame_dir(partial, frame);
            write_pairs(&dir, &cameras, &depths)?;
        }
        Ok(())
    })?;
    fs::rename(&partial, &out).with_context(|| format!("cannot move {}", out.display()))?;
    Ok(out)
}

/// Scene time of the `source_frame`-th frame a camera recorded (its dropped frames skipped).
fn scene_time(scene: &rig::sim::Scene, camera: &str, source_frame: usize) -> anyhow::Result<f64> {
    let cam = scene
        .cameras
        .iter()
        .find(|c| c.camera.name == camera)
        .with_context(|| format!("the scene has no camera {camera}"))?;
    let frame = (0..scene.frames_per_camera())
        .filter(|f| !cam.dropped.contains(f))
        .nth(source_frame)
        .with_context(|| format!("camera {camera} recorded no frame {source_frame}"))?;
    Ok(cam.start_time + frame as f64 / scene.fps())
}

fn check_pinhole(path: &Path, cameras: &[shared_types::Camera]) -> anyhow::Result<()> {
    match cameras.iter().find(|c| !c.distortion.is_none()) {
        Some(c) => bail!(
            "{}: camera {} has a lens distortion; true point maps are written only for pinhole cameras",
            path.display(),
            c.name
        ),
        None => Ok(()),
    }
}

/// Every pair's true point maps from the cameras' depths, into `out`.
fn write_pairs(
    out: &Path,
    cameras: &[shared_types::Camera],
    depths: &[Vec<f32>],
) -> anyhow::Result<()> {
    use pointinit::npy;
    fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    for a in 0..cameras.len() {
        for b in a + 1..cameras.len() {
            let maps = npy::pair_maps_from_depth(
                (&cameras[a], &depths[a]),
                (&cameras[b], &depths[b]),
                1.0,
            );
            npy::write_pair_npz(
                out,
                &cameras[a].name,
                &cameras[b].name,
                &maps,
                &Default::default(),
            )
            .with_context(|| format!("cannot write point maps into {}", out.display()))?;
        }
    }
    Ok(())
}

/// Write the simulator's true video cameras (`groundtruth/cameras.json`, `cam*`) as an
/// OpenCV-style `calibration.json` in the capture, so that the poses stage imports them
/// instead of running COLMAP (for tests and benchmarks that isolate later stages).
pub fn write_truth_calibration(capture_dir: &Path) -> anyhow::Result<()> {
    let (path, video) = truth_video_cameras(capture_dir)?;
    let mut cameras = serde_json::Map::new();
    for c in &video {
        let (i, d, w) = (&c.intrinsics, &c.distortion, &c.world_to_camera);
        if !d.is_none() {
            bail!(
                "{}: camera {} has a lens distortion; only pinhole ground truth is written as a calibration",
                path.display(),
                c.name
            );
        }
        cameras.insert(
            c.name.clone(),
            serde_json::json!({
                "K": [[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]],
                "dist": [0.0, 0.0, 0.0, 0.0, 0.0],
                "R": w.rotation().transpose().to_cols_array_2d(),
                "t": w.translation().to_array(),
                "size": [i.width, i.height],
            }),
        );
    }
    let out = capture_dir.join("calibration.json");
    shared_types::atomic::write_atomic(
        &out,
        // The truth is in the engine's pixel convention (centres at integer + 0.5).
        serde_json::to_string_pretty(&serde_json::json!({
            "pixel_centre": "half",
            "cameras": cameras
        }))?
        .as_bytes(),
    )
    .with_context(|| format!("cannot write {}", out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_settings_parse_into_the_measured_schedule() {
        let scene = demo_scene().unwrap();
        let text = demo_settings(&scene);
        let config = crate::config::CaptureConfig::parse(&text, Path::new("capture.toml")).unwrap();
        assert_eq!(config.capture.heldout.len(), 4);
        assert_eq!(
            config.init.pointmaps.as_deref(),
            Some(Path::new("pointmaps"))
        );
        assert!(config.init.moments >= 2, "the demo's maps are per moment");
        let t = &config.train;
        assert_eq!((t.iterations, t.batch_size), (2000, 1));
        assert!(t.init_time_scale <= 0.25 / (config.init.moments - 1) as f64);
        assert!(t.densify.until_iteration < t.iterations);
        assert!(t.densify.max_gaussians <= 80_000);
    }
}
