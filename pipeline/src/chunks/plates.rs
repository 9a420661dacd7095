//! The static scene refined on the whole clip. Every camera stands still, so the per-pixel
//! median of its frames spread over the clip (its static plate) is what it sees when
//! nothing moves: a view of the static scene at every moment. The first chunk sees a wall
//! only where nothing stood in front of it during its own seconds; trained a few hundred
//! steps more on the plates, alone and only in its opacities, the frozen static scene also
//! holds what the rest of the clip shows of it (the wall behind where someone stood at the
//! start), and loses what moved but stood still long enough to be frozen with it.

use std::path::Path;

use anyhow::Context;
use image::RgbImage;
use rayon::prelude::*;
use rig::frames::FramesIndex;
use shared_types::Progress;
use splat4d::train::{Background, Dataset, ImageU8, TrainConfig, View};

use crate::engine_inputs::{load_frame, pinhole_cameras, time_mapping};

/// Frames per camera whose median is its plate, spread evenly over the clip (a person who
/// keeps moving covers a pixel in fewer than half of them).
pub const PLATE_FRAMES: usize = 32;

/// Each training camera's static plate of the clip in `frames_dir` as a training view at
/// model time `time` (undistorted to its pinhole camera, like the training frames). A
/// camera's frames are read, reduced and dropped before the next camera's, so memory holds
/// [`PLATE_FRAMES`] frames of one camera, whatever the clip's length.
pub fn plate_views(
    frames_dir: &Path,
    cameras_file: &Path,
    time: f32,
    progress: &dyn Progress,
) -> anyhow::Result<Dataset> {
    let index = FramesIndex::read_json(&frames_dir.join("frames.json"))?;
    let poses = calib::poses::PosesFile::read(cameras_file)?;
    let cameras = pinhole_cameras(&index, &poses.set, cameras_file)?;
    let picked = crate::stages::init::moment_frames(index.frames.len(), PLATE_FRAMES);
    progress.start((cameras.len() * picked.len()) as u64, "images");
    let mut views = Vec::with_capacity(cameras.len());
    for (c, (camera, map)) in cameras.iter().enumerate() {
        let frames = picked
            .par_iter()
            .map(|&f| {
                let file = &index.frames[f].views[c].file;
                let image = load_frame(&frames_dir.join(file), map.as_ref())?;
                progress.advance(1);
                RgbImage::from_raw(image.width, image.height, image.data)
                    .context("a frame's pixels do not match its size")
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let plate = pointinit::plates::median_plate(&frames);
        let (width, height) = plate.dimensions();
        let image = ImageU8 {
            width,
            height,
            data: plate.into_raw(),
        };
        views.push(View::at_image_size(camera.clone(), time, image));
    }
    progress.finish();
    Ok(Dataset {
        views,
        time_mapping: time_mapping(&index),
    })
}

/// The schedule that refines the static scene on its plates: `steps` iterations of the
/// chunks' `settings` on the first chunk's background colour, every colour degree from the
/// start, no densification or opacity reset, and only the opacities learning. A wall the
/// first chunk never saw becomes opaque and what was frozen but is not in the plates
/// fades; colours, shapes and positions fitted to four plates alone turn into a fog that
/// fits each plate from its own camera and no other (held out on the minute-long demo
/// clip cut to 10 s: 15.69 dB training everything, 18.04 dB the opacities, 17.67 dB
/// without the steps).
pub fn refine_config(settings: &TrainConfig, steps: u64, background: [f32; 3]) -> TrainConfig {
    let mut config = settings.clone();
    config.iterations = steps;
    config.background = Background::Colour(background);
    config.degree_every = 0;
    config.densify.enabled = false;
    let opacity = config.lr.opacity;
    config.lr = splat4d::train::optim::LearningRates {
        position_init: 0.0,
        position_final: 0.0,
        time: 0.0,
        colour_dc: 0.0,
        colour_rest: 0.0,
        scale: 0.0,
        rotation: 0.0,
        opacity,
        ..config.lr
    };
    config.checkpoint_every = config.checkpoint_every.min(steps.div_ceil(2)).max(1);
    config
}
