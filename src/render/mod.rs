//! The rendering API every backend implements: [`RenderBackend`] renders a batch of views
//! of a model and runs the backward pass from image gradients; [`Rendered`] is one frame
//! (public images plus the backend's own state for its backward); [`Gradients`] are laid
//! out like the model so an optimiser can step each group.
//!
//! Backends: [`cpu`] (rayon over Gaussians and 16×16 tiles, generic over `f32`/`f64`), the
//! one every other backend is checked against, and [`reference`], a slow per-pixel `f64`
//! renderer that is the oracle for the CPU one. All follow the per-Gaussian math in
//! [`crate::math`] (slice → colour → project) and the blending rules of [`cpu::blend`].

pub mod backdrop;
pub mod cpu;
pub mod gpu;
pub mod reference;

use crate::Camera;
use crate::math::numerics::Real;
use crate::math::project::PinholeCamera;
use crate::model::Gaussians;
use std::any::Any;
use std::sync::Arc;

pub use cpu::CpuBackend;

/// Why a render (or its backward) was refused.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "camera '{camera}' has lens distortion; the renderer only draws pinhole images — undistort the frames and use the undistorted camera"
    )]
    DistortedCamera { camera: String },
    #[error("camera '{camera}' has an empty image ({width}×{height}); give it a positive size")]
    EmptyImage {
        camera: String,
        width: u32,
        height: u32,
    },
    #[error("camera '{camera}' has non-finite or non-positive focal lengths; check its intrinsics")]
    BadIntrinsics { camera: String },
    #[error("the model is inconsistent: {0}")]
    InconsistentModel(String),
    #[error("opacity factor has {got} values but the model has {expected} Gaussians")]
    OpacityFactorLength { expected: usize, got: usize },
    #[error("{what} gradient has {got} values, expected {expected} for this image")]
    GradientLength {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("the {what} has {got} values, expected {expected} (3 × width × height)")]
    ImageLength {
        what: &'static str,
        expected: u64,
        got: usize,
    },
    #[error(
        "backward called with a model of {got} Gaussians, but {expected} were rendered; pass the rendered model"
    )]
    ModelMismatch { expected: usize, got: usize },
    #[error(
        "backward called on a frame the {backend} backend did not render; render it with the same backend"
    )]
    WrongBackend { backend: &'static str },
    #[error("the {backend} backend has no backward pass yet; train with the CPU backend")]
    BackwardUnsupported { backend: &'static str },
    #[error("GPU: {0}")]
    Gpu(String),
}

/// Options of one render.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions<'a, F> {
    /// Colour seen where transmittance remains.
    pub background: [F; 3],
    /// Optional per-Gaussian multiplier on render opacity (the 4C4D neural decay `τ`);
    /// its gradient is returned in [`Gradients::opacity_factor`].
    pub opacity_factor: Option<&'a [F]>,
    /// Gaussians whose sliced mean is closer to the camera than this are culled.
    pub near_plane: F,
}

impl<F: Real> Default for RenderOptions<'_, F> {
    fn default() -> Self {
        Self {
            background: [F::zero(); 3],
            opacity_factor: None,
            near_plane: F::c(0.01),
        }
    }
}
/// One view of a batch: a camera, a model time, and the options of its render.
#[derive(Clone, Copy, Debug)]
pub struct ViewRequest<'a> {
    pub camera: &'a Camera,
    pub t: f32,
    pub options: RenderOptions<'a, f32>,
}

/// A renderer of 4D Gaussians: forward over a batch of views, backward from image
/// gradients. What a backend needs between the two stays inside [`Rendered`].
pub trait RenderBackend: Send + Sync {
    /// What renders, for logs and manifests (e.g. `cpu (2 threads)`, a GPU adapter).
    fn describe(&self) -> String;

