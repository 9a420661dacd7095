//! The `render` stage and the `pipeline render` command: the trained model along a camera
//! path (orbit, spiral, interpolate, train, heldout) with time frozen, swept or real, as
//! PNG frames (`rgb/`, colour-mapped `depth/`, `alpha/`) and an H.264 `render.mp4`
//! (`splat4d::paths`, `splat4d::eval::render_path`, `rig::video`).

use std::path::Path;

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use serde::{Deserialize, Serialize};
use shared_types::{Camera, Progress};
use splat4d::eval::FrameOutputs;
use splat4d::trajectories::{PathKind, PathSpec, TimeMode, camera_path};
use splat4d::{Gaussians, RenderBackend};

use crate::engine_inputs::{EngineSettings, load_trained_model, pinhole_cameras, render_backend};
use crate::heldout::pinhole_heldout_cameras;
use crate::stage_context::StageContext;

/// What a render writes, at least one of which proves it ran: the video, or PNG frames.
pub const OUTPUTS: [&str; 4] = ["render.mp4", "rgb/", "depth/", "alpha/"];

/// `[render]` settings (the same keys as the `pipeline render` flags).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSettings {
    /// orbit | spiral | interpolate | train | heldout
    pub path: String,
    /// fixed:SECONDS | sweep | real
    pub time: String,
    /// Frames of the path (`None`: one per aligned frame of the capture, at least 60).
    pub frames: Option<usize>,
    /// Frames per second of the video (`None`: the capture's frame rate).
    pub fps: Option<f64>,
    /// Output `[width, height]` (`None`: the first camera's working size).
    pub size: Option<[u32; 2]>,
    /// Write `render.mp4` (H.264).
    pub video: bool,
    /// Write `rgb/`, `depth/` and `alpha/` PNG frames.
    pub png: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            path: "orbit".into(),
            time: "sweep".into(),
            frames: None,
            fps: None,
            size: None,
            video: true,
            png: true,
        }
    }
}

/// The frames index and the pinhole cameras a path can follow: the training cameras and
/// the held-out ones of a real capture (`[capture] heldout`; none otherwise).
pub fn path_cameras(work_dir: &Path) -> anyhow::Result<(FramesIndex, Vec<Camera>, Vec<Camera>)> {
    let cameras_file = work_dir.join("poses").join("cameras.json");
    let poses = PosesFile::read(&cameras_file)?;
    let index = FramesIndex::read_json(&work_dir.join("frames").join("frames.json"))?;
    let train = pinhole_cameras(&index, &poses.set, &cameras_file)?
        .into_iter()
        .map(|(c, _)| c)
        .collect();
    let heldout = pinhole_heldout_cameras(work_dir)?;
    Ok((index, train, heldout))
}

