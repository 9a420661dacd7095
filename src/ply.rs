//! A small reader/writer for the point clouds of the `init` stage (`points.ply`): binary
//! little-endian PLY, one `vertex` element with `x y z` (float or double), `red green
//! blue` (uchar) and an optional `t` (float or double); other vertex properties are
//! skipped. Any other layout is a typed error, never a panic.

use crate::init::PointCloud;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Why a `points.ply` could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    #[error("cannot access point cloud {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path} is not a supported PLY point cloud: {reason}; write it as binary little-endian with x y z red green blue [t]"
    )]
    Format { path: PathBuf, reason: String },
    #[error(
        "{path} is truncated: {expected} vertex bytes expected, {found} present; rerun the init stage"
    )]
    Truncated {
        path: PathBuf,
        expected: u64,
        found: u64,
    },
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Kind {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn read(self, b: &[u8]) -> f64 {
        match self {
            Self::I8 => b[0] as i8 as f64,
            Self::U8 => b[0] as f64,
            Self::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Self::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Self::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Self::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Self::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Self::F64 => f64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])),
        }
    }
}

/// Read `points.ply`.
pub fn read_points_ply(path: &Path) -> Result<PointCloud, PlyError> {
    let bytes = std::fs::read(path).map_err(|source| PlyError::Io {
        path: path.into(),
        source,
    })?;
    parse_points_ply(&bytes).map_err(|e| match e {
        ParseError::Format(reason) => PlyError::Format {
            path: path.into(),
            reason,
        },
        ParseError::Truncated(expected, found) => PlyError::Truncated {
            path: path.into(),
            expected,
            found,
        },
    })
}

enum ParseError {
    Format(String),
    Truncated(u64, u64),
}

fn parse_points_ply(bytes: &[u8]) -> Result<PointCloud, ParseError> {
    let fmt = |s: &str| ParseError::Format(s.to_string());
    let end = find(bytes, b"end_header\n").ok_or_else(|| fmt("no `end_header` line"))?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| fmt("header is not text"))?;
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(fmt("missing `ply` magic"));
    }
    let mut count: Option<u64> = None;
    let mut in_vertex = false;
    let mut props: Vec<(String, Kind)> = Vec::new();
    let mut format_ok = false;
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", "binary_little_endian", _] => format_ok = true,
            ["format", f, ..] => {
                return Err(ParseError::Format(format!("format `{f}` is not supported")));
            }
            ["element", "vertex", n] => {
                if count.is_some() {
                    return Err(fmt("two vertex elements"));
                }
                count = Some(n.parse().map_err(|_| fmt("bad vertex count"))?);
                in_vertex = true;
            }
            ["element", name, n] => {
                if count.is_none() || n.parse::<u64>().ok() != Some(0) {
                    return Err(ParseError::Format(format!(
                        "element `{name}` before or after the vertices"
                    )));
                }
                in_vertex = false;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(fmt("list properties on vertices"));
            }
            ["property", ty, name] if in_vertex => {
                let k = Kind::parse(ty)
                    .ok_or_else(|| ParseError::Format(format!("unknown type `{ty}`")))?;
                props.push((name.to_string(), k));
            }
            _ => {}
        }
    }
    if !format_ok {
        return Err(fmt("no `format binary_little_endian 1.0` line"));
    }
    let n = count.ok_or_else(|| fmt("no vertex element"))?;
    let find_prop = |name: &str| props.iter().position(|(p, _)| p == name);
    let mut offsets = Vec::with_capacity(props.len());
    let mut stride = 0usize;
    for (_, k) in &props {
        offsets.push(stride);
        stride += k.size();
    }
    let need = |name: &str| {
        find_prop(name).ok_or_else(|| ParseError::Format(format!("no `{name}` property")))
    };
    let xyz_idx = [need("x")?, need("y")?, need("z")?];
    let rgb_idx = [need("red")?, need("green")?, need("blue")?];
    let t_idx = find_prop("t");
    let body = &bytes[end + b"end_header\n".len()..];
    let expected = n.saturating_mul(stride as u64);
    if (body.len() as u64) < expected {
        return Err(ParseError::Truncated(expected, body.len() as u64));
    }
    let n = n as usize;
    let mut cloud = PointCloud {
        xyz: Vec::with_capacity(n),
        rgb: Vec::with_capacity(n),
        time: t_idx.map(|_| Vec::with_capacity(n)),
    };
    let get = |row: &[u8], i: usize| props[i].1.read(&row[offsets[i]..]);
    for row in body.chunks_exact(stride.max(1)).take(n) {
        cloud.xyz.push(xyz_idx.map(|i| get(row, i) as f32));
        cloud
            .rgb
            .push(rgb_idx.map(|i| get(row, i).clamp(0.0, 255.0) as u8));
        if let (Some(t), Some(i)) = (cloud.time.as_mut(), t_idx) {
            t.push(get(row, i) as f32);
        }
    }
    Ok(cloud)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Write `cloud` as binary little-endian PLY (`x y z` float, `red green blue` uchar,
/// `t` float when present), atomically through `<path>.tmp`.
pub fn write_points_ply(cloud: &PointCloud, path: &Path) -> Result<(), PlyError> {
    let io = |source| PlyError::Io {
        path: path.into(),
        source,
    };
    let mut buf = Vec::new();
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n",
        cloud.xyz.len()
    );
    if cloud.time.is_some() {
        header.push_str("property float t\n");
    }
    header.push_str("end_header\n");
    buf.extend_from_slice(header.as_bytes());
    for i in 0..cloud.xyz.len() {
        cloud.xyz[i]
            .iter()
            .for_each(|v| buf.extend_from_slice(&v.to_le_bytes()));
        buf.extend_from_slice(&cloud.rgb.get(i).copied().unwrap_or([0; 3]));
        if let Some(t) = &cloud.time {
            buf.extend_from_slice(&t.get(i).copied().unwrap_or(0.0).to_le_bytes());
        }
    }
    let tmp = path.with_extension("ply.tmp");
    let mut f = std::fs::File::create(&tmp).map_err(io)?;
    f.write_all(&buf).map_err(io)?;
    f.sync_all().map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_and_without_time() {
        let dir = tempfile::tempdir().unwrap();
        for time in [None, Some(vec![0.5, 1.5])] {
            let c = PointCloud {
                xyz: vec![[1.0, 2.0, 3.0], [-1.0, 0.5, 9.0]],
                rgb: vec![[1, 2, 3], [250, 0, 7]],
                time,
            };
            let p = dir.path().join("points.ply");
            write_points_ply(&c, &p).unwrap();
            assert_eq!(read_points_ply(&p).unwrap(), c);
        }
    }

    #[test]
    fn truncated_and_ascii_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("points.ply");
        let c = PointCloud {
            xyz: vec![[1.0, 2.0, 3.0]; 4],
            rgb: vec![[1, 2, 3]; 4],
            time: None,
        };
        write_points_ply(&c, &p).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 3]).unwrap();
        assert!(matches!(
            read_points_ply(&p),
            Err(PlyError::Truncated { .. })
        ));
        std::fs::write(&p, b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n").unwrap();
        assert!(matches!(read_points_ply(&p), Err(PlyError::Format { .. })));
    }
}
