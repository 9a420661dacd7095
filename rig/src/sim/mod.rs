//! Simulated cameras: render a scene declared in TOML into a capture directory laid out
//! exactly like a real one (`raw/camN/GX01xxxx.MP4`, `stills/still_NN.jpg`), with the
//! ground truth beside it (`groundtruth/`). Only the effects a scene asks for are
//! simulated; an effect that is off costs nothing and changes no byte of the output.
//!
//! Rendering is a small CPU rasteriser of textured triangles (never Gaussians: the model
//! must not be tested on data made by itself). See `docs/simulator.md` for the scene format
//! and the exact meaning of every ground-truth file.

mod animation;
pub mod audio;
#[cfg(feature = "ffmpeg")]
pub mod encode;
mod error;
pub(crate) mod lens;
pub mod mesh;
pub mod output;
pub mod raster;
mod scene;
mod schema;
mod source;
pub mod texture;
mod validate;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shared_types::{CameraSet, Progress};

pub use error::SimError;
pub use scene::Scene;
pub use schema::{
    CameraRole, DeformKind, DeformSpec, Keyframe, SimCamera, TextureSpec, VIDEO_CAMERAS,
};
pub use source::SimSource;

use lens::LensPlan;
use mesh::SceneMesh;
use raster::{Light, Rendered};
use source::Shot;
use texture::hash;

/// What [`simulate`] wrote.
#[derive(Clone, Debug, Serialize)]
pub struct SimSummary {
    pub capture_dir: PathBuf,
    /// Every video file, `raw/camN/GX….MP4` (and `raw/heldoutN/…` with `heldout_videos`).
    pub videos: Vec<PathBuf>,
    /// Frames encoded into the videos (all cameras, dropped frames excluded).
    pub video_frames: u64,
    pub heldout_frames: u64,
    pub stills: Vec<PathBuf>,
    /// Seconds of scene each video camera recorded.
    pub scene_seconds: f64,
    /// Wall-clock seconds the simulation took.
    pub wall_seconds: f64,
}

/// `groundtruth/offsets.json`: the true timing of every video camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OffsetsFile {
    pub version: u32,
    pub scene: String,
    pub fps: f64,
    pub frames_per_camera: u32,
    pub duration_s: f64,
    pub seed: u64,
    /// Present when the scene records audio.
    pub audio: Option<AudioTruth>,
    /// Present when the scene has a flash.
    pub flash: Option<FlashTruth>,
    /// Every camera filmed as video: cam0..cam3, then heldoutN when `heldout_videos` is on.
    pub cameras: Vec<CameraTiming>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AudioTruth {
    pub sample_rate: u32,
    /// Scene time of the clap at its source.
    pub clap_time_s: f64,
    pub clap_position: [f64; 3],
    /// Speed of sound used for the acoustic delays (0 when the delay is off).
    pub speed_of_sound_m_s: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlashTruth {
    pub time_s: f64,
    pub duration_s: f64,
    pub strength: f64,
    /// Rolling-shutter readout (first to last row), 0 = global shutter.
    pub readout_s: f64,
    /// Exposure time of each row.
    pub shutter_s: f64,
}

/// Timing of one video camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraTiming {
    pub name: String,
    /// Scene time (common timeline, seconds) of the camera's frame 0 = `offset_s + phase_frames / fps`.
    /// Frame k (pts k/fps in the file) shows the scene at `start_time_s + k / fps`.
    pub start_time_s: f64,
    /// The declared start offset, seconds.
    pub offset_s: f64,
    /// The declared sub-frame phase, in frames.
    pub phase_frames: f64,
    pub exposure: f64,
    /// Frame indices missing from the file (their pts never occur).
    pub dropped_frames: Vec<u32>,
    /// The camera's files in order; each chapter's pts restart at 0.
    pub files: Vec<ChapterFile>,
    /// Present when the scene records audio.
    pub audio: Option<CameraAudio>,
    /// File time of the flash's start (`flash.time_s − start_time_s`), when there is a flash.
    pub flash_file_time_s: Option<f64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChapterFile {
    /// Path relative to the capture directory.
    pub file: String,
    /// Camera frame index of the chapter's first frame.
    pub first_frame: u32,
    /// Frame indices covered (dropped ones included).
    pub frames: u32,
    /// Number of frames actually in the file.
    pub written_frames: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraAudio {
    /// Distance from the clap / speed of sound (0 when the acoustic delay is off).
    pub acoustic_delay_s: f64,
    /// File time at which the clap starts in this camera's audio
    /// (`clap_time_s + acoustic_delay_s − start_time_s`).
    pub clap_file_time_s: f64,
    /// The start time audio alignment recovers: `start_time_s − acoustic_delay_s`
    /// (the offset plus the acoustic path, as an audio-only method sees it).
    pub audio_start_time_s: f64,
}

/// `groundtruth/heldout/<name>/timestamps.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldoutTimestamps {
    pub camera: String,
    pub fps: f64,
    /// Scene time of frame `NNNNNN.png`, by index.
    pub times_s: Vec<f64>,
}

/// Everything a simulation needs, shared by the camera jobs.
struct Context<'a> {
    scene: &'a Scene,
    world: World,
    dir: &'a Path,
    progress: &'a dyn Progress,
}

