//! COLMAP's binary model files (`cameras.bin`, `images.bin`, `points3D.bin`), little-endian,
//! laid out exactly as COLMAP's `Reconstruction::Read/WriteBinary`:
//!
//! - cameras: `u64 n`, then per camera `u32 id, i32 model, u64 width, u64 height, f64 params[]`.
//! - images: `u64 n`, then per image `u32 id, f64 qvec[4], f64 tvec[3], u32 camera_id,
//!   name (NUL-terminated), u64 n2d, (f64 x, f64 y, u64 point3d_id)[n2d]`.
//! - points3D: `u64 n`, then per point `u64 id, f64 xyz[3], u8 rgb[3], f64 error,
//!   u64 track_len, (u32 image_id, u32 point2d_idx)[track_len]`.

use std::path::Path;

use super::{
    CameraModel, ColmapCamera, ColmapImage, ColmapPoint3D, ModelError, Point2D, TrackElement,
};

pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>, ModelError> {
    read_items(path, 24, |r| {
        let id = r.u32()?;
        let model_id = r.i32()?;
        let model =
            CameraModel::from_id(model_id).ok_or_else(|| ModelError::UnknownCameraModel {
                path: path.to_path_buf(),
                model: format!("id {model_id}"),
            })?;
        let width = r.u64()?;
        let height = r.u64()?;
        let params = (0..model.num_params())
            .map(|_| r.f64())
            .collect::<Result<_, _>>()?;
        Ok(ColmapCamera {
            id,
            model,
            width,
            height,
            params,
        })
    })
}

pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>, ModelError> {
    read_items(path, 73, |r| {
        let id = r.u32()?;
        let qvec = [r.f64()?, r.f64()?, r.f64()?, r.f64()?];
        let tvec = [r.f64()?, r.f64()?, r.f64()?];
        let camera_id = r.u32()?;
        let name = r.c_string()?;
        let n2d = r.count(24)?;
        let mut points2d = Vec::with_capacity(n2d);
        for _ in 0..n2d {
            points2d.push(Point2D {
                xy: [r.f64()?, r.f64()?],
                point3d_id: r.u64()?,
            });
        }
        Ok(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        })
    })
}

pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint3D>, ModelError> {
    read_items(path, 51, |r| {
        let id = r.u64()?;
        let xyz = [r.f64()?, r.f64()?, r.f64()?];
        let rgb = [r.u8()?, r.u8()?, r.u8()?];
        let error = r.f64()?;
        let len = r.count(8)?;
        let mut track = Vec::with_capacity(len);
        for _ in 0..len {
            track.push(TrackElement {
                image_id: r.u32()?,
                point2d_idx: r.u32()?,
            });
        }
        Ok(ColmapPoint3D {
            id,
            xyz,
            rgb,
            error,
            track,
        })
    })
}

pub fn cameras_to_bytes<'a>(cameras: impl ExactSizeIterator<Item = &'a ColmapCamera>) -> Vec<u8> {
    let mut w = Vec::new();
    put(&mut w, &(cameras.len() as u64).to_le_bytes());
    for c in cameras {
        put(&mut w, &c.id.to_le_bytes());
        put(&mut w, &c.model.id().to_le_bytes());
        put(&mut w, &c.width.to_le_bytes());
        put(&mut w, &c.height.to_le_bytes());
        c.params.iter().for_each(|p| put(&mut w, &p.to_le_bytes()));
    }
    w
}

pub fn images_to_bytes<'a>(images: impl ExactSizeIterator<Item = &'a ColmapImage>) -> Vec<u8> {
    let mut w = Vec::new();
    put(&mut w, &(images.len() as u64).to_le_bytes());
    for i in images {
        put(&mut w, &i.id.to_le_bytes());
        i.qvec
            .iter()
            .chain(&i.tvec)
            .for_each(|v| put(&mut w, &v.to_le_bytes()));
        put(&mut w, &i.camera_id.to_le_bytes());
        put(&mut w, i.name.as_bytes());
        w.push(0);
        put(&mut w, &(i.points2d.len() as u64).to_le_bytes());
        for p in &i.points2d {
            put(&mut w, &p.xy[0].to_le_bytes());
            put(&mut w, &p.xy[1].to_le_bytes());
            put(&mut w, &p.point3d_id.to_le_bytes());
        }
    }
    w
}

