//! The exported browser viewer in headless Chromium: export a small moving scene, serve
//! the folder over HTTP on 127.0.0.1, take screenshots at two slider times, and check
//! that the canvas shows the scene (not blank) and that it changes with time.
//!
//! Skips (prints why, passes) when `/usr/bin/chromium` or the built viewer bundle is
//! missing, except under `CI=true`, where both must be present (`scripts/setup.sh`
//! installs them). WebGL runs on SwiftShader (no GPU).

use glam::DVec3;
use splat4d::export::{ExportOptions, export_all, find_viewer_bundle};
use splat4d::{
    Camera, CameraSet, ColourDegrees, Distortion, Gaussians, Intrinsics, NoProgress, TimeMapping,
    WorldToCamera,
};
use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const CHROMIUM: &str = "/usr/bin/chromium";

fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true" || v == "1")
}

/// Skip (return `true`) with a message, or fail under CI.
fn skip(why: &str) -> bool {
    if in_ci() {
        panic!("viewer browser test cannot run under CI=true: {why}; run scripts/setup.sh");
    }
    eprintln!("SKIPPED viewer browser test: {why}");
    true
}

/// A static grey backdrop, a red blob on the left early (t ≈ 0.1) and a blue blob on the
/// right late (t ≈ 0.9). World z is up; the camera looks along +y.
fn moving_scene() -> Gaussians<f32> {
    let mut g = Gaussians::<f32>::new(
        ColourDegrees::FULL,
        TimeMapping {
            start_seconds: 0.0,
            units_per_second: 1.0,
            duration: 1.0,
        },
    );
    for i in 0..20 {
        for k in 0..12 {
            let x = -1.5 + 3.0 * i as f32 / 19.0;
            let z = -1.0 + 2.0 * k as f32 / 11.0;
            g.push(
                [x, 0.8, z, 0.5],
                [-2.0, -2.5, -2.0, 3.0],
                2.0,
                [0.55, 0.55, 0.5],
            );
        }
    }
    for (cx, t, rgb) in [
        (-0.7f32, 0.1f32, [0.95, 0.1, 0.1]),
        (0.7, 0.9, [0.1, 0.2, 0.95]),
    ] {
        for i in 0..8 {
            for k in 0..8 {
                let x = cx - 0.35 + 0.7 * i as f32 / 7.0;
                let z = -0.35 + 0.7 * k as f32 / 7.0;
                g.push([x, 0.0, z, t], [-2.2, -2.2, -2.2, -1.6], 3.0, rgb);
            }
        }
    }
    g.active = ColourDegrees::DC;
    g
}

fn cameras() -> CameraSet {
    let cam = |name: &str, eye: DVec3| Camera {
        name: name.into(),
        intrinsics: Intrinsics::from_hfov(640, 480, 60.0),
        distortion: Distortion::None,
        world_to_camera: WorldToCamera::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap(),
    };
    CameraSet::new(vec![
        cam("cam0", DVec3::new(0.0, -4.0, 0.3)),
        cam("cam1", DVec3::new(1.0, -3.8, 0.2)),
    ])
}

/// A tiny static file server for `root` on 127.0.0.1 (one thread per connection).
fn serve(root: PathBuf) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let root = root.clone();
            std::thread::spawn(move || {
                let _ = respond(stream, &root);
            });
        }
    });
    port
}

fn respond(mut stream: TcpStream, root: &Path) -> std::io::Result<()> {
    let mut line = String::new();
    let mut reader = BufReader::new(stream.try_clone()?);
    reader.read_line(&mut line)?;
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h)? == 0 || h == "\r\n" || h == "\n" {
            break;
        }
    }
    let target = line.split_whitespace().nth(1).unwrap_or("/");
    let path = target.split(['?', '#']).next().unwrap_or("/");
    let rel = if path.ends_with('/') {
        format!("{path}index.html")
    } else {
        path.to_string()
    };
    let file = root.join(rel.trim_start_matches('/'));
    let body = if rel.contains("..") {
        None
    } else {
        std::fs::read(&file).ok()
    };
    let (status, body) = match body {
        Some(b) => ("200 OK", b),
        None => ("404 Not Found", b"not found".to_vec()),
    };
    let mime = match file.extension().and_then(|e| e.to_str()) {
        Some("html") => "text/html; charset=utf-8",
        Some("js") => "text/javascript",
        Some("json") => "application/json",
        _ => "application/octet-stream",
    };
    write!(
        stream,
        "HTTP/1.1 {status}\r\nContent-Type: {mime}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    stream.write_all(&body)?;
    stream.flush()
}

