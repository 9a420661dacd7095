//! The learned backdrop (`[train] background = "learned"`), fitted once the Gaussians are
//! trained (on the mean colour): each step renders one training view, drawn at random, of
//! the frozen model on black, composites the backdrop where transmittance remains, and
//! moves the backdrop's texels by Adam along the training loss's gradient. The fitted
//! pyramid is then baked faded where fewer than two training cameras saw it
//! ([`fade_unseen`]).
//!
//! After training rather than with it: learned alongside the Gaussians, the backdrop
//! takes over walls the Gaussians should draw (a simulated room lost 2.6 dB, and the later
//! the backdrop started learning the less it lost), and the GPU's whole-iteration step
//! would have to fit it too (BENCHMARKS.md, "A learned backdrop").

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

use crate::Progress;
use crate::model::Gaussians;
use crate::model::init::PointCloud;
use crate::render::backdrop::{Backdrop, BackdropAdam, Coverage, UvCache, composite};
use crate::render::{RenderBackend, RenderError, RenderOptions};
use crate::train::Dataset;
use crate::train::loss::image_loss;

/// Adam's learning rate of the texels (colour units per step) at the fit's first step,
/// and at its last: it falls exponentially between, so the texels settle rather than
/// follow the last few views drawn (basketball's held-out LPIPS varied 0.302–0.308 over
/// three seeds at a constant 0.01, 0.296–0.297 with the fall).
const FIT_LR: [f32; 2] = [0.01, 0.001];

/// The fit's steps: one training view each; a run of fewer training steps fits for as many
/// as it trained, so a quick run stays quick.
const FIT_STEPS: usize = 500;

/// Training views rendered to measure the backdrop's coverage (evenly spread over the
/// dataset's views, which run camera by camera through the frames).
const COVERAGE_VIEWS: usize = 64;

/// What the fit needs of the training config.
pub(crate) struct FitSettings {
    /// The training loss's SSIM weight.
    pub lambda_ssim: f64,
    pub seed: u64,
    /// The run's training steps: the fit takes as many, at most [`FIT_STEPS`].
    pub iterations: usize,
}

impl FitSettings {
    fn steps(&self) -> usize {
        self.iterations.clamp(1, FIT_STEPS)
    }
}

/// The backdrop to fit, `colour` everywhere: a sphere around `dataset`'s cameras at the far
/// quantile of `init`'s static points (every point when the cloud does not say which are
/// static) with `size` texels around its finest level. `None` when the cameras look at no
/// common point.
pub(crate) fn sphere(
    dataset: &Dataset,
    init: &PointCloud,
    colour: [f32; 3],
    size: usize,
) -> Option<Backdrop> {
    let cameras = dataset.cameras();
    let static_points: Vec<[f32; 3]> = match &init.time_span {
        Some(span) => init
            .xyz
            .iter()
            .zip(span)
            .filter(|(_, s)| **s > 0.0)
            .map(|(p, _)| *p)
            .collect(),
        None => init.xyz.clone(),
    };
    Backdrop::around(&cameras, &static_points, colour, size)
}

/// `backdrop` ([`sphere`]) fitted behind `model` (trained on `colour`) for
/// [`FitSettings::steps`] steps and baked faded to `colour` where the training views did not see it.
pub(crate) fn learn_backdrop(
    mut backdrop: Backdrop,
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    dataset: &Dataset,
    colour: [f32; 3],
    settings: &FitSettings,
    progress: &dyn Progress,
) -> Result<Backdrop, (usize, RenderError)> {
    let mut uvs = UvCache::default();
    progress.start(settings.steps() as u64, "view");
    progress.message("fitting the backdrop behind the trained Gaussians");
    fit_behind(
        &mut backdrop,
        &mut uvs,
        backend,
        model,
        dataset,
        settings,
        progress,
    )?;
    progress.message("fading the backdrop where no training view sees it");
    let faded = fade_unseen(&backdrop, &mut uvs, backend, model, dataset, colour)?;
    progress.finish();
    Ok(faded)
}

/// [`FitSettings::steps`] Adam steps of `backdrop`'s texels behind `model`'s frozen Gaussians, each
/// on one training view drawn at random (seeded by `settings.seed`).
fn fit_behind(
    backdrop: &mut Backdrop,
    uvs: &mut UvCache,
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    dataset: &Dataset,
    settings: &FitSettings,
    progress: &dyn Progress,
) -> Result<(), (usize, RenderError)> {
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut adam = BackdropAdam::new(backdrop, FIT_LR[0]);
    let mut grads = backdrop.zero_grads();
    let (mut target, mut d_image, mut d_alpha) = (Vec::new(), Vec::new(), Vec::new());
    let options = RenderOptions {
        background: [0.0; 3],
        ..Default::default()
    };
    let n = dataset.views.len() as u64;
    let steps = settings.steps();
    for step in 0..steps {
        adam.lr = FIT_LR[0] * (FIT_LR[1] / FIT_LR[0]).powf(step as f32 / steps as f32);
        let index = (rng.next_u64() % n) as usize;
        let view = &dataset.views[index];
        let mut r = backend
            .render(model, &view.camera, view.time, &options)
            .map_err(|e| (index, e))?;
        let pixel_uvs = uvs.get(backdrop, &view.camera);
        let behind = backdrop.colours(&pixel_uvs);
        composite(&behind, &mut r.rgb, &r.alpha);
        view.image.to_f32_into(&mut target);
        d_image.clear();
        d_image.resize(target.len(), 0.0);
        let (w, h) = (r.width as usize, r.height as usize);
        image_loss(
            &r.rgb,
            &target,
            w,
            h,
            settings.lambda_ssim,
            Some(&mut d_image),
        );
        backdrop.composite_backward(
            &pixel_uvs,
            &behind,
            &r.alpha,
            &d_image,
            &mut d_alpha,
            &mut grads,
        );
        adam.apply(backdrop, &grads);
        grads
            .iter_mut()
            .for_each(|l| l.iter_mut().for_each(|g| *g = [0.0; 3]));
        progress.advance(1);
    }
    Ok(())
}

/// The fitted `backdrop` faded to `colour` where no training view sees it past `model`'s
/// Gaussians ([`Backdrop::faded`]), coverage measured on up to [`COVERAGE_VIEWS`] views of
/// `dataset` on a grid an eighth of the finest level's width (16 to 128 cells around).
fn fade_unseen(
    backdrop: &Backdrop,
    uvs: &mut UvCache,
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    dataset: &Dataset,
    colour: [f32; 3],
) -> Result<Backdrop, (usize, RenderError)> {
    let finest = backdrop.levels.last().map_or(16, |l| l.width);
    let mut coverage = Coverage::new((finest / 8).clamp(16, 128));
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
