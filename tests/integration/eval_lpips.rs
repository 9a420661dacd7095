//! LPIPS networks. LPIPS-alex computed natively: the LPIPS repository's example images
//! (fixtures/lpips) give the published distances with the installed weights (a failure,
//! not a skip, under `CI=true`), identical images give 0, a batch gives what each pair
//! gives alone, and bad weights files and too-small images are typed errors (with made-up
//! weights, on every machine). ONNX models through tract: a model with the LPIPS interface
//! whose output is a known function (mean absolute difference, fixtures/onnx/lpips_tiny)
//! gives that function's value at any image size; wrong interfaces and broken files are
//! typed errors.

use splat4d::metrics::lpips::weights::{Tensor, encode_tensors};
use splat4d::metrics::lpips::{INSTALL_HINT, ImagePair, Lpips, LpipsError, MIN_SIDE};

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

// ---- LPIPS-alex, computed natively from the installed weights ----

/// The LPIPS repository's example images (fixtures/lpips, BSD-2, see its LICENSE).
fn example(name: &str) -> (Vec<f32>, usize, usize) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/lpips")
        .join(name);
    let img = image::open(&path).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    let data = img.into_raw().iter().map(|&v| v as f32 / 255.0).collect();
    (data, w as usize, h as usize)
}

/// The installed LPIPS-alex weights. Without them: a panic under `CI=true` (setup installs
/// them), else `None` with a line saying `what` was skipped.
fn installed(what: &str) -> Option<Lpips> {
    match Lpips::installed() {
        Ok(Some(net)) => Some(net),
        Ok(None) => {
            if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
                panic!("no LPIPS weights under CI=true: {INSTALL_HINT}");
            }
            eprintln!("SKIPPED {what}: no LPIPS weights; {INSTALL_HINT}");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn alex_gives_the_published_distances_on_the_example_images() {
    let Some(net) = installed("LPIPS-alex on the example images") else {
        return;
    };
    assert!(matches!(net, Lpips::Alex(_)), "{}", net.kind());
    let (reference, w, h) = example("ex_ref.png");
    // What the LPIPS repository's own implementation (and a plain numpy one with these
    // weights) gives for its examples.
    for (other, expected) in [("ex_p0.png", 0.722), ("ex_p1.png", 0.138)] {
        let (img, w2, h2) = example(other);
        assert_eq!((w2, h2), (w, h));
        let d = net.distance(&reference, &img, w, h).unwrap();
        eprintln!("LPIPS-alex ex_ref vs {other}: {d:.5}");
        assert!((d - expected).abs() <= 0.001, "{other}: {d} vs {expected}");
        let back = net.distance(&img, &reference, w, h).unwrap();
        assert!((d - back).abs() < 1e-6, "not symmetric: {d} vs {back}");
    }
    assert_eq!(net.distance(&reference, &reference, w, h).unwrap(), 0.0);
}

#[test]
fn alex_is_zero_for_identical_images_of_any_size() {
    let Some(net) = installed("LPIPS-alex on identical images") else {
        return;
    };
    for (w, h) in [(MIN_SIDE, MIN_SIDE), (97, 45)] {
        let a = image(3, 3 * w * h);
        assert_eq!(net.distance(&a, &a, w, h).unwrap(), 0.0, "{w}×{h}");
        let b = image(4, 3 * w * h);
        assert!(net.distance(&a, &b, w, h).unwrap() > 0.0);
    }
}

/// A weights file with AlexNet's shapes and deterministic made-up values, so that the
/// native network's plumbing is tested on every machine, weights installed or not.
fn made_up_weights(
    dir: &std::path::Path,
    drop: Option<&str>,
    bad_shape: Option<&str>,
) -> std::path::PathBuf {
    let layers = [
        (11, 3, 64),
        (5, 64, 192),
        (3, 192, 384),
        (3, 384, 256),
        (3, 256, 256),
    ];
    let mut tensors = std::collections::BTreeMap::new();
    let mut seed = 1usize;
    let mut values = |n: usize, scale: f32| -> Vec<f32> {
        seed += 1;
        (0..n)
            .map(|i| (((i * 7919 + seed * 104_729) % 2001) as f32 / 1000.0 - 1.0) * scale)
            .collect()
    };
    for (i, (k, cin, cout)) in layers.into_iter().enumerate() {
        let fan_in = (k * k * cin) as f32;
        let kernel = Tensor {
            shape: vec![k, k, cin, cout],
            data: values(k * k * cin * cout, 1.7 / fan_in.sqrt()),
        };
        let bias = Tensor {
            shape: vec![cout],
            data: values(cout, 0.1),
        };
        let lin = Tensor {
            shape: vec![1, 1, cout, 1],
            data: values(cout, 0.5).iter().map(|v| v.abs()).collect(),
        };
        tensors.insert(format!("AlexNet_0/Conv_{i}/kernel"), kernel);
        tensors.insert(format!("AlexNet_0/Conv_{i}/bias"), bias);
        tensors.insert(format!("NetLinLayer_{i}/Conv_0/kernel"), lin);
    }
    if let Some(name) = drop {
        tensors.remove(name);
    }
    if let Some(name) = bad_shape {
        tensors.get_mut(name).unwrap().shape.reverse();
    }
    let path = dir.join("made-up.safetensors");
    std::fs::write(&path, encode_tensors(&tensors)).unwrap();
    path
}

#[test]
fn alex_runs_pairs_in_a_batch_as_it_runs_them_alone() {
    let dir = tempfile::tempdir().unwrap();
    let net = Lpips::load(&made_up_weights(dir.path(), None, None)).unwrap();
    assert!(matches!(net, Lpips::Alex(_)));
    let sizes = [(64, 48), (40, 33), (64, 48)];
    let images: Vec<(Vec<f32>, Vec<f32>)> = sizes
        .iter()
        .enumerate()
        .map(|(i, (w, h))| (image(i, 3 * w * h), image(i + 10, 3 * w * h)))
        .collect();
    let pairs: Vec<ImagePair> = images
        .iter()
        .zip(sizes)
        .map(|((a, b), (width, height))| ImagePair {
            a,
            b,
            width,
            height,
        })
        .collect();
    let batch: Vec<f64> = net
        .distances(&pairs)
        .into_iter()
        .map(|d| d.unwrap())
        .collect();
    for (p, d) in pairs.iter().zip(&batch) {
        let alone = net.distance(p.a, p.b, p.width, p.height).unwrap();
        assert_eq!(*d, alone);
        assert!(alone.is_finite() && alone > 0.0, "{alone}");
        assert_eq!(net.distance(p.a, p.a, p.width, p.height).unwrap(), 0.0);
    }
}

#[test]
fn bad_weights_files_and_small_images_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = "NetLinLayer_3/Conv_0/kernel";
    let path = made_up_weights(dir.path(), Some(missing), None);
    let e = Lpips::load(&path).unwrap_err();
    assert!(
        matches!(&e, LpipsError::BadWeights { path: p, message } if p == &path && message.contains(missing)),
        "{e}"
    );
    assert!(e.to_string().contains("scripts/setup.sh"), "{e}");
    let shaped = "AlexNet_0/Conv_1/kernel";
    let e = Lpips::load(&made_up_weights(dir.path(), None, Some(shaped))).unwrap_err();
    assert!(
        matches!(&e, LpipsError::BadWeights { message, .. } if message.contains(shaped) && message.contains("[192, 64, 5, 5]")),
        "{e}"
    );
    let truncated = dir.path().join("short.safetensors");
    std::fs::write(&truncated, b"1234").unwrap();
    assert!(matches!(
        Lpips::load(&truncated).unwrap_err(),
        LpipsError::BadWeights { .. }
    ));
    assert!(matches!(
        Lpips::load(&dir.path().join("absent.safetensors")).unwrap_err(),
        LpipsError::Read { .. }
    ));

    let net = Lpips::load(&made_up_weights(dir.path(), None, None)).unwrap();
    let (w, h) = (MIN_SIDE - 1, 200);
    let a = image(1, 3 * w * h);
    let e = net.distance(&a, &a, w, h).unwrap_err();
    assert!(
        matches!(
            e,
            LpipsError::TooSmall {
                width: 30,
                height: 200,
                min: 31
            }
        ),
        "{e}"
    );
}
