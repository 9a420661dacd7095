//! The scene file's types: its TOML schema as written (every table rejects unknown keys)
//! with the defaults of omitted keys, and the cameras validation resolves it into
//! ([`SimCamera`], [`CameraRole`]). A leaf: it imports nothing from the simulator, so every
//! part of it (validation, animation, meshes, textures) may use these types.
//!
//! Each field's doc says what its key means; `docs/simulator.md` describes the same format
//! for users, key by key: keep the two in step.
//!
//! World convention: metres, z up, cameras in the OpenCV convention of `shared_types::camera`.

use serde::Deserialize;
use shared_types::{Camera, Distortion};

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
        Self {
            crf: 18,
            preset: "fast".into(),
        }
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
        Self {
            kind: "mix".into(),
            tile: 1.0,
            colors: [[0.15, 0.2, 0.3], [0.9, 0.85, 0.7]],
            cells: 8,
            seed: 0,
        }
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
// The resolved cameras.

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
