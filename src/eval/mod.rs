//! Rendering and evaluating a trained model: render camera paths to frames
//! ([`render_path`]) and measure renders against ground-truth images ([`evaluate`]):
//! PSNR, SSIM, DSSIM₁, DSSIM₂ and (when weights are installed or given) LPIPS per frame
//! and mean, PSNR and SSIM inside the moving region where a view has a mask, held-out and
//! training views reported separately, written as `metrics.json`, `per_frame.csv` and
//! side-by-side PNG grids. Every file is written under a temporary
//! name and renamed. Every render goes through a [`RenderBackend`], in batches of its
//! preferred size. The metric maths is in `metrics`, the camera paths in `trajectories`.

mod frames;
pub mod images;

use image::RgbImage;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub use frames::{FrameOutputs, FrameSink, RenderedPath, render_path};

use crate::camera::Camera;
use crate::metrics::lpips::{ImagePair, Lpips, LpipsDevice, LpipsError};
use crate::metrics::{MetricsError, image_metrics, masked_metrics, region};
use crate::model::Gaussians;
use crate::progress::Progress;
use crate::render::backdrop::{Backdrop, UvCache, composite};
use crate::render::{RenderBackend, RenderError, RenderOptions, ViewRequest};
use images::{error_heat_map, rgb8_from, side_by_side, write_atomic, write_png};

/// Grids written per set (first, middle and last frame).
pub const GRIDS_PER_SET: usize = 3;

/// Views evaluated together at least: their LPIPS pairs go through the network at once.
const LPIPS_VIEWS: usize = 4;

/// Pixels around a moving-region mask's bounding box that its LPIPS crop keeps.
pub const MOVING_BOX_MARGIN: usize = 8;
/// Least side of that crop (AlexNet's deepest layer sees 16×16-pixel steps).
pub const MOVING_BOX_MIN_SIDE: usize = 64;

/// What `metrics.json` says about LPIPS when no network was given: why, and how to get one.
pub const LPIPS_SKIPPED: &str = "skipped: no LPIPS weights installed (run scripts/setup.sh, or set LPIPS_WEIGHTS to the weights file)";

/// Why rendering or evaluation stopped.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(
        "cannot read ground-truth image {path}: {source}; check that the held-out frames were extracted"
    )]
    ReadImage {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("cannot render {view}: {source}")]
    Render { view: String, source: RenderError },
    #[error("cannot compare {view}: {source}")]
    Metrics { view: String, source: MetricsError },
    #[error("cannot read the moving-region mask {path}: {source}; give an 8-bit grey PNG")]
    ReadMask {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(
        "the moving-region mask {mask} is {mask_width}×{mask_height} but its image {image} is {width}×{height}; give a mask of the image's size"
    )]
    MaskSize {
        mask: PathBuf,
        mask_width: u32,
        mask_height: u32,
        image: PathBuf,
        width: u32,
        height: u32,
    },
    #[error("LPIPS of {view}: {source}")]
    Lpips { view: String, source: LpipsError },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot encode image {path}: {source}")]
    EncodeImage {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("the frame consumer stopped at frame {frame}: {message}")]
    Sink { frame: usize, message: String },
    #[error("nothing to evaluate: no held-out and no training views were given")]
    NoViews,
}

/// One ground-truth image to compare against.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalView {
    /// The (undistorted, pinhole) camera; rescaled to the image's size when they differ.
    pub camera: Camera,
    /// Model time `t` of the image (`model.time.model_time(seconds)`).
    pub time: f64,
    /// The ground-truth image (PNG or JPEG, 8-bit RGB).
    pub image_path: PathBuf,
    /// Where moving or deforming objects are in the image: an 8-bit grey image of the
    /// same size, inside where ≥ 128. `None`: no mask for this view.
    pub mask: Option<PathBuf>,
    /// The camera's exposure gain per RGB channel: the render is multiplied by it before it
    /// is compared (a training camera whose frames were equalised,
    /// [`crate::train::exposure`]; 1 for any other view).
    pub gain: [f32; 3],
}