/// The scene's geometry and light, built once and shared (cheaply cloned) by every camera,
/// including the live [`SimSource`]s.
#[derive(Clone)]
pub(crate) struct World {
    scene: Arc<Scene>,
    meshes: Arc<Vec<SceneMesh>>,
    light: Light,
}

impl World {
    fn new(scene: &Scene) -> Self {
        World {
            scene: Arc::new(scene.clone()),
            meshes: Arc::new(mesh::build_meshes(
                &scene.file,
                scene.file.render.texture_size,
            )),
            light: light_of(scene),
        }
    }

    fn render(&self, plan: &LensPlan, t: f64) -> Rendered {
        let world = mesh::world_positions(&self.scene.file, &self.meshes, t);
        let canvas = raster::render(&plan.view, &self.meshes, &world, &self.light);
        plan.resolve(canvas)
    }
}

fn light_of(scene: &Scene) -> Light {
    let r = &scene.file.render;
    Light {
        direction: DVec3::from_array(r.light_direction).normalize().as_vec3(),
        ambient: r.ambient as f32,
        diffuse: r.diffuse as f32,
        clear: r.clear_color.map(|v| v as f32),
    }
}

/// The prepared lens of one of the scene's cameras, at the scene's supersampling.
fn lens_plan(scene: &Scene, cam: &SimCamera) -> Result<LensPlan, SimError> {
    let mut plan = LensPlan::new(&cam.camera, scene.file.render.supersample).map_err(|m| {
        SimError::invalid(&scene.origin, format!("camera {}: {m}", cam.camera.name))
    })?;
    plan.prepare(&cam.camera);
    Ok(plan)
}

/// Every camera must see some geometry, and its lens must have a canvas (called by
/// `Scene::from_toml_str`).
pub(crate) fn check_views(scene: &Scene) -> Result<(), SimError> {
    let meshes = mesh::build_meshes(&scene.file, 16);
    let light = light_of(scene);
    for cam in &scene.cameras {
        let plan = LensPlan::new(&cam.camera, 1).map_err(|m| {
            SimError::invalid(&scene.origin, format!("camera {}: {m}", cam.camera.name))
        })?;
        let t = match cam.role {
            CameraRole::Still => scene.file.stills.time,
            _ => cam.start_time,
        };
        // A coarse pinhole render (≤ 64 px wide) of what the camera sees.
        let mut view = plan.view;
        let s = (64.0 / view.width as f32).min(1.0);
        view.fx *= s;
        view.fy *= s;
        view.cx *= s;
        view.cy *= s;
        view.width = ((view.width as f32 * s).ceil() as usize).max(1);
        view.height = ((view.height as f32 * s).ceil() as usize).max(1);
        let world = mesh::world_positions(&scene.file, &meshes, t);
        let r = raster::render(&view, &meshes, &world, &light);
        if r.id.iter().all(|&i| i == 0) {
            return Err(SimError::invalid(
                &scene.origin,
                format!(
                    "camera {} looks at nothing: no geometry in its view at t = {t} s; \
                     point its look_at at the scene or add a background",
                    cam.camera.name
                ),
            ));
        }
    }
    Ok(())
}

