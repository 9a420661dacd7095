//! The eval stage's moving-region metrics on a small simulated capture (`fixtures/tiny.toml`,
//! 160×120, a moving crate and a waving flag, one simulated held-out camera): with the
//! simulator's masks both sets report finite PSNR/SSIM inside the moving region that differ
//! from the whole image; adding a user's `masks/` folder reruns eval and uses it; a mask of
//! the wrong size is an error naming the file and both sizes; without masks they are
//! estimated from the static plates, and with that turned off nothing new is written.

use crate::common;

use std::fs;
use std::path::Path;

use common::fixture;
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::Selection;
use pipeline::simulate;

const SETTINGS: &str = "[sync]\nmethod = \"timestamps\"\n\
    [train]\niterations = 12\nbatch_size = 2\ncheckpoint_every = 0\n\
    [eval]\ntrain_views = 4\n";

fn metrics(root: &Path) -> serde_json::Value {
    serde_json::from_str(&fs::read_to_string(root.join("work/eval/metrics.json")).unwrap()).unwrap()
}

fn csv_header(root: &Path) -> String {
    let csv = fs::read_to_string(root.join("work/eval/per_frame.csv")).unwrap();
    csv.lines().next().unwrap().to_string()
}

fn to_eval() -> Selection {
    Selection {
        to: Some("eval".into()),
        ..Default::default()
    }
}

fn only_eval() -> Selection {
    Selection {
        only: Some("eval".into()),
        ..Default::default()
    }
}

/// A grey `width × height` mask, all inside.
fn write_full_mask(path: &Path, width: u32, height: u32) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::GrayImage::from_pixel(width, height, image::Luma([255]))
        .save(path)
        .unwrap();
}

#[test]
fn eval_reports_the_moving_region_where_masks_exist() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let scene = rig::sim::Scene::from_file(&fixture("tiny.toml")).unwrap();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    simulate::write_truth_calibration(&root).unwrap();
    fs::write(root.join("capture.toml"), SETTINGS).unwrap();
    // The simulator masks its held-out camera's images too.
    assert!(root.join("groundtruth/masks/heldout0/000000.png").is_file());

    let summary = common::run_stages(&root, to_eval());
    assert!(summary.failed.is_none(), "{summary:?}");
    let json = metrics(&root);
    eprintln!("heldout {}\ntrain {}", json["heldout"], json["train"]);
    for set in ["heldout", "train"] {
        let moving = &json[set]["moving"];
        assert!(moving["frames"].as_u64().unwrap() > 0, "{set}: {moving}");
        let psnr = moving["mean"]["psnr"].as_f64().expect("finite moving PSNR");
        let ssim = moving["mean"]["ssim"].as_f64().expect("finite moving SSIM");
        let fraction = moving["mask_fraction"].as_f64().unwrap();
        assert!(
            psnr.is_finite() && ssim.is_finite() && ssim <= 1.0,
            "{set}: {moving}"
        );
        assert!(fraction > 0.0 && fraction < 0.5, "{set}: {moving}");
        let whole = json[set]["mean"]["psnr"].as_f64().unwrap();
        assert!((psnr - whole).abs() > 0.01, "{set}: {psnr} vs {whole}");
    }
    assert!(json["definitions"]["moving"].is_string());
    assert!(csv_header(&root).ends_with(
        ",lpips,brightness,moving_psnr,moving_ssim,moving_lpips,moving_brightness,mask_fraction"
    ));

    // A user's masks/ (numbered like work/frames) is an input: adding it reruns eval, which
    // then uses it. Full masks of cam0: the moving region is the whole image.
    for k in 0..3 {
        write_full_mask(&root.join(format!("masks/cam0/{k:06}.png")), 160, 120);
    }
    let summary = common::run_stages(&root, to_eval());
    assert_eq!(summary.ran, ["eval"], "{summary:?}");
    let csv = fs::read_to_string(root.join("work/eval/per_frame.csv")).unwrap();
    let mut masked = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let has_mask = f[0] == "train" && f[1] == "cam0" && f[3].ends_with("cam0/000000.png");
        if has_mask {
            let (whole, moving) = (f[4].parse::<f64>().unwrap(), f[10].parse::<f64>().unwrap());
            assert!((whole - moving).abs() < 1e-3, "{line}");
            // A full mask: the LPIPS crop and the brightness are the whole image's, the
            // fraction 1.
            assert_eq!(f[12], f[8], "{line}");
            assert_eq!(f[13], f[9], "{line}");
            assert_eq!(f[14], "1.000000", "{line}");
            masked += 1;
        } else {
            assert!(
                line.ends_with(",,,,,"),
                "no user mask for this view: {line}"
            );
        }
    }
    assert_eq!(masked, 1, "{csv}");
    assert!(metrics(&root)["heldout"].get("moving").is_none());

    // A mask of the wrong shape names the file and both sizes.
    write_full_mask(&root.join("masks/cam0/000000.png"), 50, 50);
    let summary = common::run_stages(&root, only_eval());
    let (stage, error) = summary.failed.expect("a wrong-size mask fails eval");
    assert_eq!(stage, "eval");
    assert!(
        error.contains("masks/cam0/000000.png")
            && error.contains("50×50")
            && error.contains("160×120"),
        "{error}"
    );

    // No masks given: estimated from the static plates of the cameras with aligned frames
    // (the training cameras; the simulated held-out camera has none), where the crate and
    // the flag move, for the views eval measures.
    fs::remove_dir_all(root.join("masks")).unwrap();
    fs::remove_dir_all(root.join("groundtruth/masks")).unwrap();
    let summary = common::run_stages(&root, only_eval());
    assert!(summary.failed.is_none(), "{summary:?}");
    let json = metrics(&root);
    assert!(json["heldout"].get("moving").is_none());
    let moving = &json["train"]["moving"];
    let fraction = moving["mask_fraction"].as_f64().unwrap();
    assert!(fraction > 0.0 && fraction < 0.5, "{moving}");
    assert!(
        moving["mean"]["psnr"].as_f64().is_some_and(f64::is_finite),
        "{moving}"
    );
    assert!(root.join("work/eval/plate_masks/cam0/000000.png").is_file());
    // Only the views eval measures get a mask.
    let written: u64 = fs::read_dir(root.join("work/eval/plate_masks"))
        .unwrap()
        .map(|camera| fs::read_dir(camera.unwrap().path()).unwrap().count() as u64)
        .sum();
    assert_eq!(Some(written), moving["frames"].as_u64(), "{moving}");

    // Estimates turned off: nothing new in the outputs.
    fs::write(
        root.join("capture.toml"),
        format!("{SETTINGS}plate_masks = false\n"),
    )
    .unwrap();
    let summary = common::run_stages(&root, only_eval());
    assert!(summary.failed.is_none(), "{summary:?}");
    let json = metrics(&root);
    assert!(json["heldout"].get("moving").is_none() && json["train"].get("moving").is_none());
    assert!(json["definitions"].get("moving").is_none());
    assert_eq!(
        csv_header(&root),
        "set,camera,time_s,image,psnr,ssim,dssim1,dssim2,lpips,brightness"
    );
}
