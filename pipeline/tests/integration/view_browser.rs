//! `pipeline view` in headless Chromium: the tiny capture trained and exported with its
//! viewer, served by the real binary (`pipeline view CAPTURE --no-open --port 0`), loads
//! through the printed URL and draws what the engine draws at the first training camera
//! (within the viewer's tolerance); Ctrl-C (SIGINT) stops the server cleanly.

use crate::browser;
use crate::common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

use browser::{Browser, engine_render, psnr, side_by_side};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use splat4d::export::ExportOptions;

/// Cheap stages with the viewer, trained on black (no backdrop), one export step.
const SETTINGS: &str = "[sync]\nmethod = \"timestamps\"\n[init]\nsource = \"random\"\n\
    [train]\niterations = 30\nbatch_size = 1\ncheckpoint_every = 0\nbackground = [0.0, 0.0, 0.0]\n\
    [train.densify]\nfrom_iteration = 4\nuntil_iteration = 20\nevery = 4\nopacity_reset_every = 0\n\
    [render]\nframes = 1\nvideo = false\n[eval]\nheldout_per_camera = 1\n[export]\nsteps = 1\n";

/// PSNR the page must reach against the engine (the viewer tests hold it to 45 dB on
/// their own scenes; this one only has to show the served model).
const FLOOR_DB: f64 = 35.0;

#[test]
fn the_served_viewer_draws_the_model_and_ctrl_c_stops_the_server() {
    let Some(browser) = Browser::find() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = common::tiny_capture(&tmp.path().join("take01"), SETTINGS);
    let summary = common::run_stages(&root, Default::default());
    assert!(summary.failed.is_none(), "{summary:?}");

    let mut server = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["view", root.to_str().unwrap(), "--no-open", "--port", "0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = BufReader::new(server.stdout.take().unwrap());
    let mut line = String::new();
    stdout.read_line(&mut line).unwrap();
    let url = line
        .trim()
        .strip_prefix("viewer at ")
        .unwrap_or_else(|| panic!("no URL in {line:?}"))
        .to_string();
    assert!(url.starts_with("http://127.0.0.1:"), "{url}");

    // What the export stage exported: the first training camera, the one export time.
    let work = root.join("work");
    let model = pipeline::engine_inputs::load_trained_model(&work).unwrap();
    let index = FramesIndex::read_json(&work.join("frames/frames.json")).unwrap();
    let cameras_file = work.join("poses/cameras.json");
    let poses = PosesFile::read(&cameras_file).unwrap();
    let (camera, _) = pipeline::engine_inputs::pinhole_cameras(&index, &poses.set, &cameras_file)
        .unwrap()
        .remove(0);
    let times = ExportOptions {
        steps: Some(1),
        ..Default::default()
    }
    .times(&model, index.frames.len());
    let shot = tmp.path().join("view.png");
    let i = &camera.intrinsics;
    browser.screenshots(
        &tmp.path().join("profile"),
        (i.width, i.height),
        &[(format!("{url}?ui=0&play=0&camera=0&frame=0"), shot.clone())],
    );
    let page = image::open(&shot).unwrap().to_rgb8();
    let engine = engine_render(&model, &camera, times[0], [0.0; 3]);
    let lit = engine
        .pixels()
        .filter(|p| p.0.iter().any(|&c| c > 20))
        .count();
    assert!(lit > 100, "the engine draws almost nothing ({lit} pixels)");
    let db = psnr(&page, &engine);
    side_by_side(&[&page, &engine])
        .save(tmp.path().join("view-vs-engine.png"))
        .unwrap();
    assert!(
        db >= FLOOR_DB,
        "the served page against the engine: {db:.2} dB"
    );

    // Ctrl-C: the server stops and says so.
    let pid = server.id().to_string();
    assert!(
        Command::new("kill")
            .args(["-INT", &pid])
            .status()
            .unwrap()
            .success()
    );
    let status = server.wait().unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut server.stderr.take().unwrap(), &mut rest).unwrap();
    assert!(status.success(), "{status:?}: {rest}");
    assert!(rest.contains("stopped"), "{rest}");
}
