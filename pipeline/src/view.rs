//! `pipeline view`: the browser viewers the export stage wrote (`work/export/viewer/`),
//! served over HTTP on 127.0.0.1, because a browser does not let a page opened from
//! `file://` read its model. One capture is served at `/`; several each under
//! `/<n>-<folder name>/`, with a page at `/` that links them. A small static file server:
//! GET and HEAD, the MIME types the viewer needs, nothing outside the viewer folders.

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;

/// The port `pipeline view` tries first.
pub const DEFAULT_PORT: u16 = 8765;

/// One capture's viewer on the site.
#[derive(Clone, Debug, PartialEq)]
pub struct Viewer {
    /// URL path it is served under: `/`, or `/1-take01/`.
    pub prefix: String,
    /// Its `work/export/viewer/` folder.
    pub dir: PathBuf,
    /// The capture folder's name.
    pub name: String,
}

/// What the server serves.
#[derive(Clone, Debug, PartialEq)]
pub struct Site {
    pub viewers: Vec<Viewer>,
}

/// A capture's exported viewer folder; an error naming it and the command that writes it
/// when there is none.
pub fn viewer_dir(capture_dir: &Path) -> anyhow::Result<PathBuf> {
    let dir = capture_dir.join("work").join("export").join("viewer");
    if !dir.join("index.html").is_file() {
        anyhow::bail!(
            "{} holds no exported viewer; run `pipeline run {} --to export` (with [export] viewer = true, the default) first",
            dir.display(),
            capture_dir.display()
        );
    }
    Ok(dir)
}

impl Site {
    /// The viewers of `capture_dirs`: one at `/`, several each under its own path.
    pub fn of(capture_dirs: &[PathBuf]) -> anyhow::Result<Self> {
        let viewers = capture_dirs
            .iter()
            .enumerate()
            .map(|(i, capture)| {
                let dir = viewer_dir(capture)?;
                let name = capture
                    .canonicalize()
                    .unwrap_or_else(|_| capture.clone())
                    .file_name()
                    .map_or_else(|| "capture".into(), |n| n.to_string_lossy().into_owned());
                let prefix = if capture_dirs.len() == 1 {
                    "/".to_string()
                } else {
                    let slug: String = name
                        .chars()
                        .map(|c| {
                            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                                c
                            } else {
                                '-'
                            }
                        })
                        .collect();
                    format!("/{}-{slug}/", i + 1)
                };
                Ok(Viewer { prefix, dir, name })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(Self { viewers })
    }

    /// The file a request path names, `None` for a path outside every viewer folder.
    /// `Some(None)` is the index page of several captures.
    fn resolve(&self, path: &str) -> Option<Option<PathBuf>> {
        let path = percent_decode(path)?;
        if self.viewers.len() > 1 && path == "/" {
            return Some(None);
        }
        let viewer = self.viewers.iter().find(|v| path.starts_with(&v.prefix))?;
        let rest = &path[viewer.prefix.len()..];
        let relative = Path::new(rest);
        if !relative
            .components()
            .all(|c| matches!(c, Component::Normal(_)))
        {
            return None;
        }
        let mut file = viewer.dir.join(relative);
        if rest.is_empty() || rest.ends_with('/') {
            file = file.join("index.html");
        }
        Some(Some(file))
    }

    /// The page that links every capture's viewer.
    fn index_page(&self) -> String {
        let items: String = self
            .viewers
            .iter()
            .map(|v| {
                format!(
                    "<li><a href=\"{}\">{}</a> <small>{}</small></li>\n",
                    v.prefix,
                    html_escape(&v.name),
                    html_escape(&v.dir.display().to_string())
                )
            })
            .collect();
        format!(
            "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>4C4D captures</title></head>\n<body><h1>Captures</h1>\n<ul>\n{items}</ul></body></html>\n"
        )
    }
}

/// A bound server.
pub struct Server {
    listener: TcpListener,
    site: Arc<Site>,
}

impl Server {
    /// Listen on 127.0.0.1:`port`; `None` takes [`DEFAULT_PORT`], or any free port when
    /// that one is taken; 0 takes any free port.
    pub fn bind(site: Site, port: Option<u16>) -> anyhow::Result<Self> {
        let listener = match port {
            Some(p) => TcpListener::bind(("127.0.0.1", p)).with_context(|| {
                format!("cannot listen on 127.0.0.1:{p}; choose another --port")
            })?,
            None => TcpListener::bind(("127.0.0.1", DEFAULT_PORT))
                .or_else(|_| TcpListener::bind(("127.0.0.1", 0)))
                .context("cannot listen on 127.0.0.1")?,
        };
        Ok(Self {
            listener,
            site: Arc::new(site),
        })
    }

