//! Image quality metrics: PSNR, SSIM, and the two
//! structural dissimilarities DSSIM₁ and DSSIM₂. Images are interleaved RGB, row-major,
//! values in `[0, 1]`; `f32` for renders, `f64` for reference checks.
//!
//! SSIM is [`ssim::ssim`], shared with the training loss (11×11 Gaussian window, σ 1.5,
//! zero-padded "same" filtering, mean over pixels and channels — the 3DGS convention).
//! It is written for data range 1; SSIM with data range `L` equals SSIM with range 1 of
//! the images divided by `L` (means scale by `1/L`, variances by `1/L²`, and the
//! stabilisers `(k·L)²` by the same `1/L²`), which is how DSSIM₂ is computed here.
//! No IO here (see `eval`).

pub mod lpips;
pub mod ssim;

use crate::math::numerics::Real;
use crate::metrics::ssim::ssim;

/// Why two images cannot be compared.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricsError {
    #[error("image '{which}' has {got} values, expected {expected} for {width}×{height} RGB")]
    WrongSize {
        which: &'static str,
        width: usize,
        height: usize,
        expected: usize,
        got: usize,
    },
    #[error("cannot compare an empty ({width}×{height}) image")]
    Empty { width: usize, height: usize },
}

/// All metrics of one rendered image against its ground truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageMetrics {
    /// Mean squared error over pixels and channels.
    pub mse: f64,
    /// `10·log10(1 / MSE)` in dB; `+∞` for identical images.
    pub psnr: f64,
    /// SSIM with data range 1.
    pub ssim: f64,
    /// `(1 − SSIM) / 2` with data range 1.
    pub dssim1: f64,
    /// `(1 − SSIM) / 2` with data range 2 (the older scikit-image default for floats).
    pub dssim2: f64,
}

fn check<F>(a: &[F], b: &[F], width: usize, height: usize) -> Result<(), MetricsError> {
    if width == 0 || height == 0 {
        return Err(MetricsError::Empty { width, height });
    }
    let expected = 3 * width * height;
    for (which, img) in [("rendered", a.len()), ("ground truth", b.len())] {
        if img != expected {
            return Err(MetricsError::WrongSize {
                which,
                width,
                height,
                expected,
                got: img,
            });
        }
    }
    Ok(())
}

/// Mean squared error of `a` against `b` (same length).
pub fn mse<F: Real>(a: &[F], b: &[F]) -> f64 {
    let n = a.len().min(b.len()).max(1) as f64;
    a.iter()
        .zip(b)
        .map(|(&x, &y)| {
            let d = x.f64() - y.f64();
            d * d
        })
        .sum::<f64>()
        / n
}

/// PSNR in dB for images in `[0, 1]` from a mean squared error (`+∞` when it is 0).
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// PSNR of `a` against `b` in dB (peak 1).
pub fn psnr<F: Real>(a: &[F], b: &[F], width: usize, height: usize) -> Result<f64, MetricsError> {
    check(a, b, width, height)?;
    Ok(psnr_from_mse(mse(a, b)))
}

/// Mean SSIM for images whose values span `data_range` (1 for `[0, 1]` images).
pub fn ssim_with_range<F: Real>(
    a: &[F],
    b: &[F],
    width: usize,
    height: usize,
    data_range: f64,
) -> Result<f64, MetricsError> {
    check(a, b, width, height)?;
    if data_range == 1.0 {
        return Ok(ssim(a, b, width, height, None).f64());
    }
    // Rescale in f64 so the identity of the note above holds to rounding.
    let s = 1.0 / data_range;
    let a: Vec<f64> = a.iter().map(|v| v.f64() * s).collect();
    let b: Vec<f64> = b.iter().map(|v| v.f64() * s).collect();
    Ok(ssim(&a, &b, width, height, None))
}

/// DSSIM₁ = `(1 − SSIM)/2` with data range 1.
pub fn dssim1<F: Real>(a: &[F], b: &[F], width: usize, height: usize) -> Result<f64, MetricsError> {
    Ok((1.0 - ssim_with_range(a, b, width, height, 1.0)?) / 2.0)
}

/// DSSIM₂ = `(1 − SSIM)/2` with data range 2.
pub fn dssim2<F: Real>(a: &[F], b: &[F], width: usize, height: usize) -> Result<f64, MetricsError> {
    Ok((1.0 - ssim_with_range(a, b, width, height, 2.0)?) / 2.0)
}

/// PSNR, SSIM, DSSIM₁ and DSSIM₂ of `rendered` against `truth` in one call.
pub fn image_metrics<F: Real>(
    rendered: &[F],
    truth: &[F],
    width: usize,
    height: usize,
) -> Result<ImageMetrics, MetricsError> {
    check(rendered, truth, width, height)?;
    let mse = mse(rendered, truth);
    let ssim1 = ssim_with_range(rendered, truth, width, height, 1.0)?;
    let ssim2 = ssim_with_range(rendered, truth, width, height, 2.0)?;
    Ok(ImageMetrics {
        mse,
        psnr: psnr_from_mse(mse),
        ssim: ssim1,
        dssim1: (1.0 - ssim1) / 2.0,
        dssim2: (1.0 - ssim2) / 2.0,
    })
}