/// Metrics of one view.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMetrics {
    pub camera: String,
    /// The view's capture time in seconds (`model.time.seconds` of its model time).
    pub time_s: f64,
    pub image_path: PathBuf,
    /// dB; `+∞` for a pixel-exact render.
    pub psnr: f64,
    pub ssim: f64,
    pub dssim1: f64,
    pub dssim2: f64,
    /// `None` when LPIPS was skipped (no weights).
    pub lpips: Option<f64>,
    /// The render's mean brightness over the truth's, whole image (below 1: darker than
    /// the scene; a dark cloud over the view).
    pub brightness: f64,
    /// Inside the view's moving-region mask; `None` when the view has no mask.
    pub moving: Option<MovingMetrics>,
}

/// PSNR and SSIM of one view inside its moving-region mask.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MovingMetrics {
    /// Fraction of the image inside the mask (0 for an empty mask).
    pub mask_fraction: f64,
    /// dB, MSE over the masked pixels and RGB; `None` for an empty mask.
    pub psnr: Option<f64>,
    /// Mean of the SSIM map over the masked pixels and RGB; `None` for an empty mask.
    pub ssim: Option<f64>,
    /// LPIPS of the mask's box (render and truth cropped alike); `None` for an empty mask
    /// or when LPIPS was skipped.
    pub lpips: Option<f64>,
    /// The render's mean brightness inside the mask over the truth's (below 1: darker than
    /// the scene); `None` for an empty mask.
    pub brightness: Option<f64>,
}

/// Means over the views of a set whose moving-region mask is not empty.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MovingSummary {
    /// Views in the means.
    pub frames: usize,
    /// Views whose mask was empty (left out of the means).
    pub empty_masks: usize,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub lpips: Option<f64>,
    /// Mean brightness ratio, and the darkest view's.
    pub brightness: Option<f64>,
    pub darkest: Option<f64>,
    /// Index of the darkest view in the set's frames (its grid is
    /// `grid_<set>_darkest.png`).
    pub darkest_frame: Option<usize>,
    /// Mean mask fraction of the views in the means.
    pub mask_fraction: Option<f64>,
}

impl MovingSummary {
    /// The summary of `frames`; `None` when none of them has a mask.
    fn of(frames: &[FrameMetrics]) -> Option<Self> {
        let masked: Vec<&MovingMetrics> = frames.iter().filter_map(|f| f.moving.as_ref()).collect();
        if masked.is_empty() {
            return None;
        }
        let darkest_frame = least_bright(
            frames
                .iter()
                .enumerate()
                .filter_map(|(i, f)| Some((i, f.moving.as_ref()?.brightness?))),
        );
        let measured: Vec<&&MovingMetrics> = masked.iter().filter(|m| m.psnr.is_some()).collect();
        Some(Self {
            frames: measured.len(),
            empty_masks: masked.len() - measured.len(),
            psnr: mean(measured.iter().filter_map(|m| m.psnr)),
            ssim: mean(measured.iter().filter_map(|m| m.ssim)),
            lpips: mean(measured.iter().filter_map(|m| m.lpips)),
            brightness: mean(measured.iter().filter_map(|m| m.brightness)),
            darkest: darkest_frame.and_then(|i| frames[i].moving.as_ref()?.brightness),
            darkest_frame,
            mask_fraction: mean(measured.iter().map(|m| m.mask_fraction)),
        })
    }
}

/// The index of the least brightness among `(index, brightness)` pairs (the first of
/// equals); `None` when there are none.
fn least_bright(brightness: impl Iterator<Item = (usize, f64)>) -> Option<usize> {
    brightness
        .reduce(|a, b| if b.1 < a.1 { b } else { a })
        .map(|(i, _)| i)
}

/// Means over the views of one set (`None` for an empty set). PSNR is the mean of the
/// per-frame PSNRs (the 3DGS convention), `+∞` only if every frame is exact.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SetMetrics {
    pub frames: Vec<FrameMetrics>,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub dssim1: Option<f64>,
    pub dssim2: Option<f64>,
    pub lpips: Option<f64>,
    /// Mean whole-image brightness ratio.
    pub brightness: Option<f64>,
    /// Index in `frames` of the view whose whole image is darkest against its truth.
    pub darkest_frame: Option<usize>,
    /// Inside the moving-region masks; `None` when no view of the set has a mask.
    pub moving: Option<MovingSummary>,
}