    pub fn address(&self) -> anyhow::Result<SocketAddr> {
        Ok(self.listener.local_addr()?)
    }

    /// The URL of the site's front page.
    pub fn url(&self) -> anyhow::Result<String> {
        Ok(format!("http://{}/", self.address()?))
    }

    /// Answer requests (each on its own thread) until `stop` says so; it is asked a few
    /// times a second.
    pub fn serve_until(self, stop: impl Fn() -> bool) -> anyhow::Result<()> {
        self.listener.set_nonblocking(true)?;
        while !stop() {
            match self.listener.accept() {
                Ok((stream, _)) => {
                    let site = self.site.clone();
                    std::thread::spawn(move || {
                        let _ = respond(stream, &site);
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => return Err(e).context("the viewer server stopped"),
            }
        }
        Ok(())
    }
}

/// The `Content-Type` of a file the viewer folder holds.
pub fn mime_type(path: &Path) -> &'static str {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("json") => "application/json",
        Some("png") => "image/png",
        Some("jpg" | "jpeg") => "image/jpeg",
        Some("svg") => "image/svg+xml",
        Some("wasm") => "application/wasm",
        Some("glb") => "model/gltf-binary",
        Some("txt") => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}

fn respond(mut stream: TcpStream, site: &Site) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut reader = BufReader::new(stream.try_clone()?);
    let mut request = String::new();
    reader.read_line(&mut request)?;
    loop {
        let mut header = String::new();
        if reader.read_line(&mut header)? == 0 || header == "\r\n" || header == "\n" {
            break;
        }
    }
    let mut words = request.split_whitespace();
    let (method, target) = (words.next().unwrap_or(""), words.next().unwrap_or("/"));
    let path = target.split(['?', '#']).next().unwrap_or("/");
    let (status, mime, body) = if method != "GET" && method != "HEAD" {
        (
            "405 Method Not Allowed",
            "text/plain",
            b"GET or HEAD only\n".to_vec(),
        )
    } else {
        match site.resolve(path) {
            Some(None) => (
                "200 OK",
                "text/html; charset=utf-8",
                site.index_page().into_bytes(),
            ),
            Some(Some(file)) => match std::fs::read(&file) {
                Ok(body) => ("200 OK", mime_type(&file), body),
                Err(_) => ("404 Not Found", "text/plain", b"not found\n".to_vec()),
            },
            None => ("404 Not Found", "text/plain", b"not found\n".to_vec()),
        }
    };
    write!(
        stream,
        "HTTP/1.1 {status}\r\nContent-Type: {mime}\r\nContent-Length: {}\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    if method != "HEAD" {
        stream.write_all(&body)?;
    }
    stream.flush()
}

/// `%XX` escapes decoded; `None` when they do not make UTF-8.
fn percent_decode(path: &str) -> Option<String> {
    let bytes = path.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            let hex = std::str::from_utf8(&bytes[i + 1..i + 3]).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

fn html_escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Open `url` in the system's browser, when there is one to open; whether it was asked.
pub fn open_browser(url: &str) -> bool {
    let command = if cfg!(target_os = "macos") {
        Some(("open", vec![url.to_string()]))
    } else if cfg!(target_os = "windows") {
        Some((
            "cmd",
            vec!["/C".into(), "start".into(), String::new(), url.to_string()],
        ))
    } else if std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some()
    {
        Some(("xdg-open", vec![url.to_string()]))
    } else {
        None
    };
    command.is_some_and(|(program, args)| {
        std::process::Command::new(program)
            .args(args)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .is_ok()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn capture_with_viewer(root: &Path, name: &str) -> PathBuf {
        let capture = root.join(name);
        let viewer = capture.join("work/export/viewer");
        std::fs::create_dir_all(&viewer).unwrap();
        std::fs::write(viewer.join("index.html"), format!("<p>{name}</p>")).unwrap();
        std::fs::write(viewer.join("model.4dgs"), [1u8, 2, 3]).unwrap();
        std::fs::write(root.join("secret.txt"), "no").unwrap();
        capture
    }

    fn get(url: &str, path: &str) -> (String, Vec<u8>) {
        let address = url.trim_start_matches("http://").trim_end_matches('/');
        let mut stream = TcpStream::connect(address).unwrap();
        write!(stream, "GET {path} HTTP/1.1\r\nHost: {address}\r\n\r\n").unwrap();
        let mut all = Vec::new();
        std::io::Read::read_to_end(&mut stream, &mut all).unwrap();
        let split = all.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        (
            String::from_utf8_lossy(&all[..split]).into_owned(),
            all[split + 4..].to_vec(),
        )
    }

    #[test]
    fn one_capture_is_served_at_the_root_with_its_types_and_nothing_else() {
        let tmp = tempfile::tempdir().unwrap();
        let capture = capture_with_viewer(tmp.path(), "take01");
        let server = Server::bind(Site::of(&[capture]).unwrap(), Some(0)).unwrap();
        let url = server.url().unwrap();
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            server.serve_until(|| flag.load(std::sync::atomic::Ordering::SeqCst))
        });
        let (head, body) = get(&url, "/");
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        assert!(head.contains("Content-Type: text/html"), "{head}");
        assert_eq!(body, b"<p>take01</p>");
        let (head, body) = get(&url, "/model.4dgs?v=1");
        assert!(head.contains("application/octet-stream"), "{head}");
        assert_eq!(body, [1, 2, 3]);
        for outside in [
            "/../../secret.txt",
            "/%2e%2e/%2e%2e/secret.txt",
            "/missing.js",
        ] {
            let (head, _) = get(&url, outside);
            assert!(head.starts_with("HTTP/1.1 404"), "{outside}: {head}");
        }
        stop.store(true, std::sync::atomic::Ordering::SeqCst);
        thread.join().unwrap().unwrap();
    }

    #[test]
    fn several_captures_each_get_a_path_and_an_index_links_them() {
        let tmp = tempfile::tempdir().unwrap();
        let a = capture_with_viewer(tmp.path(), "take 01");
        let b = capture_with_viewer(tmp.path(), "take02");
        let site = Site::of(&[a, b]).unwrap();
        let prefixes: Vec<&str> = site.viewers.iter().map(|v| v.prefix.as_str()).collect();
        assert_eq!(prefixes, ["/1-take-01/", "/2-take02/"]);
        assert_eq!(site.resolve("/"), Some(None));
        assert!(
            site.index_page()
                .contains("<a href=\"/2-take02/\">take02</a>")
        );
        assert_eq!(
            site.resolve("/2-take02/"),
            Some(Some(site.viewers[1].dir.join("index.html")))
        );
        assert_eq!(site.resolve("/3-other/index.html"), None);
    }

    #[test]
    fn a_capture_without_an_export_is_named_with_the_command_that_makes_one() {
        let tmp = tempfile::tempdir().unwrap();
        let err = Site::of(&[tmp.path().join("take03")])
            .unwrap_err()
            .to_string();
        assert!(err.contains("take03/work/export/viewer"), "{err}");
        assert!(err.contains("--to export"), "{err}");
    }

    #[test]
    fn file_types() {
        assert_eq!(
            mime_type(Path::new("a/index.html")),
            "text/html; charset=utf-8"
        );
        assert_eq!(
            mime_type(Path::new("viewer.JS")),
            "text/javascript; charset=utf-8"
        );
        assert_eq!(mime_type(Path::new("backdrop.png")), "image/png");
        assert_eq!(mime_type(Path::new("scene.json")), "application/json");
        assert_eq!(
            mime_type(Path::new("model.4dgs")),
            "application/octet-stream"
        );
        assert_eq!(percent_decode("/a%20b").as_deref(), Some("/a b"));
        assert_eq!(percent_decode("/%zz"), None);
    }
}
