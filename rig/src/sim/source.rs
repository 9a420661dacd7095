//! The simulator's video cameras as live [`CameraSource`]s: frames are rendered on demand,
//! with the camera's sensor effects, and stamped on one clock every camera of the scene
//! shares (as V4L2 kernel timestamps are shared by cameras on one machine): scene time
//! minus [`SimSource::origin`], the earliest video camera's start, so no time is negative.
//! [`super::simulate`] renders its video files through the same [`SimSource::shot`].

use super::lens::LensPlan;
use super::raster::Rendered;
use super::{CameraRole, Scene, SimError, World, lens_plan, sensor};
#[cfg(feature = "ffmpeg")]
use crate::source::{CameraSource, Frame, PixelLayout, SourceError};

/// One video camera of a simulated scene, frame after frame (dropped frames are skipped).
pub struct SimSource {
    world: World,
    /// Index of the camera in `scene.cameras`.
    camera: usize,
    plan: LensPlan,
    /// Next camera frame index to render.
    next: u32,
    /// Frames delivered so far.
    delivered: usize,
    /// [`SimSource::origin`] of the scene.
    origin: f64,
}

/// One rendered video frame: scene time, the clean render (depth and mesh ids for the
/// ground truth) and the RGB8 the sensor recorded.
pub(crate) struct Shot {
    pub t: f64,
    pub img: Rendered,
    pub rgb: Vec<u8>,
}

impl SimSource {
    /// Scene time of the recording clock's zero: the earliest video camera's frame 0.
    pub fn origin(scene: &Scene) -> f64 {
        scene
            .video_cameras()
            .map(|c| c.start_time)
            .fold(f64::INFINITY, f64::min)
            .min(0.0)
    }

    /// Every video camera of `scene`, in scene order, sharing one copy of its geometry.
    pub fn video_cameras(scene: &Scene) -> Result<Vec<SimSource>, SimError> {
        let world = World::new(scene);
        scene
            .cameras
            .iter()
            .enumerate()
            .filter(|(_, c)| c.role == CameraRole::Video)
            .map(|(i, _)| SimSource::in_world(world.clone(), i))
            .collect()
    }

    pub(crate) fn in_world(world: World, camera: usize) -> Result<SimSource, SimError> {
        let plan = lens_plan(&world.scene, &world.scene.cameras[camera])?;
        let origin = SimSource::origin(&world.scene);
        Ok(SimSource {
            world,
            camera,
            plan,
            next: 0,
            delivered: 0,
            origin,
        })
    }

    /// Camera frame `frame` (its scene time is `start_time + frame / fps`), or `None` when
    /// the camera drops it or the scene has ended.
    pub(crate) fn shot(&self, frame: u32) -> Option<Shot> {
        let scene = &self.world.scene;
        let cam = &scene.cameras[self.camera];
        if frame >= scene.frames_per_camera() || cam.dropped.contains(&frame) {
            return None;
        }
        let t = cam.start_time + frame as f64 / scene.fps();
        let img = self.world.render(&self.plan, t);
        let rgb = sensor(scene, cam, self.camera, frame, t, &img);
        Some(Shot { t, img, rgb })
    }
}

#[cfg(feature = "ffmpeg")]
impl CameraSource for SimSource {
    fn name(&self) -> &str {
        &self.world.scene.cameras[self.camera].camera.name
    }

    fn frame_size(&self) -> (u32, u32) {
        let k = self.world.scene.cameras[self.camera].camera.intrinsics;
        (k.width, k.height)
    }

    fn nominal_fps(&self) -> Option<f64> {
        Some(self.world.scene.fps())
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        while self.next < self.world.scene.frames_per_camera() {
            let frame = self.next;
            self.next += 1;
            if let Some(shot) = self.shot(frame) {
                let (width, height) = self.frame_size();
                self.delivered += 1;
                return Ok(Some(Frame {
                    index: self.delivered - 1,
                    timestamp: shot.t - self.origin,
                    width,
                    height,
                    layout: PixelLayout::Rgb8,
                    data: shot.rgb,
                }));
            }
        }
        Ok(None)
    }
}
