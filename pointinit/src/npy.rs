//! Exported point maps on disk: `.npy` / `.npz` files holding one image pair's output of a
//! MASt3R-style model (see `docs/init.md`), read with `npyz`. Also the point-map types
//! shared by the ONNX runner and the alignment.
//!
//! Layout of a pair `(a, b)` in the point-map directory, either
//! - `a__b.npz` with arrays `pts1`, `conf1`, `pts2`, `conf2` (names configurable), or
//! - a directory `a__b/` holding `pts1.npy`, `conf1.npy`, `pts2.npy`, `conf2.npy`.
//!
//! Point maps are `H×W×3` (or `1×H×W×3`), confidences `H×W` (or `1×H×W`), `float32` or
//! `float64`, C order; both views' points are in camera `a`'s frame. A missing confidence
//! array means "all pixels confident". This module only reads and checks shapes: values
//! (NaN, scale) are judged by the alignment.

use std::path::{Path, PathBuf};

/// One view's point map: `width × height` pixels, row-major, in the pair's first camera
/// frame (arbitrary scale).
#[derive(Clone, Debug, PartialEq)]
pub struct PointMap {
    pub width: usize,
    pub height: usize,
    pub points: Vec<[f32; 3]>,
    /// Per-pixel confidence; `None`: every pixel is confident.
    pub confidence: Option<Vec<f32>>,
}

/// A model's output for an image pair: both views' point maps in the first view's frame.
#[derive(Clone, Debug, PartialEq)]
pub struct PairMaps {
    pub first: PointMap,
    pub second: PointMap,
}

/// Array names inside a pair's `.npz` / directory (also the ONNX output names).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputNames {
    pub pts1: String,
    pub conf1: String,
    pub pts2: String,
    pub conf2: String,
}

impl Default for OutputNames {
    fn default() -> Self {
        Self {
            pts1: "pts1".into(),
            conf1: "conf1".into(),
            pts2: "pts2".into(),
            conf2: "conf2".into(),
        }
    }
}

/// Why exported point maps could not be read.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("cannot read point map {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "point map {path}: {reason}; export float32/float64 C-order arrays, points H×W×3 and confidences H×W"
    )]
    Format { path: PathBuf, reason: String },
    #[error("{path} has no array `{name}` (it has: {found}); set [init] output_names to match")]
    MissingArray {
        path: PathBuf,
        name: String,
        found: String,
    },
    #[error("no exported point maps for pair {first}/{second}: expected {npz} or {dir}/")]
    MissingPair {
        first: String,
        second: String,
        npz: PathBuf,
        dir: PathBuf,
    },
}

/// File name stem of pair `(a, b)`: `a__b`.
pub fn pair_stem(first: &str, second: &str) -> String {
    format!("{first}__{second}")
}

/// Read pair `(first, second)` from the point-map directory `dir`.
pub fn read_pair(
    dir: &Path,
    first: &str,
    second: &str,
    names: &OutputNames,
) -> Result<PairMaps, NpyError> {
    let stem = pair_stem(first, second);
    let npz = dir.join(format!("{stem}.npz"));
    let sub = dir.join(&stem);
    if npz.is_file() {
        read_pair_npz(&npz, names)
    } else if sub.is_dir() {
        read_pair_dir(&sub, names)
    } else {
        Err(NpyError::MissingPair {
            first: first.into(),
            second: second.into(),
            npz,
            dir: sub,
        })
    }
}

/// Whether `dir` holds exported maps for pair `(first, second)`.
pub fn has_pair(dir: &Path, first: &str, second: &str) -> bool {
    let stem = pair_stem(first, second);
    dir.join(format!("{stem}.npz")).is_file() || dir.join(&stem).is_dir()
}

