//! Point clouds with colour and optional model time, as the `init` stage writes them
//! (`points.ply`) and the poses stage writes COLMAP's sparse points (`points3d.ply`):
//! `x y z` float, `red green blue` uchar, an optional `t` float and an optional
//! `time_span` float, through the one PLY codec ([`crate::ply`]). Reading takes `x y z`,
//! `t` and `time_span` of any scalar type and skips other properties. Any other layout is a typed error naming the file, never a panic.

use crate::ply::{PlyFormatError, PlyTable, Scalar};
use std::path::{Path, PathBuf};

/// Points with colour and optional model time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    pub xyz: Vec<[f32; 3]>,
    pub rgb: Vec<[u8; 3]>,
    /// Model time of each point, when the points come from per-frame point maps.
    pub time: Option<Vec<f32>>,
    /// How long each point was seen, in model time (PLY column `time_span`): 0 for a point
    /// seen at one moment; for a static point, the span of the moments it was seen at, its
    /// `time` then being the span's centre. `None` when the source does not say.
    pub time_span: Option<Vec<f32>>,
}

/// Why a point-cloud PLY could not be read or written.
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
        "{path} is truncated: {expected} vertex bytes expected, {found} present; rerun the stage that wrote it"
    )]
    Truncated {
        path: PathBuf,
        expected: u64,
        found: u64,
    },
}

/// Read a point-cloud PLY.
pub fn read_points_ply(path: &Path) -> Result<PointCloud, PlyError> {
    let bytes = std::fs::read(path).map_err(|source| PlyError::Io {
        path: path.into(),
        source,
    })?;
    let format = |reason: String| PlyError::Format {
        path: path.into(),
        reason,
    };
    let table = PlyTable::decode(&bytes).map_err(|e| match e {
        PlyFormatError::Layout(reason) => format(reason),
        PlyFormatError::Truncated { expected, found } => PlyError::Truncated {
            path: path.into(),
            expected,
            found,
        },
    })?;
    let need = |name: &str| {
        table
            .column(name)
            .ok_or_else(|| format(format!("no `{name}` property")))
    };
    let xyz = [need("x")?, need("y")?, need("z")?];
    let rgb = [need("red")?, need("green")?, need("blue")?];
    let t = table.column("t");
    let span = table.column("time_span");
    let rows = table.data.chunks_exact(table.names.len().max(1));
    Ok(PointCloud {
        xyz: rows.clone().map(|r| xyz.map(|i| r[i])).collect(),
        rgb: rows
            .clone()
            .map(|r| rgb.map(|i| r[i].clamp(0.0, 255.0) as u8))
            .collect(),
        time: t.map(|i| rows.clone().map(|r| r[i]).collect()),
        time_span: span.map(|i| rows.map(|r| r[i]).collect()),
    })
}

/// The PLY table of `cloud` (`x y z` float, `red green blue` uchar, `t` and `time_span`
/// float when present), with `comments` in its header.
pub fn points_table(cloud: &PointCloud, comments: Vec<String>) -> PlyTable {
    let mut names: Vec<String> = ["x", "y", "z", "red", "green", "blue"]
        .map(String::from)
        .to_vec();
    let mut types = vec![
        Scalar::F32,
        Scalar::F32,
        Scalar::F32,
        Scalar::U8,
        Scalar::U8,
        Scalar::U8,
    ];
    if cloud.time.is_some() {
        names.push("t".into());
        types.push(Scalar::F32);
    }
    if cloud.time_span.is_some() {
        names.push("time_span".into());
        types.push(Scalar::F32);
    }
    let mut data = Vec::with_capacity(names.len() * cloud.xyz.len());
    for (i, p) in cloud.xyz.iter().enumerate() {
        data.extend_from_slice(p);
        data.extend(cloud.rgb.get(i).copied().unwrap_or([0; 3]).map(f32::from));
        if let Some(t) = &cloud.time {
            data.push(t.get(i).copied().unwrap_or(0.0));
        }
        if let Some(s) = &cloud.time_span {
            data.push(s.get(i).copied().unwrap_or(0.0));
        }
    }
    PlyTable {
        comments,
        names,
        types,
        data,
    }
}

/// Write `cloud` as a point-cloud PLY, atomically.
pub fn write_points_ply(cloud: &PointCloud, path: &Path) -> Result<(), PlyError> {
    crate::atomic::write_atomic(path, &points_table(cloud, Vec::new()).encode()).map_err(|source| {
        PlyError::Io {
            path: path.into(),
            source,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_and_without_time_and_span() {
        let dir = tempfile::tempdir().unwrap();
        let times = [None, Some(vec![0.5, 1.5])];
        let spans = [None, Some(vec![0.0, 2.25])];
        for (time, time_span) in times.iter().flat_map(|t| spans.iter().map(move |s| (t, s))) {
            let c = PointCloud {
                xyz: vec![[1.0, 2.0, 3.0], [-1.0, 0.5, 9.0]],
                rgb: vec![[1, 2, 3], [250, 0, 7]],
                time: time.clone(),
                time_span: time_span.clone(),
            };
            let p = dir.path().join("points.ply");
            write_points_ply(&c, &p).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            let header = String::from_utf8_lossy(&bytes[..bytes.len().min(300)]).into_owned();
            assert_eq!(
                header.contains("property float time_span"),
                time_span.is_some()
            );
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
            time_span: None,
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
