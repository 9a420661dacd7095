//! `evaluate` end to end on a small scene: metrics per frame and mean for held-out and
//! training views separately, `metrics.json` with definitions, `per_frame.csv`, grids,
//! LPIPS skipped without weights (saying how to get them), computed natively with the
//! installed LPIPS-alex weights, and computed with an ONNX model.

use crate::eval_support;

use eval_support::*;
use glam::DVec3;
use splat4d::CpuBackend;
use splat4d::NoProgress;
use splat4d::eval::{EvalError, EvalReport, EvalView, LPIPS_SKIPPED, evaluate};
use splat4d::metrics::image_metrics;
use splat4d::metrics::lpips::Lpips;

fn lpips_fixture() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/onnx/lpips_tiny/mean_abs_diff.onnx")
}

struct Setup {
    dir: tempfile::TempDir,
    heldout: Vec<EvalView>,
    train: Vec<EvalView>,
}

/// Held-out view 0: ground truth = the model's own render (8-bit). Held-out view 1: its
/// ground truth shows another moment, so the render at the stated time differs.
/// Training views: exact renders.
fn setup() -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let model = scene();
    let cams = rig(64, 48);
    let view = |cam: &splat4d::Camera, t: f64, truth_t: f64, name: &str| {
        let path = dir.path().join(name);
        save_render(&model, cam, truth_t, &path);
        EvalView {
            camera: cam.clone(),
            time: t,
            image_path: path,
            mask: None,
            gain: [1.0; 3],
        }
    };
    let heldout = vec![
        view(&cams[1], 0.5, 0.5, "h0.png"),
        view(&cams[3], 0.0, 1.0, "h1.png"),
    ];
    let train = vec![
        view(&cams[0], 0.25, 0.25, "t0.png"),
        view(&cams[2], 0.75, 0.75, "t1.png"),
    ];
    Setup {
        dir,
        heldout,
        train,
    }
}