    /// Render every view of `views` of `model`, one frame per view, in order.
    fn render_batch(
        &self,
        model: &Gaussians<f32>,
        views: &[ViewRequest<'_>],
    ) -> Result<Vec<Rendered<f32>>, RenderError>;

    /// dL/d(image) of `frame` (rendered by this backend from `model`) → dL/d(parameters),
    /// written into `out` (resized and overwritten, not added to).
    fn backward(
        &self,
        model: &Gaussians<f32>,
        frame: &Rendered<f32>,
        up: &ImageGradients<f32>,
        out: &mut Gradients<f32>,
    ) -> Result<(), RenderError>;

    /// How many views a batch should hold to use the backend well (1 on the CPU, which
    /// parallelises inside one view).
    fn preferred_batch(&self) -> usize {
        1
    }

    /// This backend as the GPU backend, when it is one (the trainer then keeps the model
    /// and its optimiser state on the device).
    fn as_gpu(&self) -> Option<&gpu::GpuBackend> {
        None
    }

    /// Render one view.
    fn render(
        &self,
        model: &Gaussians<f32>,
        camera: &Camera,
        t: f32,
        options: &RenderOptions<'_, f32>,
    ) -> Result<Rendered<f32>, RenderError> {
        let views = [ViewRequest {
            camera,
            t,
            options: *options,
        }];
        let mut frames = self.render_batch(model, &views)?;
        Ok(frames.remove(0))
    }
}

/// Counts of one render, for throughput figures and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Gaussians drawn.
    pub visible: usize,
    /// (tile, Gaussian) pairs blended.
    pub tile_pairs: usize,
    /// Splat-pixel evaluations of the forward blend.
    pub blend_evaluations: u64,
}

/// A rendered image plus what its backend needs for the backward pass.
#[derive(Clone)]
pub struct Rendered<F: Real = f32> {
    pub width: u32,
    pub height: u32,
    /// RGB, row-major, 3 values per pixel (background composited).
    pub rgb: Vec<F>,
    /// Accumulated opacity `1 − T` per pixel.
    pub alpha: Vec<F>,
    /// `Σ wᵢ zᵢ` per pixel (camera depth weighted by blend weight; divide by alpha for
    /// the expected depth of the covered part).
    pub depth: Vec<F>,
    /// Per Gaussian: half-size of its 3σ box in pixels (max of x and y), 0 if it was not
    /// drawn (culled in time, behind the near plane, off-screen or transparent).
    pub radii: Vec<F>,
    /// The model time this image was rendered at.
    pub time: F,
    pub stats: RenderStats,
    /// The backend's auxiliary state for the backward pass.
    pub(crate) state: Arc<dyn Any + Send + Sync>,
}

impl<F: Real> std::fmt::Debug for Rendered<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Rendered")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("time", &self.time)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

/// Upstream gradients dL/d(output) of a render; `None` means zero.
#[derive(Clone, Copy, Debug)]
pub struct ImageGradients<'a, F> {
    pub rgb: &'a [F],
    pub alpha: Option<&'a [F]>,
    pub depth: Option<&'a [F]>,
}

/// dL/d(parameters), laid out like [`Gaussians`] so an optimiser can step each group.
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients<F: Real = f32> {
    pub means: Vec<[F; 4]>,
    pub log_scales: Vec<[F; 4]>,
    pub rot_left: Vec<[F; 4]>,
    pub rot_right: Vec<[F; 4]>,
    pub opacity_logits: Vec<F>,
    /// Same layout as [`Gaussians::colours`].
    pub colours: Vec<F>,
    /// dL/d(opacity factor) per Gaussian; empty when no factor was given.
    pub opacity_factor: Vec<F>,
    /// `|dL/d(2D mean)|` per Gaussian in 1/pixel units (densification statistic).
    pub mean2d_norm: Vec<F>,
}

impl<F: Real> Gradients<F> {
    /// Resize to `model` (the opacity-factor gradient gets one entry per Gaussian). Old
    /// values stay: the per-Gaussian backward overwrites every entry, so the large colour
    /// array is written once per step instead of zeroed and then written.
    pub(crate) fn resize_to(&mut self, model: &Gaussians<F>) {
        let n = model.len();
        let z4 = [F::zero(); 4];
        for v in [
            &mut self.means,
            &mut self.log_scales,
            &mut self.rot_left,
            &mut self.rot_right,
        ] {
            v.resize(n, z4);
        }
        for v in [
            &mut self.opacity_logits,
            &mut self.opacity_factor,
            &mut self.mean2d_norm,
        ] {
            v.resize(n, F::zero());
        }
        self.colours.resize(model.colours.len(), F::zero());
    }

