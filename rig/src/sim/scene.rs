//! The scene file: its TOML schema (every table rejects unknown keys), defaults, and the
//! validation that turns it into a [`Scene`] ready to simulate. The format is documented
//! key by key in `docs/simulator.md`; keep the two in step.
//!
//! World convention: metres, z up, cameras in the OpenCV convention of `shared_types::camera`.
// `!(x > 0.0)` is deliberate below: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use std::path::Path;

use glam::{DQuat, DVec2, DVec3};
use serde::Deserialize;
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::error::SimError;

/// Number of video cameras a capture holds (`raw/cam0` … `raw/cam3`).
pub const VIDEO_CAMERAS: usize = 4;

// ---------------------------------------------------------------------------------------
// The file as written (serde).

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct SceneFile {
    pub scene: SceneSection,
    #[serde(default)]
    pub render: RenderSection,
    #[serde(default)]
    pub encode: EncodeSection,
    #[serde(default)]
    pub background: BackgroundSection,
    #[serde(default)]
    pub objects: Vec<ObjectSection>,
    pub cameras: CamerasSection,
    #[serde(default)]
    pub stills: StillsSection,
    pub audio: Option<AudioSection>,
    pub flash: Option<FlashSection>,
    pub noise: Option<NoiseSection>,
    #[serde(default)]
    pub groundtruth: GroundTruthSection,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct SceneSection {
    #[serde(default)]
    pub name: String,
    /// Seconds of video each camera records.
    pub duration: f64,
    /// Frames per second of every video camera and of the held-out cameras.
    pub fps: f64,
    #[serde(default)]
    pub seed: u64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RenderSection {
    /// Samples per pixel along each axis (1 = one sample at the pixel centre).
    pub supersample: u32,
    /// Direction towards the (directional) light, world frame.
    pub light_direction: [f64; 3],
    pub ambient: f64,
    pub diffuse: f64,
    /// Edge length in texels of every baked texture tile.
    pub texture_size: u32,
    /// Colour where no geometry is hit.
    pub clear_color: [f64; 3],
}

impl Default for RenderSection {
    fn default() -> Self {
        Self {
            supersample: 1,
            light_direction: [0.4, -0.3, 1.0],
            ambient: 0.45,
            diffuse: 0.55,
            texture_size: 256,
            clear_color: [0.5, 0.5, 0.5],
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct EncodeSection {
    pub crf: u32,
    pub preset: String,
}

impl Default for EncodeSection {
    fn default() -> Self {
        Self { crf: 18, preset: "fast".into() }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct BackgroundSection {
    /// `room` (a box seen from inside), `dome` (a sphere and a floor) or `none`.
    pub kind: String,
    /// Room: `[x, y, z]` extent; the floor is at `center.z`.
    pub size: [f64; 3],
    /// Dome radius.
    pub radius: f64,
    pub center: [f64; 3],
    pub segments: u32,
    pub texture: TextureSpec,
}

impl Default for BackgroundSection {
    fn default() -> Self {
        Self {
            kind: "room".into(),
            size: [8.0, 8.0, 3.0],
            radius: 5.0,
            center: [0.0, 0.0, 0.0],
            segments: 8,
            texture: TextureSpec::default(),
        }
    }
}

/// A procedural texture, baked to a tileable square image.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct TextureSpec {
    /// `mix` (noise + checker + glyphs), `noise`, `checker`, `glyphs` or `solid`.
    pub kind: String,
    /// Metres covered by one texture tile.
    pub tile: f64,
    /// Two colours the pattern runs between (`solid` uses the first).
    pub colors: [[f64; 3]; 2],
    /// Checker squares / glyph cells per tile side.
    pub cells: u32,
    /// Added to the scene seed for this texture.
    pub seed: u64,
}

impl Default for TextureSpec {
    fn default() -> Self {
        Self { kind: "mix".into(), tile: 1.0, colors: [[0.15, 0.2, 0.3], [0.9, 0.85, 0.7]], cells: 8, seed: 0 }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ObjectSection {
    #[serde(default)]
    pub name: String,
    /// `box`, `sphere`, `plane`, `cylinder` or `mesh`.
    pub shape: String,
    /// Box `[x, y, z]`; plane `[x, y]` (z ignored).
    #[serde(default = "unit3")]
    pub size: [f64; 3],
    #[serde(default = "half")]
    pub radius: f64,
    #[serde(default = "one")]
    pub height: f64,
    #[serde(default = "default_segments")]
    pub segments: u32,
    #[serde(default)]
    pub position: [f64; 3],
    /// Euler angles in degrees, applied x then y then z.
    #[serde(default)]
    pub rotation: [f64; 3],
    #[serde(default)]
    pub texture: TextureSpec,
    /// Keyframed rigid motion; overrides `position`/`rotation` when present.
    #[serde(default)]
    pub keyframes: Vec<Keyframe>,
    pub deform: Option<DeformSpec>,
    /// `mesh`: vertices in object coordinates.
    #[serde(default)]
    pub vertices: Vec<[f64; 3]>,
    /// `mesh`: triangles as vertex indices.
    #[serde(default)]
    pub triangles: Vec<[u32; 3]>,
    /// `mesh`: optional texture coordinates in metres (one per vertex).
    #[serde(default)]
    pub uvs: Vec<[f64; 2]>,
}

fn unit3() -> [f64; 3] {
    [1.0; 3]
}
fn half() -> f64 {
    0.5
}
fn one() -> f64 {
    1.0
}
fn default_segments() -> u32 {
    16
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    /// Scene time in seconds.
    pub t: f64,
    pub position: [f64; 3],
    #[serde(default)]
    pub rotation: [f64; 3],
}

/// A non-rigid motion, applied in object coordinates before the rigid motion.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DeformSpec {
    /// `wave`: travelling wave along local x displacing local z (a flag);
    /// `bend`: local x displacement growing with the square of local z (a swaying pole).
    pub kind: DeformKind,
    pub amplitude: f64,
    #[serde(default = "one")]
    pub wavelength: f64,
    /// Hz.
    #[serde(default = "one")]
    pub frequency: f64,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum DeformKind {
    Wave,
    Bend,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CamerasSection {
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
    #[serde(default = "default_hfov")]
    pub hfov: f64,
    pub video: Vec<CameraSpec>,
    #[serde(default)]
    pub heldout: Vec<CameraSpec>,
    /// Also film every held-out camera as a video camera (`raw/heldoutN/`).
    #[serde(default)]
    pub heldout_videos: bool,
}

fn default_width() -> u32 {
    320
}
fn default_height() -> u32 {
    240
}
fn default_hfov() -> f64 {
    70.0
}

#[derive(Clone, Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(crate) struct CameraSpec {
    pub position: [f64; 3],
    pub look_at: [f64; 3],
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Horizontal field of view in degrees (or give `focal`).
    pub hfov: Option<f64>,
    /// Focal length in pixels (fx = fy).
    pub focal: Option<f64>,
    /// Start offset in seconds: scene time of the first frame, before `phase`.
    #[serde(default)]
    pub offset: f64,
    /// Sub-frame phase in frames, in [0, 1): added to the start time as `phase / fps`.
    #[serde(default)]
    pub phase: f64,
    /// Exposure gain (1 = nominal).
    #[serde(default = "one")]
    pub exposure: f64,
    #[serde(default)]
    pub distortion: Distortion,
    /// Frame indices missing from the file.
    #[serde(default)]
    pub dropped: Vec<u32>,
    /// Frames per file; the video is split into GoPro chapters GX01…, GX02….
    pub chapter_frames: Option<u32>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct StillsSection {
    pub count: u32,
    pub radius: f64,
    /// Heights of the stills alternate between these two values.
    pub heights: [f64; 2],
    pub center: [f64; 3],
    pub look_at: [f64; 3],
    pub width: u32,
    pub height: u32,
    pub hfov: f64,
    /// Scene time at which the stills are taken.
    pub time: f64,
    /// Angle of the first still, degrees from +x.
    pub start_angle: f64,
    pub jpeg_quality: u8,
}

impl Default for StillsSection {
    fn default() -> Self {
        Self {
            count: 8,
            radius: 3.0,
            heights: [1.2, 2.0],
            center: [0.0, 0.0, 0.0],
            look_at: [0.0, 0.0, 0.8],
            width: 640,
            height: 480,
            hfov: 65.0,
            time: 0.0,
            start_angle: 22.5,
            jpeg_quality: 92,
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct AudioSection {
    #[serde(default = "yes")]
    pub enabled: bool,
    #[serde(default = "default_rate")]
    pub sample_rate: u32,
    /// Standard deviation of the background noise (full scale = 1).
    #[serde(default = "default_audio_noise")]
    pub noise: f64,
    /// Scene time of the clap, seconds.
    pub clap_time: f64,
    #[serde(default)]
    pub clap_position: [f64; 3],
    /// Peak amplitude of the clap at 1 m.
    #[serde(default = "default_clap_gain")]
    pub clap_gain: f64,
    /// Delay the clap by distance / 343 m/s at each camera.
    #[serde(default = "yes")]
    pub acoustic_delay: bool,
}

fn yes() -> bool {
    true
}
fn default_rate() -> u32 {
    48_000
}
fn default_audio_noise() -> f64 {
    0.01
}
fn default_clap_gain() -> f64 {
    0.8
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct FlashSection {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Scene time the flash starts, seconds.
    pub time: f64,
    /// Seconds the flash lasts.
    #[serde(default = "default_flash_duration")]
    pub duration: f64,
    /// Added brightness (fraction of the lit value) while the flash is on.
    #[serde(default = "one")]
    pub strength: f64,
    /// Rolling-shutter readout time (seconds from the first to the last row); 0 = global.
    #[serde(default)]
    pub readout: f64,
    /// Exposure time of one row, seconds (default: half a frame interval).
    pub shutter: Option<f64>,
}

fn default_flash_duration() -> f64 {
    0.004
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct NoiseSection {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Standard deviation of additive Gaussian sensor noise (full scale = 1).
    pub sigma: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct GroundTruthSection {
    /// Write `groundtruth/masks/camN/NNNNNN.png` (moving objects) for every video frame.
    pub masks: bool,
}

impl Default for GroundTruthSection {
    fn default() -> Self {
        Self { masks: true }
    }
}

// ---------------------------------------------------------------------------------------
// The validated scene.

/// One camera of the simulated rig, with its effects resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct SimCamera {
    pub camera: Camera,
    pub role: CameraRole,
    /// Scene time of frame 0 (offset + phase / fps) for video cameras; 0 for others.
    pub start_time: f64,
    pub offset: f64,
    pub phase: f64,
    pub exposure: f64,
    pub dropped: Vec<u32>,
    pub chapter_frames: Option<u32>,
}

/// What a camera is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraRole {
    Video,
    Heldout,
    Still,
}

/// A parsed and validated scene, ready for [`super::simulate`].
#[derive(Clone, Debug)]
pub struct Scene {
    pub(crate) file: SceneFile,
    /// Name used in error messages (the file path or the given origin).
    pub origin: String,
    pub cameras: Vec<SimCamera>,
}

impl Scene {
    /// Read and validate a scene file.
    pub fn from_file(path: &Path) -> Result<Scene, SimError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| SimError::ReadScene { path: path.to_path_buf(), source })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Parse and validate a scene from TOML text; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Scene, SimError> {
        let mut file: SceneFile = toml::from_str(text)
            .map_err(|e| SimError::Parse { origin: origin.to_string(), message: e.to_string() })?;
        file.scene.fps = exact_fps(file.scene.fps, origin)?;
        let cameras = validate(&file, origin)?;
        let scene = Scene { file, origin: origin.to_string(), cameras };
        super::check_views(&scene)?;
        Ok(scene)
    }

    pub fn name(&self) -> &str {
        &self.file.scene.name
    }
    pub fn duration(&self) -> f64 {
        self.file.scene.duration
    }
    pub fn fps(&self) -> f64 {
        self.file.scene.fps
    }
    pub fn seed(&self) -> u64 {
        self.file.scene.seed
    }
    /// Frames each video camera records (before drops): `round(duration · fps)`.
    pub fn frames_per_camera(&self) -> u32 {
        (self.duration() * self.fps()).round().max(1.0) as u32
    }
    pub fn video_cameras(&self) -> impl Iterator<Item = &SimCamera> {
        self.cameras.iter().filter(|c| c.role == CameraRole::Video)
    }
    /// Whether the held-out cameras are also filmed as videos (`[cameras] heldout_videos`).
    pub fn films_heldout(&self) -> bool {
        self.file.cameras.heldout_videos
    }
    /// The same scene with its held-out cameras filmed as videos (`raw/heldoutN/`) or not.
    pub fn with_heldout_videos(mut self, on: bool) -> Scene {
        self.file.cameras.heldout_videos = on;
        self
    }
    /// Whether the scene records audio (an `[audio]` table with `enabled = true`).
    pub fn audio_enabled(&self) -> bool {
        self.file.audio.as_ref().is_some_and(|a| a.enabled)
    }
}

/// The frame rate as the exact value the video files carry: an integer, or an NTSC rate
/// `N·1000/1001` (29.97 → 30000/1001).
fn exact_fps(fps: f64, origin: &str) -> Result<f64, SimError> {
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        return Err(SimError::invalid(
            origin,
            format!("[scene] fps = {fps} is not a frame rate; give a positive number such as 30"),
        ));
    }
    if (fps - fps.round()).abs() < 1e-9 {
        return Ok(fps.round());
    }
    let ntsc = (fps * 1.001).round();
    if (fps * 1.001 - ntsc).abs() < 2e-3 {
        return Ok(ntsc * 1000.0 / 1001.0);
    }
    Err(SimError::invalid(
        origin,
        format!("[scene] fps = {fps} must be an integer or an NTSC rate (e.g. 29.97 = 30000/1001)"),
    ))
}

fn finite(origin: &str, what: &str, values: &[f64]) -> Result<(), SimError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SimError::invalid(origin, format!("{what} must be finite numbers, got {values:?}")))
    }
}

fn validate(file: &SceneFile, origin: &str) -> Result<Vec<SimCamera>, SimError> {
    let s = &file.scene;
    if !(s.fps.is_finite() && s.fps > 0.0 && s.fps <= 1000.0) {
        return Err(SimError::invalid(
            origin,
            format!("[scene] fps = {} is not a frame rate; give a positive number such as 30", s.fps),
        ));
    }
    if !(s.duration.is_finite() && s.duration > 0.0 && s.duration <= 600.0) {
        return Err(SimError::invalid(
            origin,
            format!("[scene] duration = {} s must be positive (at most 600 s)", s.duration),
        ));
    }
    let r = &file.render;
    if !(1..=4).contains(&r.supersample) {
        return Err(SimError::invalid(origin, "[render] supersample must be 1, 2, 3 or 4"));
    }
    if !(16..=4096).contains(&r.texture_size) {
        return Err(SimError::invalid(origin, "[render] texture_size must be between 16 and 4096"));
    }
    finite(origin, "[render] light_direction", &r.light_direction)?;
    if DVec3::from_array(r.light_direction).length() < 1e-9 {
        return Err(SimError::invalid(origin, "[render] light_direction must not be zero"));
    }
    if file.encode.crf > 51 {
        return Err(SimError::invalid(origin, "[encode] crf must be in 0..=51"));
    }
    const PRESETS: [&str; 10] =
        ["ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow", "placebo"];
    if !PRESETS.contains(&file.encode.preset.as_str()) {
        return Err(SimError::invalid(
            origin,
            format!("[encode] preset = {:?} is not an x264 preset; use one of {PRESETS:?}", file.encode.preset),
        ));
    }
    let bg = &file.background;
    match bg.kind.as_str() {
        "room" => {
            if bg.size.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(SimError::invalid(origin, "[background] size must be three positive lengths"));
            }
        }
        "dome" => {
            if !(bg.radius.is_finite() && bg.radius > 0.0) {
                return Err(SimError::invalid(origin, "[background] radius must be positive"));
            }
        }
        "none" => {}
        other => {
            return Err(SimError::invalid(
                origin,
                format!("[background] kind = {other:?}; use \"room\", \"dome\" or \"none\""),
            ));
        }
    }
    validate_texture(origin, "[background] texture", &bg.texture)?;
    for (i, o) in file.objects.iter().enumerate() {
        let what = format!("[[objects]] #{i} ({})", if o.name.is_empty() { &o.shape } else { &o.name });
        validate_object(origin, &what, o)?;
    }

    let cams = &file.cameras;
    if cams.video.len() != VIDEO_CAMERAS {
        return Err(SimError::invalid(
            origin,
            format!(
                "the rig has {} video cameras ([[cameras.video]]); a capture needs exactly {VIDEO_CAMERAS}",
                cams.video.len()
            ),
        ));
    }
    let mut out = Vec::new();
    for (i, spec) in cams.video.iter().enumerate() {
        out.push(resolve_camera(file, origin, spec, format!("cam{i}"), CameraRole::Video)?);
    }
    for (i, spec) in cams.heldout.iter().enumerate() {
        out.push(resolve_camera(file, origin, spec, format!("heldout{i}"), CameraRole::Heldout)?);
    }
    let st = &file.stills;
    if st.count > 0 {
        finite(origin, "[stills]", &[st.radius, st.heights[0], st.heights[1], st.hfov, st.time, st.start_angle])?;
        if !(st.radius > 0.0) {
            return Err(SimError::invalid(origin, "[stills] radius must be positive"));
        }
        if !(1..=100).contains(&st.jpeg_quality) {
            return Err(SimError::invalid(origin, "[stills] jpeg_quality must be in 1..=100"));
        }
    }
    for i in 0..st.count {
        let a = (st.start_angle + 360.0 * i as f64 / st.count as f64).to_radians();
        let c = DVec3::from_array(st.center);
        let pos = c + DVec3::new(st.radius * a.cos(), st.radius * a.sin(), st.heights[(i % 2) as usize]);
        let spec = CameraSpec {
            position: pos.to_array(),
            look_at: st.look_at,
            width: Some(st.width),
            height: Some(st.height),
            hfov: Some(st.hfov),
            exposure: 1.0,
            ..Default::default()
        };
        out.push(resolve_camera(file, origin, &spec, format!("still_{i:02}"), CameraRole::Still)?);
    }
    if let Some(a) = &file.audio {
        finite(origin, "[audio]", &[a.noise, a.clap_time, a.clap_gain])?;
        finite(origin, "[audio] clap_position", &a.clap_position)?;
        if !(8000..=192_000).contains(&a.sample_rate) {
            return Err(SimError::invalid(origin, "[audio] sample_rate must be in 8000..=192000 Hz"));
        }
        if a.noise < 0.0 || a.clap_gain < 0.0 {
            return Err(SimError::invalid(origin, "[audio] noise and clap_gain must not be negative"));
        }
    }
    if let Some(f) = &file.flash {
        finite(origin, "[flash]", &[f.time, f.duration, f.strength, f.readout, f.shutter.unwrap_or(0.01)])?;
        if f.duration <= 0.0 || f.readout < 0.0 || f.shutter.is_some_and(|s| s <= 0.0) {
            return Err(SimError::invalid(
                origin,
                "[flash] duration and shutter must be positive, readout not negative",
            ));
        }
        if f.readout + f.shutter.unwrap_or(0.5 / s.fps) > 1.0 / s.fps + 1e-12 {
            return Err(SimError::invalid(
                origin,
                "[flash] readout + shutter must fit in one frame interval (1 / fps)",
            ));
        }
    }
    if let Some(n) = &file.noise
        && !(n.sigma.is_finite() && n.sigma >= 0.0) {
            return Err(SimError::invalid(origin, "[noise] sigma must be a non-negative number"));
        }
    Ok(out)
}

fn validate_texture(origin: &str, what: &str, t: &TextureSpec) -> Result<(), SimError> {
    if !["mix", "noise", "checker", "glyphs", "solid"].contains(&t.kind.as_str()) {
        return Err(SimError::invalid(
            origin,
            format!("{what}: kind = {:?}; use mix, noise, checker, glyphs or solid", t.kind),
        ));
    }
    if !(t.tile.is_finite() && t.tile > 0.0) {
        return Err(SimError::invalid(origin, format!("{what}: tile must be a positive length in metres")));
    }
    if !(1..=64).contains(&t.cells) {
        return Err(SimError::invalid(origin, format!("{what}: cells must be in 1..=64")));
    }
    finite(origin, what, t.colors.as_flattened())
}

fn validate_object(origin: &str, what: &str, o: &ObjectSection) -> Result<(), SimError> {
    finite(origin, &format!("{what} size/radius/height"), &[o.size[0], o.size[1], o.size[2], o.radius, o.height])?;
    finite(origin, &format!("{what} position"), &o.position)?;
    finite(origin, &format!("{what} rotation"), &o.rotation)?;
    if !(1..=256).contains(&o.segments) {
        return Err(SimError::invalid(origin, format!("{what}: segments must be in 1..=256")));
    }
    match o.shape.as_str() {
        "box" | "plane" => {
            let n = if o.shape == "box" { 3 } else { 2 };
            if o.size[..n].iter().any(|v| *v <= 0.0) {
                return Err(SimError::invalid(origin, format!("{what}: size must be positive")));
            }
        }
        "sphere" | "cylinder" => {
            if o.radius <= 0.0 || (o.shape == "cylinder" && o.height <= 0.0) {
                return Err(SimError::invalid(origin, format!("{what}: radius and height must be positive")));
            }
        }
        "mesh" => {
            if o.vertices.is_empty() || o.triangles.is_empty() {
                return Err(SimError::invalid(origin, format!("{what}: a mesh needs vertices and triangles")));
            }
            if let Some(bad) = o.triangles.iter().flatten().find(|&&i| i as usize >= o.vertices.len()) {
                return Err(SimError::invalid(
                    origin,
                    format!("{what}: triangle index {bad} but only {} vertices", o.vertices.len()),
                ));
            }
            if !o.uvs.is_empty() && o.uvs.len() != o.vertices.len() {
                return Err(SimError::invalid(origin, format!("{what}: give one uv per vertex or none")));
            }
            finite(origin, &format!("{what} vertices"), o.vertices.as_flattened())?;
        }
        other => {
            return Err(SimError::invalid(
                origin,
                format!("{what}: shape = {other:?}; use box, sphere, plane, cylinder or mesh"),
            ));
        }
    }
    validate_texture(origin, &format!("{what} texture"), &o.texture)?;
    let mut last = f64::NEG_INFINITY;
    for k in &o.keyframes {
        finite(origin, &format!("{what} keyframe"), &[k.t, k.position[0], k.position[1], k.position[2]])?;
        finite(origin, &format!("{what} keyframe rotation"), &k.rotation)?;
        if k.t <= last {
            return Err(SimError::invalid(origin, format!("{what}: keyframe times must increase")));
        }
        last = k.t;
    }
    if let Some(d) = &o.deform {
        finite(origin, &format!("{what} deform"), &[d.amplitude, d.wavelength, d.frequency])?;
        if d.wavelength <= 0.0 {
            return Err(SimError::invalid(origin, format!("{what}: deform wavelength must be positive")));
        }
    }
    Ok(())
}

fn resolve_camera(
    file: &SceneFile,
    origin: &str,
    spec: &CameraSpec,
    name: String,
    role: CameraRole,
) -> Result<SimCamera, SimError> {
    let defaults = &file.cameras;
    let fps = file.scene.fps;
    finite(origin, &format!("camera {name} position"), &spec.position)?;
    finite(origin, &format!("camera {name} look_at"), &spec.look_at)?;
    finite(origin, &format!("camera {name}"), &[spec.offset, spec.phase, spec.exposure])?;
    let width = spec.width.unwrap_or(defaults.width);
    let height = spec.height.unwrap_or(defaults.height);
    if width < 16 || height < 16 || width > 8192 || height > 8192 || !width.is_multiple_of(2) || !height.is_multiple_of(2) {
        return Err(SimError::invalid(
            origin,
            format!("camera {name}: resolution {width}×{height} must be even and between 16 and 8192 pixels"),
        ));
    }
    let intrinsics = match (spec.focal, spec.hfov) {
        (Some(_), Some(_)) => {
            return Err(SimError::invalid(origin, format!("camera {name}: give either focal or hfov, not both")));
        }
        (Some(f), None) => {
            if !(f.is_finite() && f > 0.0) {
                return Err(SimError::invalid(origin, format!("camera {name}: focal must be positive pixels")));
            }
            Intrinsics { width, height, fx: f, fy: f, cx: 0.5 * width as f64, cy: 0.5 * height as f64 }
        }
        (None, hfov) => {
            let h = hfov.unwrap_or(defaults.hfov);
            if !(h.is_finite() && h > 1.0 && h < 170.0) {
                return Err(SimError::invalid(origin, format!("camera {name}: hfov = {h} must be in (1, 170) degrees")));
            }
            Intrinsics::from_hfov(width, height, h)
        }
    };
    let eye = DVec3::from_array(spec.position);
    let target = DVec3::from_array(spec.look_at);
    if (target - eye).length() < 1e-9 {
        return Err(SimError::invalid(
            origin,
            format!("camera {name} looks at nothing: look_at equals its position {:?}", spec.position),
        ));
    }
    let world_to_camera = WorldToCamera::look_at(eye, target, DVec3::Z).ok_or_else(|| {
        SimError::invalid(
            origin,
            format!("camera {name} looks straight up or down (world z is up); tilt its look_at a little"),
        )
    })?;
    validate_distortion(origin, &name, &spec.distortion, &intrinsics)?;
    if !(0.0..1.0).contains(&spec.phase) {
        return Err(SimError::invalid(origin, format!("camera {name}: phase must be in [0, 1) frames")));
    }
    if !(spec.exposure > 0.0) {
        return Err(SimError::invalid(origin, format!("camera {name}: exposure must be positive")));
    }
    let frames = (file.scene.duration * fps).round().max(1.0) as u32;
    if role != CameraRole::Video
        && (spec.offset != 0.0 || spec.phase != 0.0 || !spec.dropped.is_empty() || spec.chapter_frames.is_some())
    {
        return Err(SimError::invalid(
            origin,
            format!("camera {name}: offset, phase, dropped and chapter_frames apply to video cameras only"),
        ));
    }
    let mut dropped = spec.dropped.clone();
    dropped.sort_unstable();
    dropped.dedup();
    if let Some(&bad) = dropped.iter().find(|&&d| d == 0 || d >= frames) {
        return Err(SimError::invalid(
            origin,
            format!("camera {name}: dropped frame {bad} must be in 1..{frames} (frame 0 starts the file)"),
        ));
    }
    if let Some(c) = spec.chapter_frames
        && (c == 0 || frames.div_ceil(c) > 99) {
            return Err(SimError::invalid(origin, format!("camera {name}: chapter_frames must give 1..=99 chapters")));
        }
    let start_time = spec.offset + spec.phase / fps;
    Ok(SimCamera {
        camera: Camera { name, intrinsics, distortion: spec.distortion, world_to_camera },
        role,
        start_time,
        offset: spec.offset,
        phase: spec.phase,
        exposure: spec.exposure,
        dropped,
        chapter_frames: spec.chapter_frames,
    })
}

/// The distortion must be finite and invertible over the whole image: undistorting each
/// border pixel and distorting it again must come back within 1e-3 px.
fn validate_distortion(origin: &str, name: &str, d: &Distortion, k: &Intrinsics) -> Result<(), SimError> {
    let values: Vec<f64> = match *d {
        Distortion::None => return Ok(()),
        Distortion::Opencv { k1, k2, p1, p2, k3 } => vec![k1, k2, p1, p2, k3],
        Distortion::Fisheye { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
    };
    finite(origin, &format!("camera {name} distortion"), &values)?;
    for p in super::lens::border_pixels(k.width, k.height, 8) {
        let n = d.undistort(k.to_normalised(p));
        let back = k.to_pixels(d.distort(n));
        if !(n.is_finite() && (back - p).length() < 1e-3) || !radially_monotonic(d, n) {
            return Err(SimError::invalid(
                origin,
                format!(
                    "camera {name}: distortion {d:?} cannot be inverted at pixel ({:.0}, {:.0}); \
                     use smaller coefficients",
                    p.x, p.y
                ),
            ));
        }
    }
    Ok(())
}

/// Whether distortion keeps growing outwards up to `n` (no fold-back inside the image).
fn radially_monotonic(d: &Distortion, n: DVec2) -> bool {
    let mut last = 0.0;
    for i in 1..=32 {
        let r = d.distort(n * (i as f64 / 32.0)).length();
        if r <= last {
            return false;
        }
        last = r;
    }
    true
}

/// Rigid pose of an object at scene time `t`: keyframes interpolated linearly (position)
/// and by slerp (rotation), held constant before the first and after the last.
pub(crate) fn object_pose(o: &ObjectSection, t: f64) -> (DQuat, DVec3) {
    let quat = |r: [f64; 3]| {
        DQuat::from_rotation_z(r[2].to_radians())
            * DQuat::from_rotation_y(r[1].to_radians())
            * DQuat::from_rotation_x(r[0].to_radians())
    };
    let k = &o.keyframes;
    if k.is_empty() {
        return (quat(o.rotation), DVec3::from_array(o.position));
    }
    if t <= k[0].t {
        return (quat(k[0].rotation), DVec3::from_array(k[0].position));
    }
    for w in k.windows(2) {
        if t <= w[1].t {
            let s = (t - w[0].t) / (w[1].t - w[0].t);
            let p = DVec3::from_array(w[0].position).lerp(DVec3::from_array(w[1].position), s);
            return (quat(w[0].rotation).slerp(quat(w[1].rotation), s), p);
        }
    }
    let last = k[k.len() - 1];
    (quat(last.rotation), DVec3::from_array(last.position))
}