/// Result of [`evaluate`]; the same numbers are in `metrics.json` and `per_frame.csv`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EvalReport {
    pub heldout: SetMetrics,
    pub train: SetMetrics,
    /// `"computed"` or [`LPIPS_SKIPPED`].
    pub lpips_status: String,
    /// Files written: `metrics.json`, `per_frame.csv`, the grids.
    pub files: Vec<PathBuf>,
}

/// Metric definitions written into `metrics.json`.
fn definitions() -> serde_json::Value {
    serde_json::json!({
        "psnr": "Peak signal-to-noise ratio in dB, 10·log10(1/MSE) on RGB in [0,1] (render clamped to [0,1]); mean = mean of per-frame PSNRs; null = infinite (pixel-exact render)",
        "ssim": "Structural similarity, 11×11 Gaussian window σ=1.5, data range 1, zero-padded same-size filtering, mean over pixels and RGB channels (3DGS convention)",
        "dssim1": "(1 − SSIM)/2 with SSIM at data range 1.0 (C1=(0.01·1)², C2=(0.03·1)²)",
        "dssim2": "(1 − SSIM)/2 with SSIM at data range 2.0 (C1=(0.01·2)², C2=(0.03·2)²; the older scikit-image default for float images); smaller than dssim1 for the same images",
        "lpips": "LPIPS v0.1 (learned perceptual image patch similarity) with AlexNet, computed natively from the weights scripts/setup.sh installs, or with the ONNX model of [eval] lpips (lpips.network says which); images scaled to [-1,1]; lower is better; a 'skipped: …' text saying how to get the weights when there are none",
        "brightness": "the render's mean over pixels and RGB divided by the truth's (at least 1/255), whole image: below 1 where the render is darker than the scene; darkest_view = the view where it is least",
        "heldout": "views not used for training (novel-view quality)",
        "train": "training views (reported separately so overfitting is visible)",
    })
}

/// The definition of the moving-region metrics, added when a view has a mask.
const MOVING_DEFINITION: &str = "PSNR (MSE over the masked pixels, RGB) and SSIM (mean of the SSIM map over the masked pixels, RGB; windows also see the pixels around the mask) inside each view's moving-region mask, and LPIPS of the render and the truth cropped to the mask's bounding box (8 pixels wider each side, at least 64×64, inside the image), and brightness (the render's mean over the masked pixels and RGB divided by the truth's, at least 1/255: below 1 where the render is darker than the scene), means over the views whose mask is not empty (empty_masks: views left out); darkest = the least brightness of a view; mask_fraction = mean fraction of the image inside the mask";

fn finite(v: Option<f64>) -> serde_json::Value {
    match v {
        Some(x) if x.is_finite() => serde_json::json!(x),
        _ => serde_json::Value::Null,
    }
}

fn load_truth(path: &Path) -> Result<(Vec<f32>, u32, u32), EvalError> {
    let img = image::open(path)
        .map_err(|source| EvalError::ReadImage {
            path: path.to_path_buf(),
            source,
        })?
        .to_rgb8();
    let (w, h) = img.dimensions();
    Ok((
        img.into_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        w,
        h,
    ))
}

/// The mask of a view of size `width × height`: a pixel is inside where the grey value is
/// ≥ 128. The error names both files and sizes when the sizes differ.
fn load_mask(path: &Path, image: &Path, width: u32, height: u32) -> Result<Vec<bool>, EvalError> {
    let mask = image::open(path)
        .map_err(|source| EvalError::ReadMask {
            path: path.to_path_buf(),
            source,
        })?
        .to_luma8();
    if mask.dimensions() != (width, height) {
        return Err(EvalError::MaskSize {
            mask: path.to_path_buf(),
            mask_width: mask.width(),
            mask_height: mask.height(),
            image: image.to_path_buf(),
            width,
            height,
        });
    }
    Ok(mask.into_raw().into_iter().map(|v| v >= 128).collect())
}

/// PSNR and SSIM of `rendered` inside `mask`, with the moving region's LPIPS.
fn moving_metrics(
    rendered: &[f32],
    truth: &[f32],
    mask: &[bool],
    width: u32,
    height: u32,
    lpips: Option<f64>,
) -> Result<MovingMetrics, MetricsError> {
    let m = masked_metrics(rendered, truth, mask, width as usize, height as usize)?;
    Ok(MovingMetrics {
        mask_fraction: m.map_or(0.0, |m| m.fraction),
        psnr: m.map(|m| m.psnr),
        ssim: m.map(|m| m.ssim),
        lpips: m.and(lpips),
        brightness: m.map(|m| m.brightness),
    })
}

