//! The browser viewer on a trained demo capture (`pipeline demo`), against the engine:
//! exports the capture's model as the export stage does (the pinhole training cameras,
//! one time step per aligned frame), opens the page in headless Chromium at training
//! cameras and times, renders the engine at the same ones, prints the PSNRs and writes
//! side-by-side PNGs (viewer | engine) — the pictures in docs/export.md. Also the
//! `.splatv` played by gsplat's own renderer (`splatv.html`).
//!
//! Long and needs a trained capture: ignored by default. Run:
//! `VIEWER_DEMO_CAPTURE=4c4d-demo cargo test -p pipeline --test integration -- --ignored --nocapture viewer_demo::`
//! (`VIEWER_DEMO_OUT=DIR` for the PNGs, default `docs/viewer/`).

use crate::browser;

use std::path::{Path, PathBuf};

use browser::{Browser, engine_render, psnr, serve, side_by_side};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use shared_types::CameraSet;
use splat4d::export::{ExportOptions, export_all};

#[test]
#[ignore = "needs a trained demo capture (VIEWER_DEMO_CAPTURE) and Chromium; slow"]
fn viewer_matches_the_engine_on_the_trained_demo() {
    let Some(capture) = std::env::var_os("VIEWER_DEMO_CAPTURE").map(PathBuf::from) else {
        panic!("set VIEWER_DEMO_CAPTURE to a capture that `pipeline demo` trained");
    };
    let Some(browser) = Browser::find() else {
        return;
    };
    let out = std::env::var_os("VIEWER_DEMO_OUT")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/viewer"));
    std::fs::create_dir_all(&out).unwrap();
    let work = capture.join("work");

    // As the export stage does.
    let model = pipeline::engine_inputs::load_trained_model(&work).unwrap();
    let index = FramesIndex::read_json(&work.join("frames/frames.json")).unwrap();
    let cameras_file = work.join("poses/cameras.json");
    let poses = PosesFile::read(&cameras_file).unwrap();
    let cameras = CameraSet::new(
        pipeline::engine_inputs::pinhole_cameras(&index, &poses.set, &cameras_file)
            .unwrap()
            .into_iter()
            .map(|(c, _)| c)
            .collect(),
    );
    let options = ExportOptions {
        model4d: false,
        splatv: true,
        viewer_bundle: Some(browser.bundle.clone()),
        ..Default::default()
    };
    let times = options.times(&model, index.frames.len());
    let dir = tempfile::tempdir().unwrap();
    export_all(
        &model,
        &cameras,
        &times,
        dir.path(),
        &options,
        &splat4d::NoProgress,
    )
    .unwrap();
    let port = serve(dir.path().to_path_buf());

    let (last, mid) = (times.len() - 1, (times.len() - 1) / 2);
    let cams = cameras.cameras.len();
    // (file stem, query, camera, frame)
    let mut cases: Vec<(String, String, usize, usize)> = [0, mid, last]
        .iter()
        .map(|&f| {
            (
                format!("demo-cam0-frame{f:02}"),
                format!("camera=0&frame={f}"),
                0,
                f,
            )
        })
        .collect();
    let other = cams.saturating_sub(1).min(2);
    cases.push((
        format!("demo-cam{other}-frame{mid:02}"),
        format!("camera={other}&frame={mid}"),
        other,
        mid,
    ));
    cases.push((
        format!("splatv-cam0-frame{mid:02}"),
        format!("camera=0&frame={mid}"),
        0,
        mid,
    ));
    let shots_dir = dir.path().join("shots");
    std::fs::create_dir_all(&shots_dir).unwrap();
    let shots: Vec<(String, PathBuf)> = cases
        .iter()
        .map(|(stem, query, _, _)| {
            // The `.splatv` plays in gsplat.js on its own page.
            let page = if stem.starts_with("splatv") {
                "splatv"
            } else {
                "index"
            };
            (
                format!("http://127.0.0.1:{port}/viewer/{page}.html?ui=0&play=0&{query}"),
                shots_dir.join(format!("{stem}.png")),
            )
        })
        .collect();
    let i = &cameras.cameras[0].intrinsics;
    browser.screenshots(&shots_dir.join("profile"), (i.width, i.height), &shots);

    let mut table = Vec::new();
    for ((stem, _, cam, frame), (_, png)) in cases.iter().zip(&shots) {
        let engine = engine_render(
            &model,
            &cameras.cameras[*cam],
            times[*frame],
            options.background,
        );
        let shot = image::open(png).unwrap().to_rgb8();
        let db = psnr(&shot, &engine);
        table.push(format!(
            "| {stem} | {} | {:.3} | {db:.2} |",
            cameras.cameras[*cam].name, times[*frame]
        ));
        side_by_side(&[&shot, &engine])
            .save(out.join(format!("{stem}.png")))
            .unwrap();
    }
    println!(
        "{} Gaussians, {} export times, {} cameras\n| picture | camera | model time | PSNR against the engine (dB) |\n|---|---|---|---|\n{}",
        model.len(),
        times.len(),
        cams,
        table.join("\n")
    );
}