/// `evaluate` of the setup's views on black, without LPIPS, into `out`.
fn evaluate_on_black(s: &Setup, model: &splat4d::Gaussians, out: &std::path::Path) -> EvalReport {
    evaluate(
        &CpuBackend,
        model,
        &s.heldout,
        &s.train,
        out,
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap()
}

/// `per_frame.csv` gives each view's capture time in seconds, not in model units: at 15 fps
/// from 2 s, model time 0.5 is 3 s.
#[test]
fn per_frame_times_are_seconds() {
    let s = setup();
    let out = s.dir.path().join("eval");
    let mut model = scene();
    model.time = splat4d::model::TimeMapping::frames_over_30(2.0, 15.0, 2.0);
    let report = evaluate_on_black(&s, &model, &out);
    assert_eq!(report.heldout.frames[0].time_s, 3.0);
    let csv = std::fs::read_to_string(out.join("per_frame.csv")).unwrap();
    let row = csv.lines().nth(1).unwrap();
    assert!(row.starts_with("heldout,cam1,3.000000,"), "{row}");
}

#[test]
fn report_files_hold_per_frame_and_mean_metrics_with_definitions() {
    let s = setup();
    let out = s.dir.path().join("eval");
    let model = scene();
    let report = evaluate_on_black(&s, &model, &out);

    assert_eq!(report.heldout.frames.len(), 2);
    assert_eq!(report.train.frames.len(), 2);
    let (exact, moved) = (&report.heldout.frames[0], &report.heldout.frames[1]);
    assert!(exact.psnr > 40.0, "8-bit rounding only: {}", exact.psnr);
    assert!(
        moved.psnr < exact.psnr - 5.0,
        "another moment: {}",
        moved.psnr
    );
    assert!(moved.dssim1 > moved.dssim2 && moved.dssim2 > 0.0);
    assert!(report.heldout.frames.iter().all(|f| f.lpips.is_none()));
    // Each number is the metric of the render against the file, recomputed here.
    let r = splat4d::render::cpu::render(&model, &s.heldout[1].camera, 0.0).unwrap();
    let rendered: Vec<f32> = r.rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect();
    let truth: Vec<f32> = image::open(&s.heldout[1].image_path)
        .unwrap()
        .to_rgb8()
        .into_raw()
        .iter()
        .map(|&v| v as f32 / 255.0)
        .collect();
    let m = image_metrics(&rendered, &truth, 64, 48).unwrap();
    assert_eq!(
        (moved.psnr, moved.ssim, moved.dssim1, moved.dssim2),
        (m.psnr, m.ssim, m.dssim1, m.dssim2)
    );
    let mean_psnr = (exact.psnr + moved.psnr) / 2.0;
    assert!((report.heldout.psnr.unwrap() - mean_psnr).abs() < 1e-12);
    assert_eq!(report.lpips_status, LPIPS_SKIPPED);
    assert!(
        LPIPS_SKIPPED.contains("scripts/setup.sh"),
        "{LPIPS_SKIPPED}"
    );

    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    for key in ["psnr", "ssim", "dssim1", "dssim2", "lpips"] {
        assert!(
            json["definitions"][key]
                .as_str()
                .is_some_and(|d| d.len() > 20),
            "definition of {key}"
        );
    }
    assert_eq!(json["lpips"]["status"], LPIPS_SKIPPED);
    assert_eq!(
        json["heldout"]["mean"]["lpips"], LPIPS_SKIPPED,
        "never a number without weights"
    );
    assert_eq!(json["heldout"]["frames"], 2);
    // No masks: nothing about the moving region.
    assert!(json["heldout"].get("moving").is_none() && json["definitions"].get("moving").is_none());
    assert!((json["heldout"]["mean"]["psnr"].as_f64().unwrap() - mean_psnr).abs() < 1e-9);
    assert!(
        (json["train"]["mean"]["ssim"].as_f64().unwrap() - report.train.ssim.unwrap()).abs()
            < 1e-12
    );

    let csv = std::fs::read_to_string(out.join("per_frame.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0],
        "set,camera,time_s,image,psnr,ssim,dssim1,dssim2,lpips,brightness"
    );
    assert_eq!(lines.len(), 5);
    assert!(
        lines[2].starts_with("heldout,cam3,0.000000,") && lines[2].contains(",skipped,"),
        "{}",
        lines[2]
    );
    assert!(lines[3].starts_with("train,cam0,"));

    // Grids: ground truth | render | error for first and last frame of each set.
    let grids = grid_names(&json);
    assert_eq!(
        grids,
        [
            "grid_heldout_0000.png",
            "grid_heldout_0001.png",
            "grid_train_0000.png",
            "grid_train_0001.png"
        ]
    );
    let grid = image::open(out.join("grid_heldout_0001.png"))
        .unwrap()
        .to_rgb8();
    assert_eq!(grid.dimensions(), (3 * 64, 48));
    // Left third is the ground truth as stored.
    let gt = image::open(&s.heldout[1].image_path).unwrap().to_rgb8();
    assert!((0..64).all(|x| grid.get_pixel(x, 20) == gt.get_pixel(x, 20)));
    // No temporary files remain.
    assert!(
        std::fs::read_dir(&out).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .contains(".tmp"))
    );
}

/// A stage evaluates into a temporary folder (`work/.eval.partial`) that is renamed to
/// `work/eval` when complete, and its undistorted ground-truth copies live inside that
/// folder: `per_frame.csv` must name every image relative to its own folder, so that the
/// names hold after the rename (they used to be absolute paths into `.eval.partial`).
#[test]
fn per_frame_csv_names_images_relative_to_its_folder_and_survives_the_rename() {
    let s = setup();
    let work = s.dir.path().join("work");
    let partial = work.join(".eval.partial");
    let model = scene();
    // One image inside the output folder (an undistorted copy), one beside it (a frame of
    // another stage).
    let inside = partial.join("groundtruth/train/cam0/000000.png");
    let beside = work.join("frames/cam2/000003.png");
    for (path, view) in [(&inside, &s.train[0]), (&beside, &s.train[1])] {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::copy(&view.image_path, path).unwrap();
    }
    let mut train = s.train.clone();
    train[0].image_path = inside.clone();
    train[1].image_path = work.join("frames/./cam2/../cam2/000003.png");
    evaluate(
        &CpuBackend,
        &model,
        &s.heldout,
        &train,
        &partial,
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    std::fs::rename(&partial, work.join("eval")).unwrap();
    let csv = std::fs::read_to_string(work.join("eval/per_frame.csv")).unwrap();
    let images: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(3).unwrap())
        .collect();
    assert_eq!(images[2], "groundtruth/train/cam0/000000.png", "{csv}");
    assert_eq!(images[3], "../frames/cam2/000003.png", "{csv}");
    assert_eq!(images[0], "../../h0.png", "{csv}");
    for image in images {
        assert!(
            !image.contains(".partial") && !image.starts_with('/'),
            "{image}"
        );
        assert!(work.join("eval").join(image).is_file(), "{image} resolves");
    }
}

#[test]
fn lpips_is_computed_with_an_onnx_model() {
    let s = setup();
    let out = s.dir.path().join("eval");
    let net = Lpips::load(&lpips_fixture()).unwrap();
    let model = scene();
    let report = evaluate(
        &CpuBackend,
        &model,
        &s.heldout,
        &[],
        &out,
        Some(&net),
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    let f = &report.heldout.frames[1];
    // The fixture computes mean |a − b| of the images scaled to [-1, 1].
    let r = splat4d::render::cpu::render(&model, &s.heldout[1].camera, 0.0).unwrap();
    let truth = image::open(&s.heldout[1].image_path)
        .unwrap()
        .to_rgb8()
        .into_raw();
    let expected = r
        .rgb
        .iter()
        .zip(&truth)
        .map(|(&a, &b)| (2.0 * a.clamp(0.0, 1.0) as f64 - 2.0 * b as f64 / 255.0).abs())
        .sum::<f64>()
        / truth.len() as f64;
    assert!(
        (f.lpips.unwrap() - expected).abs() < 1e-5,
        "{:?} vs {expected}",
        f.lpips
    );
    assert_eq!(report.lpips_status, "computed");
    assert!(report.train.frames.is_empty() && report.train.psnr.is_none());
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert!(json["heldout"]["mean"]["lpips"].as_f64().is_some());
    assert!(json["train"]["mean"]["psnr"].is_null());
}

#[test]
fn lpips_alex_is_computed_natively_from_the_installed_weights() {
    let net = match Lpips::installed().unwrap() {
        Some(net) => net,
        None if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") => panic!(
            "no LPIPS weights under CI=true: {}",
            splat4d::metrics::lpips::INSTALL_HINT
        ),
        None => {
            eprintln!("SKIPPED native LPIPS in evaluate: no weights installed");
            return;
        }
    };
    let s = setup();
    let out = s.dir.path().join("eval");
    let model = scene();
    let report = evaluate(
        &CpuBackend,
        &model,
        &s.heldout,
        &s.train,
        &out,
        Some(&net),
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    assert_eq!(report.lpips_status, "computed");
    // Each view's LPIPS is the network's distance between its render and its truth.
    for (view, f) in s.heldout.iter().zip(&report.heldout.frames) {
        let r = splat4d::render::cpu::render(&model, &view.camera, view.time as f32).unwrap();
        let rendered: Vec<f32> = r.rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        let truth: Vec<f32> = image::open(&view.image_path)
            .unwrap()
            .to_rgb8()
            .into_raw()
            .iter()
            .map(|&v| v as f32 / 255.0)
            .collect();
        let expected = net.distance(&rendered, &truth, 64, 48).unwrap();
        assert!(
            (f.lpips.unwrap() - expected).abs() < 1e-5,
            "{f:?} vs {expected}"
        );
    }
    // View 0's truth is its own render (8-bit): nearly 0; view 1 shows another moment.
    let (same, other) = (
        report.heldout.frames[0].lpips.unwrap(),
        report.heldout.frames[1].lpips.unwrap(),
    );
    assert!(same < 0.01 && other > same, "{same} {other}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(json["lpips"]["network"], "alex (native)");
    assert!(json["heldout"]["mean"]["lpips"].as_f64().is_some());
    assert!(json["train"]["mean"]["lpips"].as_f64().is_some());
}

/// The grid files `metrics.json` lists.
fn grid_names(json: &serde_json::Value) -> Vec<&str> {
    json["grids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g.as_str().unwrap())
        .collect()
}

/// A grey mask of `width × height` with `inside(x, y)` set to 255.
fn write_mask(path: &std::path::Path, width: u32, height: u32, inside: impl Fn(u32, u32) -> bool) {
    image::GrayImage::from_fn(width, height, |x, y| {
        image::Luma([if inside(x, y) { 255 } else { 0 }])
    })
    .save(path)
    .unwrap();
}

#[test]
fn moving_region_metrics_are_reported_where_views_have_masks() {
    let mut s = setup();
    let model = scene();
    let dir = s.dir.path().to_path_buf();
    // Held-out view 1: the left half; view 0: no mask. Training: an empty and a full mask.
    for (name, inside) in [
        (
            "m_left.png",
            &(|x: u32, _: u32| x < 32) as &dyn Fn(u32, u32) -> bool,
        ),
        ("m_empty.png", &|_, _| false),
        ("m_full.png", &|_, _| true),
    ] {
        write_mask(&dir.join(name), 64, 48, inside);
    }
    s.heldout[1].mask = Some(dir.join("m_left.png"));
    s.train[0].mask = Some(dir.join("m_empty.png"));
    s.train[1].mask = Some(dir.join("m_full.png"));
    let out = dir.join("eval");
    let report = evaluate(
        &CpuBackend,
        &model,
        &s.heldout,
        &s.train,
        &out,
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();

    // Held-out view 1, recomputed: PSNR over the left half.
    let r = splat4d::render::cpu::render(&model, &s.heldout[1].camera, 0.0).unwrap();
    let rendered: Vec<f32> = r.rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect();
    let truth: Vec<f32> = image::open(&s.heldout[1].image_path)
        .unwrap()
        .to_rgb8()
        .into_raw()
        .iter()
        .map(|&v| v as f32 / 255.0)
        .collect();
    let mask: Vec<bool> = (0..64 * 48).map(|i| i % 64 < 32).collect();
    let want = splat4d::metrics::masked_metrics(&rendered, &truth, &mask, 64, 48)
        .unwrap()
        .unwrap();
    let held = report.heldout.frames[1].moving.unwrap();
    assert_eq!(
        (held.psnr, held.ssim, held.mask_fraction),
        (Some(want.psnr), Some(want.ssim), 0.5)
    );
    assert!(held.psnr.unwrap() != report.heldout.frames[1].psnr);
    assert_eq!(report.heldout.frames[0].moving, None);
    let moving = report.heldout.moving.unwrap();
    assert_eq!(
        (moving.frames, moving.empty_masks, moving.psnr),
        (1, 0, Some(want.psnr))
    );
    // Training: the empty mask is left out (and counted); the full mask is the whole image.
    let train = report.train.moving.unwrap();
    assert_eq!(
        (train.frames, train.empty_masks, train.mask_fraction),
        (1, 1, Some(1.0))
    );
    let full = &report.train.frames[1];
    let exact = |a: f64, b: f64| (a - b).abs() < 1e-9 || a == b;
    assert!(
        exact(full.moving.unwrap().psnr.unwrap(), full.psnr),
        "{full:?}"
    );
    assert!((full.moving.unwrap().ssim.unwrap() - full.ssim).abs() < 1e-5);
    // Whole-image brightness: the render's mean over the truth's (a full mask's too).
    assert!((full.moving.unwrap().brightness.unwrap() - full.brightness).abs() < 1e-9);
    let whole = splat4d::metrics::image_metrics(&rendered, &truth, 64, 48).unwrap();
    assert!((report.heldout.frames[1].brightness - whole.brightness).abs() < 1e-12);

    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert!(
        json["definitions"]["moving"]
            .as_str()
            .is_some_and(|d| d.contains("mask"))
    );
    assert_eq!(json["heldout"]["moving"]["frames"], 1);
    assert_eq!(json["train"]["moving"]["empty_masks"], 1);
    assert!((json["heldout"]["moving"]["mean"]["psnr"].as_f64().unwrap() - want.psnr).abs() < 1e-9);
    assert_eq!(json["heldout"]["moving"]["mask_fraction"], 0.5);
    // Each set names its darkest whole view.
    for (set, metrics) in [("heldout", &report.heldout), ("train", &report.train)] {
        let least = (0..metrics.frames.len())
            .min_by(|&a, &b| {
                metrics.frames[a]
                    .brightness
                    .total_cmp(&metrics.frames[b].brightness)
            })
            .unwrap();
        assert_eq!(metrics.darkest_frame, Some(least));
        let view = &json[set]["darkest_view"];
        assert_eq!(view["camera"], metrics.frames[least].camera.as_str());
        // serde_json parses a float to within one ulp of what it wrote.
        let written = view["brightness"].as_f64().unwrap();
        assert!((written - metrics.frames[least].brightness).abs() < 1e-12);
    }
    // Each set's view with the darkest moving region gets its grid too: the one masked
    // held-out view, the full-masked training view (the empty mask has no brightness).
    let grids = grid_names(&json);
    assert_eq!(
        grids,
        [
            "grid_heldout_0000.png",
            "grid_heldout_0001.png",
            "grid_heldout_darkest.png",
            "grid_train_0000.png",
            "grid_train_0001.png",
            "grid_train_darkest.png"
        ]
    );
    for (set, metrics) in [("heldout", &report.heldout), ("train", &report.train)] {
        let read = |name: String| std::fs::read(out.join(name)).unwrap();
        assert!(
            read(format!("grid_{set}_darkest.png")) == read(format!("grid_{set}_0001.png")),
            "{set}: the darkest grid is not view 1's"
        );
        // metrics.json names that view.
        assert_eq!(metrics.moving.unwrap().darkest_frame, Some(1));
        let view = &json[set]["moving"]["darkest_view"];
        assert_eq!(view["camera"], metrics.frames[1].camera.as_str());
        assert_eq!(view["time_s"].as_f64(), Some(metrics.frames[1].time_s));
    }
    let csv = std::fs::read_to_string(out.join("per_frame.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0],
        "set,camera,time_s,image,psnr,ssim,dssim1,dssim2,lpips,brightness,moving_psnr,moving_ssim,moving_lpips,moving_brightness,mask_fraction"
    );
    assert!(
        lines[1].contains(",skipped,") && lines[1].ends_with(",,,,,"),
        "no mask: {}",
        lines[1]
    );
    assert!(lines[2].ends_with(",0.500000"), "{}", lines[2]);
    assert!(
        lines[3].contains(",skipped,") && lines[3].ends_with(",,,,,0.000000"),
        "empty mask: {}",
        lines[3]
    );

    // A mask of another size names both files and sizes.
    write_mask(&dir.join("m_small.png"), 32, 24, |_, _| true);
    s.heldout[1].mask = Some(dir.join("m_small.png"));
    let e = evaluate(
        &CpuBackend,
        &model,
        &s.heldout,
        &[],
        &dir.join("e"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, EvalError::MaskSize { .. }), "{text}");
    assert!(
        text.contains("m_small.png")
            && text.contains("32×24")
            && text.contains("h1.png")
            && text.contains("64×48"),
        "{text}"
    );

    // With a network, the moving region has its LPIPS too: over the whole image for a full
    // mask, none for an empty one (the fixture's network is mean |a − b|).
    s.heldout[1].mask = Some(dir.join("m_left.png"));
    let net = Lpips::load(&lpips_fixture()).unwrap();
    let report = evaluate(
        &CpuBackend,
        &model,
        &s.heldout,
        &s.train,
        &dir.join("with-lpips"),
        Some(&net),
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    let full = &report.train.frames[1];
    let (whole, moving) = (full.lpips.unwrap(), full.moving.unwrap().lpips.unwrap());
    assert!(
        whole > 0.0 && (moving - whole).abs() < 1e-6,
        "{whole} {moving}"
    );
    assert_eq!(report.train.frames[0].moving.unwrap().lpips, None);
    let held = report.heldout.moving.unwrap();
    assert_eq!(held.lpips, report.heldout.frames[1].moving.unwrap().lpips);
    assert!(held.lpips.is_some_and(|v| v > 0.0));
}

#[test]
fn ground_truth_of_another_size_renders_at_that_size() {
    let s = setup();
    let model = scene();
    let mut view = s.heldout[0].clone();
    let small = view.camera.intrinsics.scaled_to(32, 24);
    let mut cam = view.camera.clone();
    cam.intrinsics = small;
    view.image_path = s.dir.path().join("small.png");
    save_render(&model, &cam, view.time, &view.image_path);
    let report = evaluate(
        &CpuBackend,
        &model,
        &[view],
        &[],
        &s.dir.path().join("e"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    assert!(report.heldout.frames[0].psnr > 40.0);
}

#[test]
fn missing_images_and_empty_requests_are_typed_errors() {
    let s = setup();
    let model = scene();
    let mut view = s.heldout[0].clone();
    view.image_path = s.dir.path().join("nope.png");
    let e = evaluate(
        &CpuBackend,
        &model,
        &[view],
        &[],
        &s.dir.path().join("e"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(&e, EvalError::ReadImage { path, .. } if path.ends_with("nope.png")),
        "{e}"
    );
    let e = evaluate(
        &CpuBackend,
        &model,
        &[],
        &[],
        &s.dir.path().join("e"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(e, EvalError::NoViews));
    let mut far = s.heldout[0].clone();
    far.camera = camera("distorted", DVec3::new(0.0, -3.0, 0.0), 64, 48);
    far.camera.distortion = splat4d::Distortion::radial_tangential(0.1, 0.0, 0.0, 0.0, 0.0);
    let e = evaluate(
        &CpuBackend,
        &model,
        &[far],
        &[],
        &s.dir.path().join("e"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(e, EvalError::Render { .. }), "{e}");
}

#[test]
fn views_are_rendered_on_the_background_the_model_was_trained_on() {
    let dir = tempfile::tempdir().unwrap();
    let model = scene();
    let cam = rig(64, 48).remove(1);
    let grey = [0.6f32, 0.5, 0.4];
    let options = splat4d::render::RenderOptions {
        background: grey,
        ..Default::default()
    };
    let r = splat4d::render::cpu::render_with(&model, &cam, 0.5, &options).unwrap();
    let path = dir.path().join("truth.png");
    splat4d::eval::images::rgb8(&r).save(&path).unwrap();
    let views = [EvalView {
        camera: cam,
        time: 0.5,
        image_path: path,
        mask: None,
        gain: [1.0; 3],
    }];
    let psnr = |background: [f32; 3], name: &str| {
        let report = evaluate(
            &CpuBackend,
            &model,
            &views,
            &[],
            &dir.path().join(name),
            None,
            background,
            None,
            &NoProgress,
        )
        .unwrap();
        report.heldout.psnr.unwrap()
    };
    let (right, black) = (psnr(grey, "grey"), psnr([0.0; 3], "black"));
    assert!(right > 40.0, "8-bit rounding only: {right}");
    assert!(black < right - 10.0, "{black} vs {right}");
}

#[test]
fn a_training_view_is_compared_as_its_camera_filmed_it() {
    // A camera that films at half the brightness; its frames were equalised for training,
    // so the render is multiplied by its gain before it meets the frame.
    let dir = tempfile::tempdir().unwrap();
    let model = scene();
    let cam = rig(64, 48).remove(0);
    let path = dir.path().join("dark.png");
    save_render(&model, &cam, 0.5, &path);
    let mut dark = image::open(&path).unwrap().into_rgb8();
    for p in dark.pixels_mut() {
        p.0 = p.0.map(|v| (v as f32 * 0.5).round() as u8);
    }
    dark.save(&path).unwrap();
    let view = |gain| EvalView {
        camera: cam.clone(),
        time: 0.5,
        image_path: path.clone(),
        mask: None,
        gain,
    };
    let report = evaluate(
        &CpuBackend,
        &model,
        &[],
        &[view([0.5; 3]), view([1.0; 3])],
        &dir.path().join("eval"),
        None,
        [0.0; 3],
        None,
        &NoProgress,
    )
    .unwrap();
    let (gained, as_rendered) = (&report.train.frames[0], &report.train.frames[1]);
    assert!(gained.psnr > 40.0, "8-bit rounding only: {}", gained.psnr);
    assert!(
        as_rendered.psnr < gained.psnr - 10.0,
        "{}",
        as_rendered.psnr
    );
}