/// LPIPS of each view's moving region: of the render and the truth cropped to the mask's
/// box ([`MOVING_BOX_MARGIN`], [`MOVING_BOX_MIN_SIDE`]); `None` for a view without a mask
/// or with an empty one. An error names the view's index in the batch.
fn moving_lpips(
    net: &Lpips,
    device: LpipsDevice,
    rendered: &[Vec<f32>],
    truths: &[(Vec<f32>, u32, u32)],
    masks: &[Option<Vec<bool>>],
) -> Result<Vec<Option<f64>>, (usize, LpipsError)> {
    let mut crops = Vec::new();
    for (k, ((r, (t, w, h)), mask)) in rendered.iter().zip(truths).zip(masks).enumerate() {
        let (w, h) = (*w as usize, *h as usize);
        let rect = mask
            .as_ref()
            .and_then(|m| region::mask_box(m, w, h, MOVING_BOX_MARGIN, MOVING_BOX_MIN_SIDE));
        if let Some(rect) = rect {
            crops.push((
                k,
                rect,
                region::crop_rgb(r, w, rect),
                region::crop_rgb(t, w, rect),
            ));
        }
    }
    let pairs: Vec<ImagePair> = crops
        .iter()
        .map(|(_, rect, a, b)| ImagePair {
            a,
            b,
            width: rect.width(),
            height: rect.height(),
        })
        .collect();
    let mut out = vec![None; rendered.len()];
    for ((k, ..), d) in crops.iter().zip(net.distances_on(device, &pairs)) {
        out[*k] = Some(d.map_err(|e| (*k, e))?);
    }
    Ok(out)
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// Frames of a set that get a grid image: first, middle and last.
fn grid_indices(n: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = match n {
        0 => vec![],
        _ => (0..GRIDS_PER_SET.min(n))
            .map(|k| {
                if GRIDS_PER_SET.min(n) == 1 {
                    0
                } else {
                    k * (n - 1) / (GRIDS_PER_SET.min(n) - 1)
                }
            })
            .collect(),
    };
    idx.dedup();
    idx
}

struct SetRun<'a> {
    name: &'static str,
    views: &'a [EvalView],
}