    /// Add `other` (same layout) into these gradients, parameter by parameter (the
    /// densification statistic and the opacity-factor gradient are left as they are).
    pub fn add(&mut self, other: &Self) {
        let add4 = |a: &mut Vec<[F; 4]>, b: &Vec<[F; 4]>| {
            a.as_flattened_mut()
                .iter_mut()
                .zip(b.as_flattened())
                .for_each(|(x, y)| *x += *y)
        };
        add4(&mut self.means, &other.means);
        add4(&mut self.log_scales, &other.log_scales);
        add4(&mut self.rot_left, &other.rot_left);
        add4(&mut self.rot_right, &other.rot_right);
        for (a, b) in [
            (&mut self.opacity_logits, &other.opacity_logits),
            (&mut self.colours, &other.colours),
        ] {
            a.iter_mut().zip(b).for_each(|(x, y)| *x += *y);
        }
    }

    /// All-zero gradients for `model`.
    pub fn zeros_like(model: &Gaussians<F>, with_factor: bool) -> Self {
        let n = model.len();
        Self {
            means: vec![[F::zero(); 4]; n],
            log_scales: vec![[F::zero(); 4]; n],
            rot_left: vec![[F::zero(); 4]; n],
            rot_right: vec![[F::zero(); 4]; n],
            opacity_logits: vec![F::zero(); n],
            colours: vec![F::zero(); model.colours.len()],
            opacity_factor: if with_factor {
                vec![F::zero(); n]
            } else {
                Vec::new()
            },
            mean2d_norm: vec![F::zero(); n],
        }
    }
}
/// The pinhole camera of `camera` for rendering, or why it cannot be drawn (distorted
/// lens, empty image, bad focal lengths). Every backend starts from this check.
pub(crate) fn checked_pinhole<F: Real>(
    camera: &Camera,
    near: F,
) -> Result<PinholeCamera<F>, RenderError> {
    if !camera.distortion.is_none() {
        return Err(RenderError::DistortedCamera {
            camera: camera.name.clone(),
        });
    }
    let i = &camera.intrinsics;
    if i.width == 0 || i.height == 0 {
        return Err(RenderError::EmptyImage {
            camera: camera.name.clone(),
            width: i.width,
            height: i.height,
        });
    }
    if !(i.fx.is_finite()
        && i.fy.is_finite()
        && i.fx > 0.0
        && i.fy > 0.0
        && i.cx.is_finite()
        && i.cy.is_finite())
    {
        return Err(RenderError::BadIntrinsics {
            camera: camera.name.clone(),
        });
    }
    Ok(PinholeCamera::from_camera(camera, near))
}
/// The model's time period for the spherindrical colour (its duration, 1 if unknown).
pub(crate) fn period_of<F: Real>(model: &Gaussians<F>) -> F {
    let d = model.time.duration;
    F::c(if d.is_finite() && d > 0.0 { d } else { 1.0 })
}
/// Check a backward call's inputs against the frame: the model has the rendered size, and
/// the upstream gradients have one value per pixel (three for RGB).
pub(crate) fn check_backward_inputs<F: Real>(
    frame: &Rendered<F>,
    model: &Gaussians<F>,
    factor_len: Option<usize>,
    up: &ImageGradients<F>,
) -> Result<(), RenderError> {
    let n = model.len();
    let rendered = frame.radii.len();
    if n != rendered || n != factor_len.unwrap_or(rendered) {
        return Err(RenderError::ModelMismatch {
            expected: rendered,
            got: n,
        });
    }
    model
        .check_consistent()
        .map_err(RenderError::InconsistentModel)?;
    let npix = frame.width as usize * frame.height as usize;
    let check = |what, got: usize, want| {
        if got == want {
            Ok(())
        } else {
            Err(RenderError::GradientLength {
                what,
                expected: want,
                got,
            })
        }
    };
    check("rgb", up.rgb.len(), 3 * npix)?;
    if let Some(a) = up.alpha {
        check("alpha", a.len(), npix)?;
    }
    if let Some(d) = up.depth {
        check("depth", d.len(), npix)?;
    }
    Ok(())
}
