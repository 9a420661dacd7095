//! Evaluation metrics against values computed by hand on tiny images,
//! including the DSSIM₁ / DSSIM₂ difference (data range 1 vs 2).

use splat4d::metrics::{MetricsError, dssim1, dssim2, image_metrics, psnr, ssim_with_range};

/// The centre weight of the normalised 11-tap Gaussian window (σ = 1.5).
fn centre_weight() -> f64 {
    1.0 / (-5..=5)
        .map(|d: i32| (-(d * d) as f64 / 4.5).exp())
        .sum::<f64>()
}

/// SSIM of a 1×1 image pair written out from the definition: with zero padding the
/// window sees only the pixel itself, with weight g = w0² (w0 per axis), so
/// μ = g·x, σx² = g·x² − g²·x², σxy = g·x·y − g²·x·y.
fn ssim_1x1_by_hand(x: [f64; 3], y: [f64; 3], range: f64) -> f64 {
    let g = centre_weight().powi(2);
    let (c1, c2) = ((0.01 * range).powi(2), (0.03 * range).powi(2));
    let mut sum = 0.0;
    for c in 0..3 {
        let (mx, my) = (g * x[c], g * y[c]);
        let sxx = g * x[c] * x[c] - mx * mx;
        let syy = g * y[c] * y[c] - my * my;
        let sxy = g * x[c] * y[c] - mx * my;
        sum +=
            (2.0 * mx * my + c1) * (2.0 * sxy + c2) / ((mx * mx + my * my + c1) * (sxx + syy + c2));
    }
    sum / 3.0
}

#[test]
fn psnr_matches_hand_values() {
    let a = vec![0.5f64; 12];
    let b: Vec<f64> = a.iter().map(|v| v + 0.1).collect();
    assert!(
        (psnr(&a, &b, 2, 2).unwrap() - 20.0).abs() < 1e-9,
        "MSE 0.01 is 20 dB"
    );
    let mut c = a.clone();
    c[7] = 0.8; // one value off by 0.3: MSE = 0.09 / 12 = 0.0075
    let expected = 10.0 * (1.0 / 0.0075f64).log10();
    assert!((psnr(&a, &c, 2, 2).unwrap() - expected).abs() < 1e-9);
    assert!((expected - 21.249_387).abs() < 1e-5);
    assert_eq!(psnr(&a, &a, 2, 2).unwrap(), f64::INFINITY);
}

#[test]
fn ssim_and_both_dssims_match_the_definition_on_one_pixel() {
    let x = [0.2, 0.5, 0.9];
    let y = [0.3, 0.5, 0.4];
    let s1 = ssim_1x1_by_hand(x, y, 1.0);
    let s2 = ssim_1x1_by_hand(x, y, 2.0);
    assert!((ssim_with_range(&x, &y, 1, 1, 1.0).unwrap() - s1).abs() < 1e-12);
    assert!((ssim_with_range(&x, &y, 1, 1, 2.0).unwrap() - s2).abs() < 1e-12);
    let d1 = dssim1(&x, &y, 1, 1).unwrap();
    let d2 = dssim2(&x, &y, 1, 1).unwrap();
    assert!((d1 - (1.0 - s1) / 2.0).abs() < 1e-12);
    assert!((d2 - (1.0 - s2) / 2.0).abs() < 1e-12);
    // The larger stabilisers of data range 2 make the same pair look more similar:
    // the two conventions give visibly different numbers, so they must be named.
    assert!(d2 < d1 - 0.005, "DSSIM₁ {d1} vs DSSIM₂ {d2}");
}

#[test]
fn dssim_conventions_differ_on_a_textured_image_and_agree_on_identity() {
    let (w, h) = (16, 12);
    let a: Vec<f64> = (0..3 * w * h)
        .map(|i| ((i * 37 % 101) as f64) / 100.0)
        .collect();
    let b: Vec<f64> = a
        .iter()
        .enumerate()
        .map(|(i, v)| (v + 0.05 * ((i % 7) as f64 - 3.0)).clamp(0.0, 1.0))
        .collect();
    let m = image_metrics(&a, &b, w, h).unwrap();
    assert!(m.dssim1 > m.dssim2 && m.dssim2 > 0.0);
    assert!((m.dssim1 - (1.0 - m.ssim) / 2.0).abs() < 1e-15);
    let same = image_metrics(&a, &a, w, h).unwrap();
    assert_eq!(same.psnr, f64::INFINITY);
    assert!(
        (same.ssim - 1.0).abs() < 1e-12 && same.dssim1.abs() < 1e-12 && same.dssim2.abs() < 1e-12
    );
}

#[test]
fn f32_path_agrees_with_f64_reference() {
    let (w, h) = (20, 15);
    let a: Vec<f64> = (0..3 * w * h)
        .map(|i| ((i * 53 % 97) as f64) / 96.0)
        .collect();
    let b: Vec<f64> = (0..3 * w * h)
        .map(|i| ((i * 29 % 89) as f64) / 88.0)
        .collect();
    let (af, bf): (Vec<f32>, Vec<f32>) = (
        a.iter().map(|&v| v as f32).collect(),
        b.iter().map(|&v| v as f32).collect(),
    );
    let m64 = image_metrics(&a, &b, w, h).unwrap();
    let m32 = image_metrics(&af, &bf, w, h).unwrap();
    assert!((m64.psnr - m32.psnr).abs() < 1e-4);
    assert!((m64.ssim - m32.ssim).abs() < 1e-5);
    assert!((m64.dssim2 - m32.dssim2).abs() < 1e-5);
}

#[test]
fn mismatched_images_are_refused_not_panicked_on() {
    let a = vec![0.0f32; 12];
    let b = vec![0.0f32; 9];
    assert!(matches!(
        image_metrics(&a, &b, 2, 2),
        Err(MetricsError::WrongSize {
            which: "ground truth",
            ..
        })
    ));
    assert!(matches!(
        psnr(&a, &a, 0, 4),
        Err(MetricsError::Empty { .. })
    ));
}

#[test]
fn psnr_of_known_mse() {
    assert!((splat4d::metrics::psnr_from_mse(1e-3) - 30.0).abs() < 1e-12);
    assert_eq!(splat4d::metrics::psnr_from_mse(0.0), f64::INFINITY);
}