/// Render every view of `heldout` and `train`, compare with its ground-truth image, and
/// write into `out_dir`: `metrics.json` (definitions, LPIPS status, per-set means),
/// `per_frame.csv` (one row per view) and `grid_<set>_<frame>.png` (ground truth |
/// render | error heat map) for a few frames of each set. LPIPS is computed only when
/// `lpips` is given (on the renderer's device when that is a GPU, else on the CPU);
/// otherwise it is reported as [`LPIPS_SKIPPED`]. Views are rendered on
/// `background`, the colour the model was trained on, or on its learned `backdrop`.
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    backend: &dyn RenderBackend,
    model: &Gaussians<f32>,
    heldout: &[EvalView],
    train: &[EvalView],
    out_dir: &Path,
    lpips: Option<&Lpips>,
    background: [f32; 3],
    backdrop: Option<&Backdrop>,
    progress: &dyn Progress,
) -> Result<EvalReport, EvalError> {
    if heldout.is_empty() && train.is_empty() {
        return Err(EvalError::NoViews);
    }
    std::fs::create_dir_all(out_dir).map_err(|source| EvalError::Write {
        path: out_dir.to_path_buf(),
        source,
    })?;
    progress.start((heldout.len() + train.len()) as u64, "views");
    let mut report = EvalReport {
        lpips_status: if lpips.is_some() {
            "computed".into()
        } else {
            LPIPS_SKIPPED.into()
        },
        ..Default::default()
    };
    let sets = [
        SetRun {
            name: "heldout",
            views: heldout,
        },
        SetRun {
            name: "train",
            views: train,
        },
    ];
    let lpips_device = match backend.as_gpu() {
        Some(gpu) => LpipsDevice::Gpu(&gpu.gpu),
        None => LpipsDevice::Cpu,
    };
    let mut grids = Vec::new();
    let mut uv_cache = UvCache::default();
    for set in &sets {
        let wanted_grids = grid_indices(set.views.len());
        let mut frames = Vec::with_capacity(set.views.len());
        // The view whose moving region came out darkest so far, and its grid.
        let mut darkest: Option<(f64, RgbImage)> = None;
        // At least a few views at a time, so that LPIPS takes their pairs through its
        // layers together even where the renderer draws one view at a time.
        let batch = backend.preferred_batch().max(LPIPS_VIEWS);
        for (chunk_index, chunk) in set.views.chunks(batch).enumerate() {
            let first = chunk_index * batch;
            let label = |i: usize| format!("{} view {i} ({})", set.name, set.views[i].camera.name);
            let mut truths = Vec::with_capacity(chunk.len());
            let mut cameras = Vec::with_capacity(chunk.len());
            for view in chunk {
                let (truth, w, h) = load_truth(&view.image_path)?;
                let mut camera = view.camera.clone();
                if (camera.intrinsics.width, camera.intrinsics.height) != (w, h) {
                    camera.intrinsics = camera.intrinsics.scaled_to(w, h);
                }
                truths.push((truth, w, h));
                cameras.push(camera);
            }
            let requests: Vec<ViewRequest> = chunk
                .iter()
                .zip(&cameras)
                .map(|(view, camera)| ViewRequest {
                    camera,
                    t: view.time as f32,
                    options: RenderOptions {
                        background: if backdrop.is_some() {
                            [0.0; 3]
                        } else {
                            background
                        },
                        ..RenderOptions::default()
                    },
                })
                .collect();
            let mut renders =
                backend
                    .render_batch(model, &requests)
                    .map_err(|source| EvalError::Render {
                        view: label(first),
                        source,
                    })?;
            if let Some(b) = backdrop {
                for (r, camera) in renders.iter_mut().zip(&cameras) {
                    let uvs = uv_cache.get(b, camera);
                    composite(&b.colours(&uvs), &mut r.rgb, &r.alpha);
                }
            }
            let rendered: Vec<Vec<f32>> = renders
                .iter()
                .zip(chunk)
                .map(|(r, view)| {
                    r.rgb
                        .iter()
                        .enumerate()
                        .map(|(k, v)| (v * view.gain[k % 3]).clamp(0.0, 1.0))
                        .collect()
                })
                .collect();
            // LPIPS of the whole batch at once: the native network runs the views in parallel,
            // on the renderer's GPU when it has one.
            let lpips_values: Vec<Option<f64>> = match lpips {
                Some(net) => {
                    let pairs: Vec<ImagePair> = rendered
                        .iter()
                        .zip(&truths)
                        .map(|(r, (t, w, h))| ImagePair {
                            a: r,
                            b: t,
                            width: *w as usize,
                            height: *h as usize,
                        })
                        .collect();
                    net.distances_on(lpips_device, &pairs)
                        .into_iter()
                        .enumerate()
                        .map(|(k, d)| {
                            d.map(Some).map_err(|source| EvalError::Lpips {
                                view: label(first + k),
                                source,
                            })
                        })
                        .collect::<Result<_, _>>()?
                }
                None => vec![None; chunk.len()],
            };
            let masks: Vec<Option<Vec<bool>>> = chunk
                .iter()
                .zip(&truths)
                .map(|(view, (_, w, h))| {
                    view.mask
                        .as_ref()
                        .map(|path| load_mask(path, &view.image_path, *w, *h))
                        .transpose()
                })
                .collect::<Result<_, _>>()?;
            let moving_lpips = match lpips {
                Some(net) => moving_lpips(net, lpips_device, &rendered, &truths, &masks).map_err(
                    |(k, source)| EvalError::Lpips {
                        view: label(first + k),
                        source,
                    },
                )?,
                None => vec![None; chunk.len()],
            };
            for (k, (((rendered, (truth, w, h)), lp), (mask, moving_lp))) in rendered
                .into_iter()
                .zip(truths)
                .zip(lpips_values)
                .zip(masks.iter().zip(moving_lpips))
                .enumerate()
            {
                let view = &chunk[k];
                let i = first + k;
                let label = || label(i);
                let m =
                    image_metrics(&rendered, &truth, w as usize, h as usize).map_err(|source| {
                        EvalError::Metrics {
                            view: label(),
                            source,
                        }
                    })?;
                let moving = mask
                    .as_ref()
                    .map(|mask| moving_metrics(&rendered, &truth, mask, w, h, moving_lp))
                    .transpose()
                    .map_err(|source| EvalError::Metrics {
                        view: label(),
                        source,
                    })?;
                let grid = || {
                    side_by_side(&[
                        &rgb8_from(&truth, w, h),
                        &rgb8_from(&rendered, w, h),
                        &error_heat_map(&rendered, &truth, w, h),
                    ])
                };
                if wanted_grids.contains(&i) {
                    let path = out_dir.join(format!("grid_{}_{i:04}.png", set.name));
                    write_png(&path, &grid())?;
                    grids.push(path);
                }
                if let Some(b) = moving.as_ref().and_then(|m| m.brightness)
                    && darkest.as_ref().is_none_or(|(least, _)| b < *least)
                {
                    darkest = Some((b, grid()));
                }
                progress.message(&format!("{} PSNR {:.2} dB", label(), m.psnr));
                progress.advance(1);
                frames.push(FrameMetrics {
                    camera: view.camera.name.clone(),
                    time_s: model.time.seconds(view.time),
                    image_path: view.image_path.clone(),
                    psnr: m.psnr,
                    ssim: m.ssim,
                    dssim1: m.dssim1,
                    dssim2: m.dssim2,
                    lpips: lp,
                    brightness: m.brightness,
                    moving,
                });
            }
        }
        if let Some((_, grid)) = &darkest {
            let path = out_dir.join(format!("grid_{}_darkest.png", set.name));
            write_png(&path, grid)?;
            grids.push(path);
        }
        let summary = SetMetrics {
            psnr: mean(frames.iter().map(|f| f.psnr)),
            ssim: mean(frames.iter().map(|f| f.ssim)),
            dssim1: mean(frames.iter().map(|f| f.dssim1)),
            dssim2: mean(frames.iter().map(|f| f.dssim2)),
            lpips: if lpips.is_some() {
                mean(frames.iter().filter_map(|f| f.lpips))
            } else {
                None
            },
            brightness: mean(frames.iter().map(|f| f.brightness)),
            darkest_frame: least_bright(frames.iter().map(|f| f.brightness).enumerate()),
            moving: MovingSummary::of(&frames),
            frames,
        };
        if set.name == "heldout" {
            report.heldout = summary;
        } else {
            report.train = summary;
        }
    }

    // per_frame.csv
    let any_mask = report.heldout.moving.is_some() || report.train.moving.is_some();
    let mut csv = String::from("set,camera,time_s,image,psnr,ssim,dssim1,dssim2,lpips,brightness");
    csv.push_str(if any_mask {
        ",moving_psnr,moving_ssim,moving_lpips,moving_brightness,mask_fraction\n"
    } else {
        "\n"
    });
    for (name, set) in [("heldout", &report.heldout), ("train", &report.train)] {
        for f in &set.frames {
            let lp = f
                .lpips
                .map(|v| format!("{v:.6}"))
                .unwrap_or_else(|| "skipped".into());
            let _ = write!(
                csv,
                "{name},{},{:.6},{},{:.4},{:.6},{:.6},{:.6},{lp},{:.4}",
                csv_field(&f.camera),
                f.time_s,
                csv_field(&relative_path(out_dir, &f.image_path).display().to_string()),
                f.psnr,
                f.ssim,
                f.dssim1,
                f.dssim2,
                f.brightness,
            );
            if any_mask {
                csv.push_str(&moving_csv(f.moving.as_ref()));
            }
            csv.push('\n');
        }
    }
    let csv_path = out_dir.join("per_frame.csv");
    write_atomic(&csv_path, csv.as_bytes())?;

    // metrics.json
    let set_json = |s: &SetMetrics| {
        let mut value = serde_json::json!({
            "frames": s.frames.len(),
            "mean": {
                "psnr": finite(s.psnr),
                "ssim": finite(s.ssim),
                "dssim1": finite(s.dssim1),
                "dssim2": finite(s.dssim2),
                "lpips": match (lpips.is_some(), s.lpips) {
                    (true, v) => finite(v),
                    (false, _) => serde_json::json!(LPIPS_SKIPPED),
                },
                "brightness": finite(s.brightness),
            },
            "darkest_view": s.darkest_frame.map(|i| serde_json::json!({
                "camera": s.frames[i].camera,
                "time_s": s.frames[i].time_s,
                "brightness": finite(Some(s.frames[i].brightness)),
            })),
        });
        if let Some(moving) = &s.moving {
            value["moving"] = moving_json(moving, &s.frames);
        }
        value
    };
    let file_name = |p: &PathBuf| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let mut json = serde_json::json!({
        "version": 1,
        "definitions": definitions(),
        "lpips": {
            "status": report.lpips_status,
            "network": lpips.map(|l| l.kind()),
            "model": lpips.map(|l| l.path().display().to_string()),
        },
        "heldout": set_json(&report.heldout),
        "train": set_json(&report.train),
        "per_frame": "per_frame.csv",
        "grids": grids.iter().map(file_name).collect::<Vec<_>>(),
        "grid_layout": format!("ground truth | render | mean absolute error (inferno, 0 to {})", images::ERROR_SCALE),
    });
    if any_mask {
        json["definitions"]["moving"] = MOVING_DEFINITION.into();
    }
    let json_path = out_dir.join("metrics.json");
    crate::atomic::write_json(&json_path, &json).map_err(|source| EvalError::Write {
        path: json_path.clone(),
        source,
    })?;
    progress.finish();

    report.files = vec![json_path, csv_path];
    report.files.extend(grids);
    Ok(report)
}

