//! COLMAP's text model files (`cameras.txt`, `images.txt`, `points3D.txt`), as written by
//! `colmap model_converter --output_type TXT`:
//!
//! - cameras: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`, one line each.
//! - images: two lines each: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then
//!   `POINTS2D[]` as `X Y POINT3D_ID` triples (`-1` for none; the line may be empty).
//! - points3D: `POINT3D_ID X Y Z R G B ERROR TRACK[]` with `IMAGE_ID POINT2D_IDX` pairs.
//!
//! `#` lines are comments. Numbers are written in Rust's shortest round-trip form, so a
//! text model reads back bit-identical.

use std::fmt::Write as _;
use std::path::Path;
use std::str::{FromStr, SplitWhitespace};

use super::{
    ColmapCamera, ColmapImage, ColmapPoint3D, INVALID_POINT3D_ID, ModelError, Point2D, TrackElement,
};

pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>, ModelError> {
    read_lines(path, |f| {
        let id = f.next("CAMERA_ID")?;
        let model_name: String = f.next("MODEL")?;
        let model = model_name
            .parse()
            .map_err(|_| ModelError::UnknownCameraModel {
                path: path.to_path_buf(),
                model: model_name,
            })?;
        let width = f.next("WIDTH")?;
        let height = f.next("HEIGHT")?;
        let params: Vec<f64> = f.rest("PARAMS")?;
        ColmapCamera::new(id, model, width, height, params.clone()).ok_or(ModelError::ParamCount {
            path: path.to_path_buf(),
            camera_id: id,
            model: model.name(),
            got: params.len(),
            expected: model.num_params(),
        })
    })
}

pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>, ModelError> {
    let text = read(path)?;
    let mut lines = text.lines().enumerate();
    let mut out = Vec::new();
    while let Some((n, line)) = lines.next() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut f = Fields {
            it: line.split_whitespace(),
            path,
            line: n + 1,
        };
        let id = f.next("IMAGE_ID")?;
        let qvec = [f.next("QW")?, f.next("QX")?, f.next("QY")?, f.next("QZ")?];
        let tvec = [f.next("TX")?, f.next("TY")?, f.next("TZ")?];
        let camera_id = f.next("CAMERA_ID")?;
        let name = f.it.collect::<Vec<_>>().join(" ");
        if name.is_empty() {
            return Err(malformed(path, n + 1, "missing NAME"));
        }
        // The POINTS2D line always follows, even when empty.
        let (n2, points_line) = lines.next().map(|(n, l)| (n + 1, l)).unwrap_or((n + 2, ""));
        let mut g = Fields {
            it: points_line.split_whitespace(),
            path,
            line: n2,
        };
        let tokens: Vec<&str> = g.it.by_ref().collect();
        if !tokens.len().is_multiple_of(3) {
            return Err(malformed(
                path,
                n2,
                "POINTS2D is not a list of X Y POINT3D_ID triples",
            ));
        }
        let mut points2d = Vec::with_capacity(tokens.len() / 3);
        for c in tokens.chunks_exact(3) {
            let num = |t: &str| {
                t.parse::<f64>()
                    .map_err(|_| malformed(path, n2, &format!("POINTS2D: {t:?} is not a number")))
            };
            let point3d_id = if c[2] == "-1" {
                INVALID_POINT3D_ID
            } else {
                c[2].parse().map_err(|_| {
                    malformed(path, n2, &format!("POINT3D_ID {:?} is not an ID", c[2]))
                })?
            };
            points2d.push(Point2D {
                xy: [num(c[0])?, num(c[1])?],
                point3d_id,
            });
        }
        out.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
    }
    Ok(out)
}

pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint3D>, ModelError> {
    read_lines(path, |f| {
        let id = f.next("POINT3D_ID")?;
        let xyz = [f.next("X")?, f.next("Y")?, f.next("Z")?];
        let rgb = [f.next("R")?, f.next("G")?, f.next("B")?];
        let error = f.next("ERROR")?;
        let track: Vec<u32> = f.rest("TRACK")?;
        if !track.len().is_multiple_of(2) {
            return Err(malformed(
                path,
                f.line,
                "TRACK is not a list of IMAGE_ID POINT2D_IDX pairs",
            ));
        }
        let track = track
            .chunks_exact(2)
            .map(|c| TrackElement {
                image_id: c[0],
                point2d_idx: c[1],
            })
            .collect();
        Ok(ColmapPoint3D {
            id,
            xyz,
            rgb,
            error,
            track,
        })
    })
}

