//! Image quality metrics: PSNR, SSIM, and the two
//! structural dissimilarities DSSIM₁ and DSSIM₂, over the whole image or inside a mask
//! ([`masked_metrics`]). Images are interleaved RGB, row-major, values in `[0, 1]`; `f32`
//! for renders, `f64` for reference checks; masks are one flag per pixel, row-major.
//!
//! SSIM is [`ssim::ssim`], shared with the training loss (11×11 Gaussian window, σ 1.5,
//! zero-padded "same" filtering, mean over pixels and channels — the 3DGS convention).
//! It is written for data range 1; SSIM with data range `L` equals SSIM with range 1 of
//! the images divided by `L` (means scale by `1/L`, variances by `1/L²`, and the
//! stabilisers `(k·L)²` by the same `1/L²`), which is how DSSIM₂ is computed here.
//! No IO here (see `eval`).

pub mod lpips;
pub mod region;
pub mod ssim;

use crate::math::numerics::Real;
use crate::metrics::ssim::{masked_ssim, ssim};

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
    #[error("the mask has {got} pixels, expected {expected} for a {width}×{height} image")]
    WrongMaskSize {
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
    /// The render's mean over pixels and channels divided by the truth's
    /// ([`brightness_ratio`]): below 1 where the render is darker than the scene.
    pub brightness: f64,
}

/// A render's summed values over the truth's, the truth's mean at least 1/255 (`values`
/// summed in each): below 1 where the render is darker than the scene, 0 for a black
/// render of a black truth.
pub fn brightness_ratio(sum_rendered: f64, sum_truth: f64, values: usize) -> f64 {
    let n = values.max(1) as f64;
    (sum_rendered / n) / (sum_truth / n).max(1.0 / 255.0)
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
    let sum = |v: &[F]| v.iter().map(|x| x.f64()).sum::<f64>();
    Ok(ImageMetrics {
        mse,
        psnr: psnr_from_mse(mse),
        ssim: ssim1,
        dssim1: (1.0 - ssim1) / 2.0,
        dssim2: (1.0 - ssim2) / 2.0,
        brightness: brightness_ratio(sum(rendered), sum(truth), rendered.len()),
    })
}

/// PSNR and SSIM of a render inside a mask.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaskedMetrics {
    /// Fraction of the image's pixels inside the mask.
    pub fraction: f64,
    /// Mean squared error over the masked pixels, all three channels.
    pub mse: f64,
    /// `10·log10(1 / MSE)` of that error in dB; `+∞` when the masked pixels are identical.
    pub psnr: f64,
    /// Mean of the SSIM map (data range 1) over the masked pixels and channels.
    pub ssim: f64,
    /// The render's mean over the masked pixels and channels divided by the truth's (the
    /// truth's at least 1/255): below 1 where the render is darker than the scene.
    pub brightness: f64,
}

/// PSNR and SSIM of `rendered` against `truth` inside `mask` (one flag per pixel); `None`
/// when the mask is empty. SSIM windows still see the pixels around the mask.
pub fn masked_metrics<F: Real>(
    rendered: &[F],
    truth: &[F],
    mask: &[bool],
    width: usize,
    height: usize,
) -> Result<Option<MaskedMetrics>, MetricsError> {
    check(rendered, truth, width, height)?;
    if mask.len() != width * height {
        return Err(MetricsError::WrongMaskSize {
            width,
            height,
            expected: width * height,
            got: mask.len(),
        });
    }
    let Some(ssim) = masked_ssim(rendered, truth, width, height, mask) else {
        return Ok(None);
    };
    let (mut sum, mut inside) = (0.0f64, 0usize);
    let (mut sum_r, mut sum_t) = (0.0f64, 0.0f64);
    for ((r, t), _) in rendered
        .chunks_exact(3)
        .zip(truth.chunks_exact(3))
        .zip(mask)
        .filter(|(_, m)| **m)
    {
        for (&x, &y) in r.iter().zip(t) {
            sum += (x.f64() - y.f64()).powi(2);
            sum_r += x.f64();
            sum_t += y.f64();
        }
        inside += 1;
    }
    let values = (3 * inside) as f64;
    let mse = sum / values;
    Ok(Some(MaskedMetrics {
        fraction: inside as f64 / (width * height) as f64,
        mse,
        psnr: psnr_from_mse(mse),
        ssim,
        brightness: brightness_ratio(sum_r, sum_t, 3 * inside),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(n: usize, k: f64) -> Vec<f64> {
        (0..n).map(|i| ((i as f64 * k).sin() + 1.0) / 2.0).collect()
    }

    #[test]
    fn masked_psnr_counts_only_the_masked_pixels() {
        let (w, h) = (6, 4);
        let truth = ramp(3 * w * h, 0.37);
        let mut rendered = truth.clone();
        // Pixel 5 off by 0.1 in every channel, pixel 20 off by 0.3 in red only.
        for c in 0..3 {
            rendered[3 * 5 + c] += 0.1;
        }
        rendered[3 * 20] += 0.3;
        let mut mask = vec![false; w * h];
        mask[5] = true;
        mask[6] = true;
        let m = masked_metrics(&rendered, &truth, &mask, w, h)
            .unwrap()
            .unwrap();
        // MSE over 2 pixels × 3 channels: three errors of 0.1², three zeros.
        let mse = 3.0 * 0.01 / 6.0;
        assert!((m.mse - mse).abs() < 1e-12, "{}", m.mse);
        assert!((m.psnr - (-10.0 * mse.log10())).abs() < 1e-9);
        assert!((m.fraction - 2.0 / 24.0).abs() < 1e-15);
        // Brightness: the render's masked mean over the truth's (pixel 5 is 0.1 brighter).
        let t_sum: f64 = truth[15..21].iter().sum();
        assert!(
            (m.brightness - (t_sum + 0.3) / t_sum).abs() < 1e-12,
            "{}",
            m.brightness
        );
        let dark: Vec<f64> = truth.iter().map(|v| v * 0.5).collect();
        let d = masked_metrics(&dark, &truth, &mask, w, h).unwrap().unwrap();
        assert!((d.brightness - 0.5).abs() < 1e-12);
        // A black truth counts as 1/255: a black render is 0, not NaN.
        let black = vec![0.0; 3 * w * h];
        let b = masked_metrics(&black, &black, &mask, w, h)
            .unwrap()
            .unwrap();
        assert_eq!(b.brightness, 0.0);
        // A full mask gives the whole-image values.
        let full = masked_metrics(&rendered, &truth, &vec![true; w * h], w, h)
            .unwrap()
            .unwrap();
        let whole = image_metrics(&rendered, &truth, w, h).unwrap();
        assert!((full.psnr - whole.psnr).abs() < 1e-9);
        assert!((full.ssim - whole.ssim).abs() < 1e-12);
        assert!((full.brightness - whole.brightness).abs() < 1e-12);
        let half = image_metrics(&dark, &truth, w, h).unwrap();
        assert!((half.brightness - 0.5).abs() < 1e-12, "{}", half.brightness);
        assert_eq!(full.fraction, 1.0);
        // An empty mask gives nothing; a mask of the wrong size is an error.
        assert_eq!(
            masked_metrics(&rendered, &truth, &vec![false; w * h], w, h),
            Ok(None)
        );
        assert!(matches!(
            masked_metrics(&rendered, &truth, &[true; 5], w, h),
            Err(MetricsError::WrongMaskSize {
                got: 5,
                expected: 24,
                ..
            })
        ));
    }
}