/// A pair stored as one `.npz` archive.
pub fn read_pair_npz(path: &Path, names: &OutputNames) -> Result<PairMaps, NpyError> {
    let io = |source| NpyError::Io {
        path: path.into(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let zip_error = |e| io(std::io::Error::new(std::io::ErrorKind::InvalidData, e));
    let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(zip_error)?;
    // numpy's savez names each array's member `NAME.npy`.
    let found = archive
        .file_names()
        .map(|n| n.strip_suffix(".npy").unwrap_or(n))
        .collect::<Vec<_>>()
        .join(", ");
    let get = |name: &str, required: bool| -> Result<Option<Array>, NpyError> {
        match archive.by_name(&format!("{name}.npy")) {
            Ok(f) => array_from(open_npy(f, path)?, path).map(Some),
            Err(zip::result::ZipError::FileNotFound) if required => Err(NpyError::MissingArray {
                path: path.into(),
                name: name.into(),
                found: found.clone(),
            }),
            Err(zip::result::ZipError::FileNotFound) => Ok(None),
            Err(e) => Err(zip_error(e)),
        }
    };
    pair_maps(names, path, get)
}

/// A pair stored as a directory of `.npy` files.
pub fn read_pair_dir(dir: &Path, names: &OutputNames) -> Result<PairMaps, NpyError> {
    let read = |name: &str, required: bool| -> Result<Option<Array>, NpyError> {
        let path = dir.join(format!("{name}.npy"));
        if !path.is_file() && !required {
            return Ok(None);
        }
        read_npy(&path).map(Some)
    };
    pair_maps(names, dir, read)
}

/// A pair's maps from its arrays, each fetched by `get(name, required)` (`None`: an
/// optional array that is absent); `origin` names the pair in errors.
fn pair_maps(
    names: &OutputNames,
    origin: &Path,
    mut get: impl FnMut(&str, bool) -> Result<Option<Array>, NpyError>,
) -> Result<PairMaps, NpyError> {
    let pts1 = get(&names.pts1, true)?.unwrap_or_default();
    let conf1 = get(&names.conf1, false)?;
    let pts2 = get(&names.pts2, true)?.unwrap_or_default();
    let conf2 = get(&names.conf2, false)?;
    Ok(PairMaps {
        first: point_map(pts1, conf1, origin)?,
        second: point_map(pts2, conf2, origin)?,
    })
}

/// A numeric array as `f32` with its shape.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Array {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Read one `.npy` file of `float32` or `float64` values.
pub fn read_npy(path: &Path) -> Result<Array, NpyError> {
    let bytes = std::fs::read(path).map_err(|source| NpyError::Io {
        path: path.into(),
        source,
    })?;
    array_from(open_npy(&bytes[..], path)?, path)
}

/// The longest array header numpy reads without being told to trust the file
/// (`numpy.lib.format`'s `max_header_size`).
const MAX_HEADER_BYTES: usize = 10_000;

/// An `.npy` stream opened by npyz, after checking the header length it declares: npyz
/// allocates whatever a damaged length field asks for (fuzz_readers found a 660 MB one).
fn open_npy<R: std::io::Read>(
    mut reader: R,
    path: &Path,
) -> Result<npyz::NpyFile<impl std::io::Read>, NpyError> {
    use std::io::Read;
    // Magic (6 bytes), version (2), header length (2 bytes in version 1, else 4).
    let mut start = Vec::with_capacity(12);
    (&mut reader)
        .take(12)
        .read_to_end(&mut start)
        .map_err(|source| NpyError::Io {
            path: path.into(),
            source,
        })?;
    if start.len() == 12 && start.starts_with(b"\x93NUMPY") {
        let declared = match start[6] {
            1 => u16::from_le_bytes([start[8], start[9]]) as usize,
            _ => u32::from_le_bytes([start[8], start[9], start[10], start[11]]) as usize,
        };
        if declared > MAX_HEADER_BYTES {
            return Err(NpyError::Format {
                path: path.into(),
                reason: format!(
                    "its array header claims {declared} bytes (numpy writes at most \
                     {MAX_HEADER_BYTES}): the file is damaged; export it again"
                ),
            });
        }
    }
    let stream = std::io::Cursor::new(start).chain(reader);
    unpanicked(path, || npyz::NpyFile::new(stream))?.map_err(|e| NpyError::Format {
        path: path.into(),
        reason: format!("not an .npy file ({e})"),
    })
}

/// `f`, a call into npyz, with its panics made errors: it multiplies a header's shape
/// unchecked, so a damaged header overflows (fuzz_readers found it).
fn unpanicked<T>(path: &Path, f: impl FnOnce() -> T) -> Result<T, NpyError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|_| NpyError::Format {
        path: path.into(),
        reason: "the array header is damaged (its shape overflows)".into(),
    })
}