pub fn cameras_to_text<'a>(cameras: impl ExactSizeIterator<Item = &'a ColmapCamera>) -> String {
    let mut s = String::new();
    s.push_str("# Camera list with one line of data per camera:\n");
    s.push_str("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    let _ = writeln!(s, "# Number of cameras: {}", cameras.len());
    for c in cameras {
        let _ = write!(s, "{} {} {} {}", c.id, c.model.name(), c.width, c.height);
        c.params.iter().for_each(|p| {
            let _ = write!(s, " {p}");
        });
        s.push('\n');
    }
    s
}

pub fn images_to_text<'a>(
    images: impl ExactSizeIterator<Item = &'a ColmapImage> + Clone,
) -> String {
    let n = images.len();
    let observations: usize = images.clone().map(|i| i.num_observations()).sum();
    let mean = if n == 0 {
        0.0
    } else {
        observations as f64 / n as f64
    };
    let mut s = String::new();
    s.push_str("# Image list with two lines of data per image:\n");
    s.push_str("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n");
    s.push_str("#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
    let _ = writeln!(
        s,
        "# Number of images: {n}, mean observations per image: {mean}"
    );
    for i in images {
        let [qw, qx, qy, qz] = i.qvec;
        let [tx, ty, tz] = i.tvec;
        let _ = writeln!(
            s,
            "{} {qw} {qx} {qy} {qz} {tx} {ty} {tz} {} {}",
            i.id, i.camera_id, i.name
        );
        let mut first = true;
        for p in &i.points2d {
            if !first {
                s.push(' ');
            }
            first = false;
            if p.point3d_id == INVALID_POINT3D_ID {
                let _ = write!(s, "{} {} -1", p.xy[0], p.xy[1]);
            } else {
                let _ = write!(s, "{} {} {}", p.xy[0], p.xy[1], p.point3d_id);
            }
        }
        s.push('\n');
    }
    s
}

pub fn points3d_to_text<'a>(
    points: impl ExactSizeIterator<Item = &'a ColmapPoint3D> + Clone,
) -> String {
    let n = points.len();
    let track_sum: usize = points.clone().map(|p| p.track.len()).sum();
    let mean = if n == 0 {
        0.0
    } else {
        track_sum as f64 / n as f64
    };
    let mut s = String::new();
    s.push_str("# 3D point list with one line of data per point:\n");
    s.push_str("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    let _ = writeln!(s, "# Number of points: {n}, mean track length: {mean}");
    for p in points {
        let [x, y, z] = p.xyz;
        let [r, g, b] = p.rgb;
        let _ = write!(s, "{} {x} {y} {z} {r} {g} {b} {}", p.id, p.error);
        for t in &p.track {
            let _ = write!(s, " {} {}", t.image_id, t.point2d_idx);
        }
        s.push('\n');
    }
    s
}

fn read(path: &Path) -> Result<String, ModelError> {
    std::fs::read_to_string(path).map_err(|source| ModelError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Non-comment, non-empty lines with their 1-based line numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// One item per data line of the file at `path` (blank and `#` lines skipped), each parsed
/// by `item` from the line's fields.
fn read_lines<T>(
    path: &Path,
    mut item: impl FnMut(&mut Fields) -> Result<T, ModelError>,
) -> Result<Vec<T>, ModelError> {
    let text = read(path)?;
    data_lines(&text)
        .map(|(line, text)| {
            item(&mut Fields {
                it: text.split_whitespace(),
                path,
                line,
            })
        })
        .collect()
}

fn malformed(path: &Path, line: usize, what: &str) -> ModelError {
    ModelError::Malformed {
        path: path.to_path_buf(),
        what: format!("line {line}: {what}"),
    }
}

/// Whitespace-separated fields of one line, parsed with errors naming file, line and field.
struct Fields<'a> {
    it: SplitWhitespace<'a>,
    path: &'a Path,
    line: usize,
}

impl Fields<'_> {
    fn next<T: FromStr>(&mut self, field: &str) -> Result<T, ModelError> {
        let tok = self
            .it
            .next()
            .ok_or_else(|| malformed(self.path, self.line, &format!("missing {field}")))?;
        tok.parse().map_err(|_| {
            malformed(
                self.path,
                self.line,
                &format!("{field} {tok:?} is not a valid number"),
            )
        })
    }
    fn rest<T: FromStr>(&mut self, field: &str) -> Result<Vec<T>, ModelError> {
        self.it
            .by_ref()
            .map(|tok| {
                tok.parse().map_err(|_| {
                    malformed(
                        self.path,
                        self.line,
                        &format!("{field}: {tok:?} is not a number"),
                    )
                })
            })
            .collect()
    }
}