fn refuse_existing(dir: &Path) -> Result<(), SimError> {
    for sub in ["raw", "stills", "groundtruth"] {
        let p = dir.join(sub);
        if let Ok(mut entries) = std::fs::read_dir(&p)
            && entries.next().is_some()
        {
            return Err(SimError::CaptureExists {
                path: dir.to_path_buf(),
                found: format!("{sub}/"),
            });
        }
    }
    Ok(())
}

#[cfg(feature = "ffmpeg")]
/// Render `scene` into `capture_dir` (created if missing; must not already hold a capture).
pub fn simulate(
    scene: &Scene,
    capture_dir: &Path,
    progress: &dyn Progress,
) -> Result<SimSummary, SimError> {
    let started = Instant::now();
    refuse_existing(capture_dir)?;
    std::fs::create_dir_all(capture_dir).map_err(|e| SimError::write(capture_dir, e))?;
    encode::init();
    let ctx = Context {
        scene,
        world: World::new(scene),
        dir: capture_dir,
        progress,
    };
    let frames = scene.frames_per_camera() as u64;
    let heldout = scene
        .cameras
        .iter()
        .filter(|c| c.role == CameraRole::Heldout)
        .count() as u64;
    let stills = scene
        .cameras
        .iter()
        .filter(|c| c.role == CameraRole::Still)
        .count() as u64;
    let filmed_heldout = if scene.films_heldout() { heldout } else { 0 };
    progress.start(
        frames * (VIDEO_CAMERAS as u64 + heldout + filmed_heldout) + stills,
        "frames",
    );

    type Filmed = (CameraTiming, Vec<PathBuf>, u64);
    enum Done {
        Video(Filmed),
        Heldout(u64, Option<Filmed>),
        Still(PathBuf),
    }
    let results: Vec<Result<Done, SimError>> = scene
        .cameras
        .par_iter()
        .enumerate()
        .map(|(index, cam)| match cam.role {
            CameraRole::Video => video_camera(&ctx, cam, index).map(Done::Video),
            CameraRole::Heldout => {
                let truth = heldout_camera(&ctx, cam)?;
                let filmed = if scene.films_heldout() {
                    Some(video_camera(&ctx, cam, index)?)
                } else {
                    None
                };
                Ok(Done::Heldout(truth, filmed))
            }
            CameraRole::Still => still(&ctx, cam).map(Done::Still),
        })
        .collect();

    let mut summary = SimSummary {
        capture_dir: capture_dir.to_path_buf(),
        videos: Vec::new(),
        video_frames: 0,
        heldout_frames: 0,
        stills: Vec::new(),
        scene_seconds: scene.frames_per_camera() as f64 / scene.fps(),
        wall_seconds: 0.0,
    };
    let mut timings = Vec::new();
    for r in results {
        match r? {
            Done::Video((t, files, n)) => {
                timings.push(t);
                summary.videos.extend(files);
                summary.video_frames += n;
            }
            Done::Heldout(n, filmed) => {
                summary.heldout_frames += n;
                if let Some((t, files, n)) = filmed {
                    timings.push(t);
                    summary.videos.extend(files);
                    summary.video_frames += n;
                }
            }
            Done::Still(p) => summary.stills.push(p),
        }
    }

    let gt = capture_dir.join("groundtruth");
    let cameras = CameraSet::new(scene.cameras.iter().map(|c| c.camera.clone()).collect());
    output::write_json(&gt.join("cameras.json"), &cameras)?;
    let f = &scene.file;
    let offsets = OffsetsFile {
        version: 1,
        scene: f.scene.name.clone(),
        fps: scene.fps(),
        frames_per_camera: scene.frames_per_camera(),
        duration_s: f.scene.duration,
        seed: scene.seed(),
        audio: f.audio.as_ref().filter(|a| a.enabled).map(|a| AudioTruth {
            sample_rate: a.sample_rate,
            clap_time_s: a.clap_time,
            clap_position: a.clap_position,
            speed_of_sound_m_s: if a.acoustic_delay {
                audio::SPEED_OF_SOUND
            } else {
                0.0
            },
        }),
        flash: flash_of(scene).map(|(fl, shutter)| FlashTruth {
            time_s: fl.time,
            duration_s: fl.duration,
            strength: fl.strength,
            readout_s: fl.readout,
            shutter_s: shutter,
        }),
        cameras: timings,
    };
    output::write_json(&gt.join("offsets.json"), &offsets)?;
    progress.finish();
    summary.wall_seconds = started.elapsed().as_secs_f64();
    Ok(summary)
}

