//! The learned backdrop while training (`[train] background = "learned"`): each view is
//! rendered on black, the backdrop composited where transmittance remains, and the loss's
//! gradient split between the render's alpha and the backdrop's texels, which take an Adam
//! step with the Gaussians every iteration. Training ends by baking it faded where the
//! training views did not see it ([`fade_unseen`]).

use std::path::{Path, PathBuf};

use crate::Camera;
use crate::model::Gaussians;
use crate::render::backdrop::{
    Backdrop, BackdropAdam, BackdropFileError, Coverage, Level, UvCache, composite, load_backdrop,
    save_backdrop,
};
use crate::render::{RenderBackend, RenderError, RenderOptions, Rendered};
use crate::train::Dataset;

/// Adam's learning rate of the texels (colour units per step).
pub const BACKDROP_LR: f32 = 0.01;

/// A backdrop, its optimiser, and per camera (and size) the pixels' texture coordinates.
pub(crate) struct BackdropFit {
    pub backdrop: Backdrop,
    pub adam: BackdropAdam,
    uvs: UvCache,
    grads: Vec<Vec<[f32; 3]>>,
    d_alpha: Vec<f32>,
    /// The backdrop's colours behind the last composited view, for its backward.
    behind: Vec<[f32; 3]>,
}

impl BackdropFit {
    pub fn new(backdrop: Backdrop, adam: BackdropAdam) -> Self {
        Self {
            grads: backdrop.zero_grads(),
            backdrop,
            adam,
            uvs: UvCache::default(),
            d_alpha: Vec::new(),
            behind: Vec::new(),
        }
    }

    /// Composite the backdrop into `frame` (rendered on black from `camera`).
    pub fn composite(&mut self, camera: &Camera, frame: &mut Rendered<f32>) {
        let uvs = self.uvs.get(&self.backdrop, camera);
        self.behind = self.backdrop.colours(&uvs);
        composite(&self.behind, &mut frame.rgb, &frame.alpha);
    }

    /// From dL/d(composited colour) of `frame` (the view last composited): add the texels' gradient, and return
    /// dL/d(alpha) for the render's backward.
    pub fn backward(&mut self, camera: &Camera, frame: &Rendered<f32>, d_rgb: &[f32]) -> &[f32] {
        let uvs = self.uvs.get(&self.backdrop, camera);
        self.backdrop.composite_backward(
            &uvs,
            &self.behind,
            &frame.alpha,
            d_rgb,
            &mut self.d_alpha,
            &mut self.grads,
        );
        &self.d_alpha
    }

    /// Adam on the gathered gradient, which is then cleared.
    pub fn step(&mut self) {
        self.adam.apply(&mut self.backdrop, &self.grads);
        self.grads
            .iter_mut()
            .for_each(|l| l.iter_mut().for_each(|g| *g = [0.0; 3]));
    }
}

/// Training views rendered to measure the backdrop's coverage (evenly spread over the
/// dataset's views, which run camera by camera through the frames).
const COVERAGE_VIEWS: usize = 64;

/// The trained `backdrop` faded to `colour` where no training view sees it past `model`'s
/// Gaussians ([`Backdrop::faded`]), coverage measured on up to [`COVERAGE_VIEWS`] views of
/// `dataset` on a grid an eighth of the finest level's width (16 to 128 cells around).
pub(crate) fn fade_unseen(
    backdrop: &Backdrop,
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    dataset: &Dataset,
    colour: [f32; 3],
) -> Result<Backdrop, (usize, RenderError)> {
    let finest = backdrop.levels.last().map_or(16, |l| l.width);
    let mut coverage = Coverage::new((finest / 8).clamp(16, 128));
    let mut uvs = UvCache::default();
    let n = dataset.views.len();
    let stride = n.div_ceil(COVERAGE_VIEWS).max(1);
    let options = RenderOptions {
        background: [0.0; 3],
        ..Default::default()
    };
    for index in (0..n).step_by(stride) {
        let view = &dataset.views[index];
        let r = backend
            .render(model, &view.camera, view.time, &options)
            .map_err(|e| (index, e))?;
        coverage.add(
            &view.camera.name,
            &uvs.get(backdrop, &view.camera),
            &r.alpha,
        );
    }
    Ok(backdrop.faded(&coverage, colour))
}

/// A backdrop with its Adam moments in one file (a checkpoint's `NNNNNN.backdrop`): the
/// backdrop file of the texels' levels followed by the first and then the second moments'.
pub(crate) fn save_state(fit: &BackdropFit, path: &Path) -> Result<(), BackdropFileError> {
    let mut all = fit.backdrop.clone();
    for moments in [&fit.adam.m, &fit.adam.v] {
        all.levels
            .extend(fit.backdrop.levels.iter().zip(moments).map(|(l, m)| Level {
                width: l.width,
                texels: m.clone(),
            }));
    }
    save_backdrop(&all, path)
}

/// Read what [`save_state`] wrote; the optimiser resumes at `step`.
pub(crate) fn load_state(path: &Path, step: u32) -> Result<BackdropFit, BackdropFileError> {
    let mut all = load_backdrop(path)?;
    let n = all.levels.len();
    if n % 3 != 0 {
        return Err(BackdropFileError::Corrupt {
            path: PathBuf::from(path),
            reason: format!("{n} levels, not texels and two moments"),
        });
    }
    let v: Vec<_> = all
        .levels
        .split_off(2 * n / 3)
        .into_iter()
        .map(|l| l.texels)
        .collect();
    let m: Vec<_> = all
        .levels
        .split_off(n / 3)
        .into_iter()
        .map(|l| l.texels)
        .collect();
    let adam = BackdropAdam {
        m,
        v,
        step,
        lr: BACKDROP_LR,
    };
    Ok(BackdropFit::new(all, adam))
}
