//! Driving the exported browser viewer in Debian's headless Chromium (playwright-core,
//! SwiftShader WebGL) and comparing what it shows with the engine's own render. Shared by
//! `tests/integration/viewer_browser.rs` and the pipeline's `viewer_demo` check on a trained demo
//! capture (`#[path]`-included there).
#![allow(dead_code)] // each test binary uses a different part of this module

use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use splat4d::{Camera, Gaussians, RenderBackend, RenderOptions};

pub const CHROMIUM: &str = "/usr/bin/chromium";

pub fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true" || v == "1")
}

/// Skip (return `true`) with a message, or fail under CI.
pub fn skip(why: &str) -> bool {
    if in_ci() {
        panic!("viewer browser test cannot run under CI=true: {why}; run scripts/setup.sh");
    }
    eprintln!("SKIPPED viewer browser test: {why}");
    true
}

/// What a browser test needs: Node.js, the screenshot script, the built viewer bundle.
pub struct Browser {
    pub node: PathBuf,
    pub script: PathBuf,
    pub bundle: PathBuf,
}

impl Browser {
    /// Everything a browser test needs, or `None` (after printing why) when something is
    /// missing; under `CI=true` a missing piece fails the test instead.
    pub fn find() -> Option<Browser> {
        let project = Path::new(env!("CARGO_MANIFEST_DIR"));
        // The viewer project of the checkout under test (test binaries may live in a
        // shared target folder whose ancestors hold another checkout's bundle).
        let project = if project.join("viewer").is_dir() {
            project.join("viewer")
        } else {
            project.join("../viewer")
        };
        if !Path::new(CHROMIUM).exists() && skip("/usr/bin/chromium is not installed") {
            return None;
        }
        let own = project.join("dist");
        let bundle = if own.join("index.html").is_file() {
            own
        } else {
            match splat4d::export::find_viewer_bundle() {
                Ok(b) => b,
                Err(e) => {
                    skip(&e.to_string());
                    return None;
                }
            }
        };
        let Some(node) = which("node") else {
            skip("node is not installed");
            return None;
        };
        if !project.join("node_modules/playwright-core").is_dir() {
            skip("viewer/node_modules/playwright-core is missing (npm ci --prefix viewer)");
            return None;
        }
        Some(Browser {
            node,
            script: project.join("test/screenshot.mjs"),
            bundle,
        })
    }

    /// Screenshots of `(url, png)` pairs in one browser session at `viewport` (width,
    /// height); panics with the script's output on failure.
    pub fn screenshots(&self, profile: &Path, viewport: (u32, u32), shots: &[(String, PathBuf)]) {
        let mut cmd = Command::new(&self.node);
        cmd.arg(&self.script)
            .arg(format!("--viewport={}x{}", viewport.0, viewport.1))
            .arg(CHROMIUM)
            .arg(profile);
        for (url, png) in shots {
            cmd.arg(url).arg(png);
        }
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start node");
        // Drain both pipes while waiting, so a chatty page cannot block the script.
        let (mut out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
        let out_t = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = std::io::Read::read_to_string(&mut out, &mut s);
            s
        });
        let err_t = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = std::io::Read::read_to_string(&mut err, &mut s);
            s
        });
        let start = Instant::now();
        let limit = Duration::from_secs(150 + 60 * shots.len() as u64);
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break Some(status);
            }
            if start.elapsed() > limit {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        let log = format!("{}{}", out_t.join().unwrap(), err_t.join().unwrap());
        eprintln!("{log}");
        assert!(
            status.is_some_and(|s| s.success()),
            "screenshot script failed (or ran over {limit:?}):\n{log}"
        );
    }
}

pub fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|d| Path::new(d).join(name))
        .find(|p| p.is_file())
}

/// A tiny static file server for `root` on 127.0.0.1 (one thread per connection).
pub fn serve(root: PathBuf) -> u16 {
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
        Some("css") => "text/css",
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

/// The engine's render of `model` from `camera` at model time `t` (CPU backend, black
/// background), as 8-bit RGB.
pub fn engine_render(
    model: &Gaussians<f32>,
    camera: &Camera,
    t: f64,
    background: [f32; 3],
) -> image::RgbImage {
    let options = RenderOptions {
        background,
        ..RenderOptions::default()
    };
    let r = splat4d::CpuBackend
        .render(model, camera, t as f32, &options)
        .expect("engine render");
    let px = r
        .rgb
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    image::RgbImage::from_raw(r.width, r.height, px).unwrap()
}

/// PSNR in dB of two 8-bit RGB images of one size.
pub fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions(), "image sizes");
    let f = |img: &image::RgbImage| -> Vec<f32> {
        img.as_raw().iter().map(|&v| v as f32 / 255.0).collect()
    };
    let (w, h) = a.dimensions();
    splat4d::metrics::image_metrics(&f(a), &f(b), w as usize, h as usize)
        .expect("metrics")
        .psnr
}

/// Images next to each other, left to right (same height).
pub fn side_by_side(images: &[&image::RgbImage]) -> image::RgbImage {
    let h = images.iter().map(|i| i.height()).max().unwrap_or(0);
    let w = images.iter().map(|i| i.width()).sum();
    let mut out = image::RgbImage::new(w, h);
    let mut x0 = 0;
    for img in images {
        for (x, y, p) in img.enumerate_pixels() {
            out.put_pixel(x0 + x, y, *p);
        }
        x0 += img.width();
    }
    out
}