/// The flash, when the scene has one switched on, with its row exposure time.
fn flash_of(scene: &Scene) -> Option<(&schema::FlashSection, f64)> {
    scene
        .file
        .flash
        .as_ref()
        .filter(|f| f.enabled && f.strength != 0.0)
        .map(|f| (f, f.shutter.unwrap_or(0.5 / scene.fps())))
}

/// Sensor-side effects of a video frame taken at scene time `t` (exposure, flash, noise),
/// then quantisation to RGB8. Each effect is skipped entirely when off.
fn sensor(
    scene: &Scene,
    cam: &SimCamera,
    cam_index: usize,
    frame: u32,
    t: f64,
    img: &Rendered,
) -> Vec<u8> {
    let (w, h) = (img.width, img.height);
    let mut px: Vec<[f32; 3]> = img.color.clone();
    let mut gains: Option<Vec<f32>> = None;
    if cam.exposure != 1.0 {
        gains = Some(vec![cam.exposure as f32; h]);
    }
    if let Some((fl, shutter)) = flash_of(scene) {
        let rows: Vec<f32> = (0..h)
            .map(|r| {
                // Row r starts exposing at t + readout·r/h and integrates for `shutter`.
                let a = t + fl.readout * r as f64 / h as f64;
                let overlap = ((a + shutter).min(fl.time + fl.duration) - a.max(fl.time)).max(0.0);
                (1.0 + fl.strength * overlap / shutter) as f32
            })
            .collect();
        if rows.iter().any(|&g| g != 1.0) {
            let g = gains.get_or_insert_with(|| vec![1.0; h]);
            for (g, r) in g.iter_mut().zip(rows) {
                *g *= r;
            }
        }
    }
    if let Some(g) = &gains {
        for (row, &gain) in px.chunks_mut(w).zip(g) {
            for p in row {
                *p = p.map(|v| v * gain);
            }
        }
    }
    if let Some(n) = scene
        .file
        .noise
        .as_ref()
        .filter(|n| n.enabled && n.sigma > 0.0)
    {
        let mut rng = ChaCha8Rng::seed_from_u64(hash(
            scene.seed(),
            0x5E75_0000 + cam_index as u64,
            frame as u64,
        ));
        let sigma = n.sigma as f32;
        for p in &mut px {
            for v in p.iter_mut() {
                let (u1, u2): (f32, f32) = (rng.random::<f32>().max(1e-12), rng.random::<f32>());
                *v += sigma * (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos();
            }
        }
    }
    to_rgb8(&px)
}

fn to_rgb8(px: &[[f32; 3]]) -> Vec<u8> {
    px.iter()
        .flat_map(|p| p.map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8))
        .collect()
}

fn rel(ctx: &Context, p: &Path) -> String {
    p.strip_prefix(ctx.dir)
        .unwrap_or(p)
        .to_string_lossy()
        .replace('\\', "/")
}