fn array_from<R: std::io::Read>(file: npyz::NpyFile<R>, path: &Path) -> Result<Array, NpyError> {
    let format = |reason: String| NpyError::Format {
        path: path.into(),
        reason,
    };
    if file.order() == npyz::Order::Fortran {
        return Err(format("Fortran order".into()));
    }
    let shape = file.shape().iter().map(|&d| d as usize).collect::<Vec<_>>();
    let len = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| format(format!("shape {shape:?} overflows")))?;
    let data = match file.dtype() {
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4 => {
            file.into_vec::<f32>()
        }
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 8 => {
            file.into_vec::<f64>()
                .map(|v| v.into_iter().map(|x| x as f32).collect())
        }
        other => return Err(format(format!("dtype {other:?}"))),
    }
    .map_err(|e| format(format!("unreadable data ({e})")))?;
    if data.len() != len {
        return Err(format(format!(
            "shape {shape:?} needs {len} values, file has {}",
            data.len()
        )));
    }
    Ok(Array { shape, data })
}

/// Check shapes (`[1,]H,W,3` points, `[1,]H,W` confidence) and build a [`PointMap`].
pub fn point_map(pts: Array, conf: Option<Array>, path: &Path) -> Result<PointMap, NpyError> {
    let format = |reason: String| NpyError::Format {
        path: path.into(),
        reason,
    };
    let s = match pts.shape.as_slice() {
        [1, h, w, 3] | [h, w, 3] => [*h, *w],
        other => {
            return Err(format(format!(
                "point map shape {other:?}, expected [1,]H×W×3"
            )));
        }
    };
    if s[0] == 0 || s[1] == 0 {
        return Err(format(format!("empty point map {:?}", pts.shape)));
    }
    let confidence = match conf {
        None => None,
        Some(c) => {
            let cs = match c.shape.as_slice() {
                [1, h, w] | [h, w] | [1, h, w, 1] => [*h, *w],
                other => {
                    return Err(format(format!(
                        "confidence shape {other:?}, expected [1,]H×W"
                    )));
                }
            };
            if cs != s {
                return Err(format(format!(
                    "confidence is {}×{} but its point map is {}×{}",
                    cs[0], cs[1], s[0], s[1]
                )));
            }
            Some(c.data)
        }
    };
    Ok(PointMap {
        width: s[1],
        height: s[0],
        points: pts
            .data
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        confidence,
    })
}

/// Write a `float32` `.npy` file of `shape` (C order), atomically.
pub fn write_npy(path: &Path, shape: &[usize], data: &[f32]) -> std::io::Result<()> {
    use npyz::WriterBuilder;
    let mut buf = Vec::new();
    let shape64 = shape.iter().map(|&d| d as u64).collect::<Vec<_>>();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&shape64)
        .writer(&mut buf)
        .begin_nd()?;
    w.extend(data.iter().copied())?;
    w.finish()?;
    shared_types::atomic::write_atomic(path, &buf)
}

/// The arrays of a pair as written, in order, each `(name, shape, data)`: the first view's
/// points (`height × width × 3`) and confidences (`height × width`, when present), then the
/// second view's.
fn pair_arrays<'a>(
    maps: &PairMaps,
    names: &'a OutputNames,
) -> Vec<(&'a str, Vec<usize>, Vec<f32>)> {
    let mut arrays = Vec::new();
    for (map, pn, cn) in [
        (&maps.first, &names.pts1, &names.conf1),
        (&maps.second, &names.pts2, &names.conf2),
    ] {
        let flat = map.points.iter().flatten().copied().collect::<Vec<_>>();
        arrays.push((pn.as_str(), vec![map.height, map.width, 3], flat));
        if let Some(c) = &map.confidence {
            arrays.push((cn.as_str(), vec![map.height, map.width], c.clone()));
        }
    }
    arrays
}