pub fn points3d_to_bytes<'a>(points: impl ExactSizeIterator<Item = &'a ColmapPoint3D>) -> Vec<u8> {
    let mut w = Vec::new();
    put(&mut w, &(points.len() as u64).to_le_bytes());
    for p in points {
        put(&mut w, &p.id.to_le_bytes());
        p.xyz.iter().for_each(|v| put(&mut w, &v.to_le_bytes()));
        put(&mut w, &p.rgb);
        put(&mut w, &p.error.to_le_bytes());
        put(&mut w, &(p.track.len() as u64).to_le_bytes());
        for t in &p.track {
            put(&mut w, &t.image_id.to_le_bytes());
            put(&mut w, &t.point2d_idx.to_le_bytes());
        }
    }
    w
}

fn put(w: &mut Vec<u8>, bytes: &[u8]) {
    w.extend_from_slice(bytes);
}

/// The items of the file at `path`: a `u64` count (each item at least `min_item_bytes`
/// long), then the items, each read by `item`; the file must end with the last one.
fn read_items<T>(
    path: &Path,
    min_item_bytes: usize,
    mut item: impl FnMut(&mut Reader) -> Result<T, ModelError>,
) -> Result<Vec<T>, ModelError> {
    let bytes = read(path)?;
    let mut r = Reader {
        bytes: &bytes,
        pos: 0,
        path,
    };
    let n = r.count(min_item_bytes)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        out.push(item(&mut r)?);
    }
    r.finish()?;
    Ok(out)
}

fn read(path: &Path) -> Result<Vec<u8>, ModelError> {
    std::fs::read(path).map_err(|source| ModelError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// A bounds-checked little-endian cursor: truncated files give an error, never a panic.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], ModelError> {
        let end = self
            .pos
            .checked_add(N)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| ModelError::Malformed {
                path: self.path.to_path_buf(),
                what: format!(
                    "file ends early at byte {} of {}",
                    self.bytes.len(),
                    self.pos + N
                ),
            })?;
        let mut out = [0; N];
        out.copy_from_slice(&self.bytes[self.pos..end]);
        self.pos = end;
        Ok(out)
    }
    fn u8(&mut self) -> Result<u8, ModelError> {
        Ok(self.take::<1>()?[0])
    }
    fn u32(&mut self) -> Result<u32, ModelError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    fn i32(&mut self) -> Result<i32, ModelError> {
        Ok(i32::from_le_bytes(self.take()?))
    }
    fn u64(&mut self) -> Result<u64, ModelError> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    fn f64(&mut self) -> Result<f64, ModelError> {
        Ok(f64::from_le_bytes(self.take()?))
    }
    /// A count of items each at least `min_item_bytes` long, checked against the bytes left
    /// so that a corrupt count cannot ask for a huge allocation.
    fn count(&mut self, min_item_bytes: usize) -> Result<usize, ModelError> {
        let n = self.u64()?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n.saturating_mul(min_item_bytes as u64) > left {
            return Err(ModelError::Malformed {
                path: self.path.to_path_buf(),
                what: format!(
                    "count {n} at byte {} does not fit in the {left} bytes left",
                    self.pos - 8
                ),
            });
        }
        Ok(n as usize)
    }
    fn c_string(&mut self) -> Result<String, ModelError> {
        let rest = &self.bytes[self.pos..];
        let len = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| ModelError::Malformed {
                path: self.path.to_path_buf(),
                what: "image name without terminating NUL".into(),
            })?;
        let name = String::from_utf8_lossy(&rest[..len]).into_owned();
        self.pos += len + 1;
        Ok(name)
    }
    fn finish(&self) -> Result<(), ModelError> {
        if self.pos == self.bytes.len() {
            Ok(())
        } else {
            Err(ModelError::Malformed {
                path: self.path.to_path_buf(),
                what: format!(
                    "{} trailing bytes after the last record",
                    self.bytes.len() - self.pos
                ),
            })
        }
    }
}
