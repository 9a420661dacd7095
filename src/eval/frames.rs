//! Rendering a camera path (from `crate::trajectories`) to numbered PNG frames: colour, depth
//! through a colour map, alpha; optionally handing each colour frame to a sink (an MP4
//! writer in the `pipeline` crate).

use std::path::{Path, PathBuf};

use image::RgbImage;

use super::EvalError;
use super::images::{alpha8, depth_colour, depth_range, rgb8, write_png};
use crate::camera::Camera;
use crate::model::Gaussians;
use crate::progress::Progress;
use crate::render::backdrop::Backdrop;
use crate::render::{RenderBackend, RenderOptions};

/// Which images to write for every frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameOutputs {
    /// `rgb/NNNNNN.png`.
    pub rgb: bool,
    /// `depth/NNNNNN.png`, expected depth through the turbo map (near red, far blue).
    pub depth: bool,
    /// `alpha/NNNNNN.png`, accumulated opacity in grey.
    pub alpha: bool,
}

impl FrameOutputs {
    /// Colour, depth and alpha.
    pub const ALL: Self = Self {
        rgb: true,
        depth: true,
        alpha: true,
    };
    /// Nothing on disk (frames go only to the sink).
    pub const NONE: Self = Self {
        rgb: false,
        depth: false,
        alpha: false,
    };
}

/// Receives each colour frame in order (e.g. to encode a video). An `Err` stops the render.
pub type FrameSink<'a> = &'a mut dyn FnMut(usize, &RgbImage) -> Result<(), String>;

/// What [`render_path`] produced.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedPath {
    /// Frames rendered.
    pub frames: usize,
    /// Folders written (`rgb`, `depth`, `alpha` under the output folder).
    pub folders: Vec<PathBuf>,
    /// Depth (near, far) mapped to the ends of the colour map, taken from the first frame
    /// that covers any pixel; `None` when no depth was written or nothing was covered.
    pub depth_range: Option<(f32, f32)>,
}

/// Render every `(camera, model time)` of `path` on `background` (or the learned
/// `backdrop` the model was trained on) into `out_dir`
/// (`rgb/`, `depth/`, `alpha/` as asked, frames `000000.png`, …), giving each colour
/// frame to `sink` when there is one. Each PNG is written under a temporary name first.
#[allow(clippy::too_many_arguments)]
pub fn render_path(
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    path: &[(Camera, f64)],
    out_dir: &Path,
    outputs: FrameOutputs,
    background: [f32; 3],
    backdrop: Option<&Backdrop>,
    progress: &dyn Progress,
    mut sink: Option<FrameSink<'_>>,
) -> Result<RenderedPath, EvalError> {
    let options = RenderOptions {
        background: if backdrop.is_some() {
            [0.0; 3]
        } else {
            background
        },
        ..RenderOptions::default()
    };
    let mut folders = Vec::new();
    for (wanted, name) in [
        (outputs.rgb, "rgb"),
        (outputs.depth, "depth"),
        (outputs.alpha, "alpha"),
    ] {
        if wanted {
            let dir = out_dir.join(name);
            std::fs::create_dir_all(&dir).map_err(|source| EvalError::Write {
                path: dir.clone(),
                source,
            })?;
            folders.push(dir);
        }
    }
    progress.start(path.len() as u64, "frames");
    let mut range = None;
    for (i, (camera, t)) in path.iter().enumerate() {
        let mut r = backend
            .render(model, camera, *t as f32, &options)
            .map_err(|source| EvalError::Render {
                view: format!("frame {i} ({})", camera.name),
                source,
            })?;
        if let Some(b) = backdrop {
            b.draw(camera, &mut r);
        }
        let name = format!("{i:06}.png");
        let colour = rgb8(&r);
        if outputs.rgb {
            write_png(&out_dir.join("rgb").join(&name), &colour)?;
        }
        if outputs.depth {
            if range.is_none() {
                range = depth_range(&r);
            }
            // Until some frame covers a pixel, every depth image is black.
            let img = depth_colour(&r, range.unwrap_or((0.0, 1.0)));
            write_png(&out_dir.join("depth").join(&name), &img)?;
        }
        if outputs.alpha {
            write_png(&out_dir.join("alpha").join(&name), &alpha8(&r))?;
        }
        if let Some(sink) = sink.as_mut() {
            sink(i, &colour).map_err(|message| EvalError::Sink { frame: i, message })?;
        }
        progress.advance(1);
    }
    progress.finish();
    Ok(RenderedPath {
        frames: path.len(),
        folders,
        depth_range: range,
    })
}