/// The moving-region columns of a `per_frame.csv` row (empty where the view has no mask,
/// or its mask is empty).
fn moving_csv(m: Option<&MovingMetrics>) -> String {
    let value =
        |v: Option<f64>, digits: usize| v.map_or(String::new(), |v| format!("{v:.digits$}"));
    match m {
        None => ",,,,,".into(),
        Some(m) => format!(
            ",{},{},{},{},{:.6}",
            value(m.psnr, 4),
            value(m.ssim, 6),
            value(m.lpips, 6),
            value(m.brightness, 4),
            m.mask_fraction
        ),
    }
}

/// `metrics.json`'s `moving` object of a set whose views are `frames`.
fn moving_json(m: &MovingSummary, frames: &[FrameMetrics]) -> serde_json::Value {
    let darkest_view = m
        .darkest_frame
        .map(|i| serde_json::json!({ "camera": frames[i].camera, "time_s": frames[i].time_s }));
    serde_json::json!({
        "frames": m.frames,
        "empty_masks": m.empty_masks,
        "mean": { "psnr": finite(m.psnr), "ssim": finite(m.ssim), "lpips": finite(m.lpips), "brightness": finite(m.brightness) },
        "darkest": finite(m.darkest),
        "darkest_view": darkest_view,
        "mask_fraction": finite(m.mask_fraction),
    })
}