/// Screenshots of `(url, png)` pairs through `viewer/test/screenshot.mjs` (playwright-core
/// driving Debian's Chromium, SwiftShader WebGL); panics with the script's output on
/// failure.
fn screenshots(node: &Path, script: &Path, profile: &Path, shots: &[(String, PathBuf)]) {
    let mut cmd = Command::new(node);
    cmd.arg(script).arg(CHROMIUM).arg(profile);
    for (url, png) in shots {
        cmd.arg(url).arg(png);
    }
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start node");
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(240) {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let output = child.wait_with_output().unwrap();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    eprintln!("{log}");
    assert!(output.status.success(), "screenshot script failed:\n{log}");
}

fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|d| Path::new(d).join(name))
        .find(|p| p.is_file())
}

/// Counts of pixels in the canvas area (the top and bottom UI strips left out) that are
/// far from the page background, strongly red, and strongly blue.
fn census(img: &image::RgbImage) -> (usize, usize, usize) {
    let (w, h) = img.dimensions();
    let (mut lit, mut red, mut blue) = (0, 0, 0);
    for y in 40..h.saturating_sub(60) {
        for x in 0..w {
            let [r, g, b] = img.get_pixel(x, y).0.map(|v| v as i32);
            if (r - 17).abs() + (g - 17).abs() + (b - 17).abs() > 60 {
                lit += 1;
            }
            if r > 120 && r > g + 60 && r > b + 60 {
                red += 1;
            }
            if b > 120 && b > r + 60 && b > g + 40 {
                blue += 1;
            }
        }
    }
    (lit, red, blue)
}

#[test]
fn viewer_shows_the_scene_and_changes_with_time() {
    if !Path::new(CHROMIUM).exists() && skip("/usr/bin/chromium is not installed") {
        return;
    }
    let bundle = match find_viewer_bundle() {
        Ok(b) => b,
        Err(e) => {
            if skip(&e.to_string()) {
                return;
            }
            unreachable!()
        }
    };
    let viewer_project = Path::new(env!("CARGO_MANIFEST_DIR")).join("viewer");
    let script = viewer_project.join("test/screenshot.mjs");
    let Some(node) = which("node") else {
        if skip("node is not installed") {
            return;
        }
        unreachable!()
    };
    if !viewer_project.join("node_modules/playwright-core").is_dir()
        && skip("viewer/node_modules/playwright-core is missing (npm ci --prefix viewer)")
    {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = moving_scene();
    let times: Vec<f64> = (0..5).map(|k| k as f64 / 4.0).collect();
    let opts = ExportOptions {
        frames: false,
        model4d: false,
        splatv: false,
        viewer_bundle: Some(bundle),
        ..Default::default()
    };
    let report = export_all(&model, &cameras(), &times, dir.path(), &opts, &NoProgress).unwrap();
    let index = report.viewer_index.unwrap();
    assert!(index.is_file());
    let port = serve(dir.path().join("viewer"));

    let shots = dir.path().join("shots");
    std::fs::create_dir_all(&shots).unwrap();
    // Frame 0, frame 4, and frame 4 reached from frame 0 inside one page (?goto).
    let pairs: Vec<(String, PathBuf)> = ["frame=0", "frame=4", "frame=0&goto=4"]
        .iter()
        .enumerate()
        .map(|(k, q)| {
            (
                format!("http://127.0.0.1:{port}/index.html?{q}&play=0"),
                shots.join(format!("shot{k}.png")),
            )
        })
        .collect();
    screenshots(&node, &script, &shots.join("profile"), &pairs);
    let mut results = Vec::new();
    for (frame, (_, png)) in [0, 4, 4].iter().zip(&pairs) {
        let img = image::open(png).expect("screenshot PNG").to_rgb8();
        if let Some(keep) = std::env::var_os("SPLAT4D_KEEP_SHOTS") {
            let _ = std::fs::copy(png, Path::new(&keep).join(png.file_name().unwrap()));
        }
        let c = census(&img);
        eprintln!("frame {frame}: {c:?} (lit, red, blue pixels)");
        results.push((img, c));
    }
    let total = {
        let (w, h) = results[0].0.dimensions();
        (w * h) as usize
    };
    let ((a, ca), (b, cb)) = (&results[0], &results[1]);
    assert!(
        ca.0 > total / 20 && cb.0 > total / 20,
        "canvas looks blank: {ca:?} {cb:?}"
    );
    // Early: the red blob, no blue one; late: the other way round.
    assert!(
        ca.1 > 500 && ca.2 < ca.1 / 10,
        "frame 0 should show red: {ca:?}"
    );
    assert!(
        cb.2 > 500 && cb.1 < cb.2 / 10,
        "frame 4 should show blue: {cb:?}"
    );
    let diff: u64 = a
        .pixels()
        .zip(b.pixels())
        .map(|(p, q)| {
            (0..3)
                .map(|k| (p.0[k] as i64 - q.0[k] as i64).unsigned_abs())
                .sum::<u64>()
        })
        .sum();
    assert!(
        diff as f64 / total as f64 > 5.0,
        "screenshots barely differ: {diff}"
    );
}