/// Render `model` along the path of `settings` into `out_dir` (`render.mp4` and/or PNG
/// folders) with `backend`. `cameras` are the pinhole training cameras, `heldout` the
/// held-out ones; `background` is the colour the model was trained on (`[train] background`),
/// `backdrop` its learned backdrop when it has one.
#[allow(clippy::too_many_arguments)]
pub fn render(
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    background: [f32; 3],
    backdrop: Option<&splat4d::render::backdrop::Backdrop>,
    cameras: &[Camera],
    heldout: &[Camera],
    settings: &RenderSettings,
    default_frames: usize,
    default_fps: f64,
    out_dir: &Path,
    progress: &dyn Progress,
) -> anyhow::Result<usize> {
    let kind: PathKind = settings.path.parse().context("[render] path")?;
    let time: TimeMode = settings.time.parse().context("[render] time")?;
    let frames = settings.frames.unwrap_or(default_frames.max(60));
    let mut spec = PathSpec::new(kind, time, frames);
    spec.fps = settings.fps.unwrap_or(default_fps);
    spec.size = settings.size.map(|[w, h]| (w, h));
    let path = camera_path(&spec, cameras, heldout, &model.time)?;
    if path.is_empty() {
        bail!("the camera path is empty");
    }
    std::fs::create_dir_all(out_dir)?;
    let outputs = if settings.png {
        FrameOutputs::ALL
    } else {
        FrameOutputs::NONE
    };
    let mut video = None;
    if settings.video {
        let (w, h) = (path[0].0.intrinsics.width, path[0].0.intrinsics.height);
        if w % 2 == 1 || h % 2 == 1 {
            bail!("H.264 needs an even frame size, got {w}×{h}; set [render] size = [even, even]");
        }
        video = Some(VideoWriter::create(
            &out_dir.join("render.mp4"),
            w,
            h,
            spec.fps,
        )?);
    }
    let mut sink = |_: usize, rgb: &image::RgbImage| -> Result<(), String> {
        match video.as_mut() {
            Some(v) => v.push(rgb.as_raw()),
            None => Ok(()),
        }
    };
    let rendered = splat4d::eval::render_path(
        backend,
        model,
        &path,
        out_dir,
        outputs,
        background,
        backdrop,
        progress,
        Some(&mut sink),
    )?;
    if let Some(v) = video {
        v.finish()?;
    }
    Ok(rendered.frames)
}

/// What writes `render.mp4`: FFmpeg's H.264, or, in a build without FFmpeg, nothing.
#[cfg(feature = "ffmpeg")]
struct VideoWriter(rig::video::Mp4Writer);

#[cfg(feature = "ffmpeg")]
impl VideoWriter {
    fn create(file: &Path, w: u32, h: u32, fps: f64) -> anyhow::Result<Self> {
        let options = rig::video::VideoOptions::new(fps);
        Ok(Self(rig::video::Mp4Writer::create(file, w, h, &options)?))
    }

    fn push(&mut self, rgb: &[u8]) -> Result<(), String> {
        self.0.push(rgb).map_err(|e| e.to_string())
    }

    fn finish(self) -> anyhow::Result<()> {
        self.0.finish()?;
        Ok(())
    }
}

/// Never built: a build without FFmpeg refuses `[render] video = true`.
#[cfg(not(feature = "ffmpeg"))]
enum VideoWriter {}

#[cfg(not(feature = "ffmpeg"))]
impl VideoWriter {
    fn create(_: &Path, _: u32, _: u32, _: f64) -> anyhow::Result<Self> {
        Err(crate::without_ffmpeg("[render] video = true (render.mp4)")
            .context("set [render] video = false in capture.toml for PNG frames only"))
    }

    fn push(&mut self, _: &[u8]) -> Result<(), String> {
        match *self {}
    }

    fn finish(self) -> anyhow::Result<()> {
        match self {}
    }
}

/// The `render` stage; `trained` is what the model was trained on.
pub fn run(
    ctx: &StageContext,
    settings: &RenderSettings,
    trained: &crate::engine_inputs::TrainRecord,
    engine: &EngineSettings,
) -> anyhow::Result<()> {
    let backdrop = trained.load_backdrop(&ctx.capture.work_dir())?;
    if !settings.video && !settings.png {
        anyhow::bail!(
            "capture.toml [render]: `video` and `png` are both false, so the stage would write nothing; set one of them to true"
        );
    }
    let model = load_trained_model(&ctx.capture.work_dir())?;
    let (index, cameras, heldout) = path_cameras(&ctx.capture.work_dir())?;
    let backend = render_backend(engine.backend)?;
    ctx.record_tool("render backend", &backend.describe());
    let frames = render(
        backend.as_ref(),
        &model,
        trained.background,
        backdrop.as_ref(),
        &cameras,
        &heldout,
        settings,
        index.frames.len(),
        index.fps,
        &ctx.out_dir,
        ctx.progress,
    )?;
    tracing::info!(
        "rendered {frames} frames along the {} path (time {}) into {}",
        settings.path,
        settings.time,
        ctx.stage_dir("render").display()
    );
    Ok(())
}