#[cfg(feature = "ffmpeg")]
fn video_camera(
    ctx: &Context,
    cam: &SimCamera,
    index: usize,
) -> Result<(CameraTiming, Vec<PathBuf>, u64), SimError> {
    let scene = ctx.scene;
    let f = &scene.file;
    let fps = scene.fps();
    let frames = scene.frames_per_camera();
    let name = &cam.camera.name;
    let source = SimSource::in_world(ctx.world.clone(), index)?;
    let k = cam.camera.intrinsics;

    let audio_cfg = f.audio.as_ref().filter(|a| a.enabled);
    let track = audio_cfg.map(|a| {
        let n = (frames as f64 / fps * a.sample_rate as f64).round() as usize;
        let distance =
            (cam.camera.world_to_camera.centre() - DVec3::from_array(a.clap_position)).length();
        audio::camera_track(
            &audio::Clap::new(scene.seed()),
            scene.seed(),
            index as u64,
            a.sample_rate,
            n,
            cam.start_time,
            a.clap_time,
            distance,
            a.acoustic_delay,
            a.noise,
            a.clap_gain,
        )
    });
    let rate = audio_cfg.map(|a| a.sample_rate);
    let sample_at =
        |frame: u32| rate.map_or(0, |r| (frame as f64 / fps * r as f64).round() as usize);

    let dir = ctx.dir.join("raw").join(name);
    std::fs::create_dir_all(&dir).map_err(|e| SimError::write(&dir, e))?;
    let per_chapter = cam.chapter_frames.unwrap_or(frames).min(frames);
    let mut files = Vec::new();
    let mut chapters = Vec::new();
    let mut written_total = 0u64;
    for (c, first) in (0..frames).step_by(per_chapter as usize).enumerate() {
        let last = (first + per_chapter).min(frames);
        let path = dir.join(format!("GX{:02}0001.MP4", c + 1));
        let mut writer = encode::Mp4Writer::create(
            &path,
            k.width,
            k.height,
            fps,
            f.encode.crf,
            &f.encode.preset,
            rate,
        )?;
        let mut pending = Vec::new();
        let mut pushed = sample_at(first);
        let mut written = 0u32;
        for frame in first..last {
            if let Some(Shot { img, rgb, .. }) = source.shot(frame) {
                writer.push_video((frame - first) as i64, &rgb)?;
                written += 1;
                if frame == 0 {
                    let depth: Vec<f32> = img
                        .depth
                        .iter()
                        .map(|&d| if d.is_finite() { d } else { 0.0 })
                        .collect();
                    let p = ctx
                        .dir
                        .join("groundtruth")
                        .join("depth")
                        .join(format!("{name}.npy"));
                    output::write_atomic(&p, &output::npy_f32(img.height, img.width, &depth))?;
                }
                write_mask(ctx, name, frame, &img)?;
            }
            if let Some(tr) = &track {
                let upto = sample_at(frame + 1).min(tr.samples.len());
                writer.push_audio(&tr.samples[pushed..upto], &mut pending)?;
                pushed = upto;
            }
            ctx.progress.advance(1);
        }
        files.push(writer.finish(pending)?);
        chapters.push(ChapterFile {
            file: rel(ctx, files.last().expect("just pushed")),
            first_frame: first,
            frames: last - first,
            written_frames: written,
        });
        written_total += written as u64;
    }
    let timing = CameraTiming {
        name: name.clone(),
        start_time_s: cam.start_time,
        offset_s: cam.offset,
        phase_frames: cam.phase,
        exposure: cam.exposure,
        dropped_frames: cam.dropped.clone(),
        files: chapters,
        audio: track.map(|tr| CameraAudio {
            acoustic_delay_s: tr.acoustic_delay,
            clap_file_time_s: tr.clap_file_time,
            audio_start_time_s: cam.start_time - tr.acoustic_delay,
        }),
        flash_file_time_s: flash_of(scene).map(|(fl, _)| fl.time - cam.start_time),
    };
    Ok((timing, files, written_total))
}