/// `to` relative to the folder `from` (`..` where it lies outside), so that a file of
/// `from` can name it without naming `from` itself: a stage writes into a temporary
/// folder that is renamed when complete, and the name must hold after the rename. Both
/// are made absolute first (lexically, against the working directory); `to` is returned
/// absolute when the two share no root.
pub fn relative_path(from: &Path, to: &Path) -> PathBuf {
    use std::path::Component;
    let (Ok(from), Ok(to)) = (std::path::absolute(from), std::path::absolute(to)) else {
        return to.to_path_buf();
    };
    // Lexical clean-up of `.` and `..` (absolute paths have no leading `..` to keep).
    fn clean(p: &Path) -> Vec<Component<'_>> {
        let mut out: Vec<Component<'_>> = Vec::new();
        for c in p.components() {
            match c {
                Component::CurDir => {}
                Component::ParentDir => {
                    if matches!(out.last(), Some(Component::Normal(_))) {
                        out.pop();
                    }
                }
                other => out.push(other),
            }
        }
        out
    }
    let (f, t) = (clean(&from), clean(&to));
    let common = f.iter().zip(&t).take_while(|(a, b)| a == b).count();
    if common == 0 || !matches!(f.first(), Some(Component::RootDir | Component::Prefix(_))) {
        return to;
    }
    let mut rel = PathBuf::new();
    for _ in common..f.len() {
        rel.push("..");
    }
    for c in &t[common..] {
        rel.push(c.as_os_str());
    }
    rel
}

/// Quote a CSV field when it holds a comma, quote or newline.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