/// Write pair maps as `a__b/{pts1,conf1,pts2,conf2}.npy` under `dir` (confidences only
/// when present): the layout [`read_pair`] reads.
pub fn write_pair_dir(
    dir: &Path,
    first: &str,
    second: &str,
    maps: &PairMaps,
    names: &OutputNames,
) -> std::io::Result<()> {
    let sub = dir.join(pair_stem(first, second));
    std::fs::create_dir_all(&sub)?;
    for (name, shape, data) in pair_arrays(maps, names) {
        write_npy(&sub.join(format!("{name}.npy")), &shape, &data)?;
    }
    Ok(())
}

/// Write pair maps as one `a__b.npz` archive under `dir` (arrays named by `names`;
/// confidences only when present), atomically.
pub fn write_pair_npz(
    dir: &Path,
    first: &str,
    second: &str,
    maps: &PairMaps,
    names: &OutputNames,
) -> std::io::Result<()> {
    use npyz::WriterBuilder;
    let path = dir.join(format!("{}.npz", pair_stem(first, second)));
    shared_types::atomic::write_with(&path, |tmp| {
        // As numpy's savez: one stored `NAME.npy` member per array.
        // Buffered: npyz hands the writer one element at a time.
        let mut npz = zip::ZipWriter::new(std::io::BufWriter::new(std::fs::File::create(tmp)?));
        let options =
            zip::write::FileOptions::default().compression_method(zip::CompressionMethod::Stored);
        for (name, shape, data) in pair_arrays(maps, names) {
            npz.start_file(format!("{name}.npy"), options)?;
            let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
            let mut w = npyz::WriteOptions::new()
                .default_dtype()
                .shape(&shape)
                .writer(&mut npz)
                .begin_nd()?;
            w.extend(data)?;
            w.finish()?;
        }
        npz.finish()?.into_inner().map_err(|e| e.into_error())?;
        Ok(())
    })
}

/// What a perfect MASt3R-style model would output for the pair `(first, second)`: each
/// view's z-depth map (`0` or non-finite = no surface; row-major at the camera's
/// resolution) turned into points in `first`'s camera frame, divided by `scale`.
/// Pixels without a surface get the point `(0, 0, 0)` and confidence 0; the others
/// confidence 5. Both cameras must be pinhole (depth from a distortion-free render).
/// Used to benchmark and test the init stage with the simulator's true depth.
pub fn pair_maps_from_depth(
    first: (&shared_types::Camera, &[f32]),
    second: (&shared_types::Camera, &[f32]),
    scale: f64,
) -> PairMaps {
    let to_first = first.0.world_to_camera;
    let view = |(cam, depth): (&shared_types::Camera, &[f32])| {
        let w = cam.intrinsics.width as usize;
        let (points, confidence) = depth
            .iter()
            .enumerate()
            .map(|(i, &z)| {
                if !(z > 0.0 && z.is_finite()) {
                    return ([0.0; 3], 0.0);
                }
                let n = cam
                    .intrinsics
                    .to_normalised(glam::DVec2::new((i % w) as f64 + 0.5, (i / w) as f64 + 0.5));
                let z = z as f64;
                let world =
                    cam.world_to_camera
                        .inverse_apply(glam::DVec3::new(n.x * z, n.y * z, z));
                ((to_first.apply(world) / scale).as_vec3().to_array(), 5.0)
            })
            .unzip();
        PointMap {
            width: w,
            height: cam.intrinsics.height as usize,
            points,
            confidence: Some(confidence),
        }
    };
    PairMaps {
        first: view(first),
        second: view(second),
    }
}