/// `groundtruth/masks/<camera>/NNNNNN.png` of frame `frame` (255 where a moving or
/// deforming object is visible), when the scene asks for masks.
fn write_mask(ctx: &Context, camera: &str, frame: u32, img: &Rendered) -> Result<(), SimError> {
    if !ctx.scene.file.groundtruth.masks {
        return Ok(());
    }
    let moving: Vec<u16> = ctx
        .world
        .meshes
        .iter()
        .filter(|m| m.moving)
        .map(|m| m.id)
        .collect();
    let mask: Vec<u8> = img
        .id
        .iter()
        .map(|i| if moving.contains(i) { 255 } else { 0 })
        .collect();
    let path = ctx
        .dir
        .join("groundtruth")
        .join("masks")
        .join(camera)
        .join(format!("{frame:06}.png"));
    output::write_gray_png(&path, img.width as u32, img.height as u32, &mask)
}

fn heldout_camera(ctx: &Context, cam: &SimCamera) -> Result<u64, SimError> {
    let scene = ctx.scene;
    let name = &cam.camera.name;
    let plan = lens_plan(scene, cam)?;
    let dir = ctx.dir.join("groundtruth").join("heldout").join(name);
    let k = cam.camera.intrinsics;
    let mut times = Vec::new();
    for frame in 0..scene.frames_per_camera() {
        let t = frame as f64 / scene.fps();
        let img = ctx.world.render(&plan, t);
        output::write_rgb(
            &dir.join(format!("{frame:06}.png")),
            k.width,
            k.height,
            &to_rgb8(&img.color),
            None,
        )?;
        write_mask(ctx, name, frame, &img)?;
        times.push(t);
        ctx.progress.advance(1);
    }
    let n = times.len() as u64;
    output::write_json(
        &dir.join("timestamps.json"),
        &HeldoutTimestamps {
            camera: name.clone(),
            fps: scene.fps(),
            times_s: times,
        },
    )?;
    Ok(n)
}

fn still(ctx: &Context, cam: &SimCamera) -> Result<PathBuf, SimError> {
    let scene = ctx.scene;
    let name = &cam.camera.name;
    let plan = lens_plan(scene, cam)?;
    let img = ctx.world.render(&plan, scene.file.stills.time);
    let k = cam.camera.intrinsics;
    let path = ctx.dir.join("stills").join(format!("{name}.jpg"));
    output::write_rgb(
        &path,
        k.width,
        k.height,
        &to_rgb8(&img.color),
        Some(scene.file.stills.jpeg_quality),
    )?;
    ctx.progress.advance(1);
    Ok(path)
}

/// Every triangle of the scene's meshes (background and objects) in world coordinates at
/// scene time `t`: the true surfaces, for checking reconstructions against them.
pub fn surface_triangles(scene: &Scene, t: f64) -> Vec<[DVec3; 3]> {
    let meshes = mesh::build_meshes(&scene.file, 16);
    let world = mesh::world_positions(&scene.file, &meshes, t);
    meshes
        .iter()
        .zip(&world)
        .flat_map(|(m, pos)| {
            m.mesh
                .triangles
                .iter()
                .map(move |tri| tri.map(|i| pos[i as usize].as_dvec3()))
        })
        .collect()
}

/// The point of triangle `[a, b, c]` closest to `p` (Voronoi regions of the vertices, edges
/// and face; Ericson, Real-Time Collision Detection, 5.1.5): with [`surface_triangles`],
/// the distance of a reconstructed point to the true surfaces.
pub fn closest_on_triangle(p: DVec3, [a, b, c]: [DVec3; 3]) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Render one camera of the scene at scene time `t` without sensor effects (for tests and
/// tools): RGB in [0, 1], z-depth (∞ where empty) and mesh ids.
pub fn render_clean(scene: &Scene, camera: &str, t: f64) -> Option<Rendered> {
    let cam = scene.cameras.iter().find(|c| c.camera.name == camera)?;
    let mut plan = LensPlan::new(&cam.camera, scene.file.render.supersample).ok()?;
    plan.prepare(&cam.camera);
    let meshes = mesh::build_meshes(&scene.file, scene.file.render.texture_size);
    let world = mesh::world_positions(&scene.file, &meshes, t);
    Some(plan.resolve(raster::render(
        &plan.view,
        &meshes,
        &world,
        &light_of(scene),
    )))
}
