//! Loading LPIPS ONNX models with tract: a model with the LPIPS interface whose output is
//! a known function (mean absolute difference, fixtures/onnx/lpips_tiny) gives that
//! function's value at any image size; wrong interfaces and broken files are typed errors.

use splat4d::metrics::lpips::{Lpips, LpipsError};

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/onnx/lpips_tiny")
        .join(name)
}

fn image(seed: usize, n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| ((i * 7919 + seed * 104_729) % 1000) as f32 / 999.0)
        .collect()
}

#[test]
fn known_function_gives_its_value_at_several_sizes() {
    let net = Lpips::load(&fixture("mean_abs_diff.onnx")).unwrap();
    for (w, h) in [(16, 12), (40, 30), (16, 12)] {
        let (a, b) = (image(1, 3 * w * h), image(2, 3 * w * h));
        // In [-1, 1]: |(2a − 1) − (2b − 1)| = 2|a − b|.
        let expected = a
            .iter()
            .zip(&b)
            .map(|(x, y)| 2.0 * (x - y).abs() as f64)
            .sum::<f64>()
            / a.len() as f64;
        let got = net.distance(&a, &b, w, h).unwrap();
        assert!(
            (got - expected).abs() < 1e-5,
            "{w}×{h}: {got} vs {expected}"
        );
        assert_eq!(net.distance(&a, &a, w, h).unwrap(), 0.0);
    }
}

#[test]
fn wrong_interfaces_are_refused_at_load() {
    let e = Lpips::load(&fixture("one_input.onnx")).unwrap_err();
    assert!(
        matches!(&e, LpipsError::WrongInterface { message, .. } if message.contains("1 input")),
        "{e}"
    );
    let e = Lpips::load(&fixture("vector_output.onnx")).unwrap_err();
    assert!(
        matches!(&e, LpipsError::WrongInterface { message, .. } if message.contains("single number")),
        "{e}"
    );
}

#[test]
fn missing_and_corrupt_files_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let e = Lpips::load(&dir.path().join("absent.onnx")).unwrap_err();
    assert!(matches!(e, LpipsError::Read { .. }));
    let bad = dir.path().join("corrupt.onnx");
    let mut bytes = std::fs::read(fixture("mean_abs_diff.onnx")).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(&bad, &bytes).unwrap();
    let e = Lpips::load(&bad).unwrap_err();
    assert!(
        matches!(&e, LpipsError::Corrupt { path, .. } if path == &bad),
        "{e}"
    );
    assert!(e.to_string().contains("docs/render-eval.md"));
}

#[test]
fn images_of_the_wrong_size_are_refused() {
    let net = Lpips::load(&fixture("mean_abs_diff.onnx")).unwrap();
    let e = net
        .distance(&image(1, 3 * 8 * 8), &image(2, 3 * 8 * 7), 8, 8)
        .unwrap_err();
    assert!(
        matches!(
            e,
            LpipsError::ImageSize {
                expected: 192,
                got_b: 168,
                ..
            }
        ),
        "{e}"
    );
}
