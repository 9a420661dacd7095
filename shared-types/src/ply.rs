//! The workspace's one PLY codec: binary little-endian, one `vertex` element of scalar
//! properties, plus `comment` lines. Point clouds (`points.ply`, `points3d.ply`), 3DGS
//! frames and the native 4D model are all such tables; this module knows nothing about
//! what the columns mean.
//!
//! Values are held as `f32`; each column keeps its file type, so a `uchar` colour column
//! is written back as `uchar`. Reading accepts every PLY scalar type; other elements
//! are allowed only when empty (`element face 0`), list properties are refused.

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
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

    fn name(self) -> &'static str {
        match self {
            Self::I8 => "char",
            Self::U8 => "uchar",
            Self::I16 => "short",
            Self::U16 => "ushort",
            Self::I32 => "int",
            Self::U32 => "uint",
            Self::F32 => "float",
            Self::F64 => "double",
        }
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn read(self, b: &[u8]) -> f32 {
        let a4 = || [b[0], b[1], b[2], b[3]];
        match self {
            Self::I8 => b[0] as i8 as f32,
            Self::U8 => b[0] as f32,
            Self::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
            Self::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
            Self::I32 => i32::from_le_bytes(a4()) as f32,
            Self::U32 => u32::from_le_bytes(a4()) as f32,
            Self::F32 => f32::from_le_bytes(a4()),
            Self::F64 => {
                f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32
            }
        }
    }

    /// Append `v` in this type (integers rounded and saturated to their range).
    fn write(self, v: f32, out: &mut Vec<u8>) {
        let r = v.round();
        match self {
            Self::I8 => out.push(r as i8 as u8),
            Self::U8 => out.push(r as u8),
            Self::I16 => out.extend_from_slice(&(r as i16).to_le_bytes()),
            Self::U16 => out.extend_from_slice(&(r as u16).to_le_bytes()),
            Self::I32 => out.extend_from_slice(&(r as i32).to_le_bytes()),
            Self::U32 => out.extend_from_slice(&(r as u32).to_le_bytes()),
            Self::F32 => out.extend_from_slice(&v.to_le_bytes()),
            Self::F64 => out.extend_from_slice(&(v as f64).to_le_bytes()),
        }
    }
}

/// Why bytes are not a PLY table this codec reads.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlyFormatError {
    #[error("{0}")]
    Layout(String),
    #[error("truncated: {expected} bytes of vertices expected, {found} present")]
    Truncated { expected: u64, found: u64 },
}

/// Rows of named scalar columns, row-major, plus the header's comment lines.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyTable {
    /// `comment` lines of the header, without the `comment ` prefix.
    pub comments: Vec<String>,
    /// Property names in file order.
    pub names: Vec<String>,
    /// The file type of each property (same length as `names`).
    pub types: Vec<Scalar>,
    /// `rows × names.len()` values.
    pub data: Vec<f32>,
}

impl PlyTable {
    /// A table whose columns are all `float`.
    pub fn floats(comments: Vec<String>, names: Vec<String>, data: Vec<f32>) -> Self {
        let types = vec![Scalar::F32; names.len()];
        Self {
            comments,
            names,
            types,
            data,
        }
    }

    /// Number of rows (vertices).
    pub fn rows(&self) -> usize {
        self.data.len() / self.names.len().max(1)
    }

    /// Column index of a property.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The value of a `comment KEY value…` line, if present.
    pub fn comment_value(&self, key: &str) -> Option<&str> {
        self.comments.iter().find_map(|c| {
            let rest = c.strip_prefix(key)?;
            rest.starts_with(' ').then(|| rest.trim())
        })
    }

    /// The binary little-endian PLY file.
    pub fn encode(&self) -> Vec<u8> {
        let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
        for c in &self.comments {
            header.push_str(&format!("comment {c}\n"));
        }
        header.push_str(&format!("element vertex {}\n", self.rows()));
        for (n, t) in self.names.iter().zip(&self.types) {
            header.push_str(&format!("property {} {n}\n", t.name()));
        }
        header.push_str("end_header\n");
        let stride: usize = self.types.iter().map(|t| t.size()).sum();
        let mut out = Vec::with_capacity(header.len() + stride * self.rows());
        out.extend_from_slice(header.as_bytes());
        if self.types.iter().all(|&t| t == Scalar::F32) {
            for v in &self.data {
                out.extend_from_slice(&v.to_le_bytes());
            }
        } else {
            for row in self.data.chunks_exact(self.names.len().max(1)) {
                for (&v, t) in row.iter().zip(&self.types) {
                    t.write(v, &mut out);
                }
            }
        }
        out
    }

    /// Parse a binary little-endian PLY with one vertex element of scalar properties.
    /// The error says what is wrong with the layout.
    pub fn decode(bytes: &[u8]) -> Result<Self, PlyFormatError> {
        let layout = |s: &str| PlyFormatError::Layout(s.to_string());
        const END: &[u8] = b"end_header\n";
        let end = bytes
            .windows(END.len())
            .position(|w| w == END)
            .ok_or_else(|| layout("no `end_header` line"))?;
        let header =
            std::str::from_utf8(&bytes[..end]).map_err(|_| layout("header is not text"))?;
        let mut lines = header.lines();
        if lines.next().map(str::trim) != Some("ply") {
            return Err(layout("missing `ply` magic"));
        }
        let (mut comments, mut names, mut types) = (Vec::new(), Vec::new(), Vec::new());
        let mut count: Option<u64> = None;
        let (mut in_vertex, mut format_ok) = (false, false);
        for line in lines {
            if let Some(c) = line.strip_prefix("comment ") {
                comments.push(c.to_string());
                continue;
            }
            let w: Vec<&str> = line.split_whitespace().collect();
            match w.as_slice() {
                ["format", "binary_little_endian", _] => format_ok = true,
                ["format", f, ..] => {
                    return Err(PlyFormatError::Layout(format!(
                        "format `{f}` is not supported"
                    )));
                }
                ["element", "vertex", n] => {
                    if count.is_some() {
                        return Err(layout("two vertex elements"));
                    }
                    count = Some(n.parse().map_err(|_| layout("bad vertex count"))?);
                    in_vertex = true;
                }
                ["element", name, n] => {
                    if count.is_none() || n.parse::<u64>().ok() != Some(0) {
                        return Err(PlyFormatError::Layout(format!(
                            "element `{name}` before the vertices or not empty"
                        )));
                    }
                    in_vertex = false;
                }
                ["property", "list", ..] if in_vertex => {
                    return Err(layout("list properties on vertices"));
                }
                ["property", ty, name] if in_vertex => {
                    let t = Scalar::parse(ty)
                        .ok_or_else(|| PlyFormatError::Layout(format!("unknown type `{ty}`")))?;
                    names.push(name.to_string());
                    types.push(t);
                }
                _ => {}
            }
        }
        if !format_ok {
            return Err(layout("not binary little-endian"));
        }
        let rows = count.ok_or_else(|| layout("no vertex element"))?;
        let stride: usize = types.iter().map(|t: &Scalar| t.size()).sum();
        let body = &bytes[end + END.len()..];
        let expected = rows.saturating_mul(stride as u64);
        if (body.len() as u64) < expected {
            return Err(PlyFormatError::Truncated {
                expected,
                found: body.len() as u64,
            });
        }
        let rows = rows as usize;
        let mut data = Vec::with_capacity(rows * names.len());
        if types.iter().all(|&t| t == Scalar::F32) {
            data.extend(
                body[..expected as usize]
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            );
        } else {
            for row in body.chunks_exact(stride.max(1)).take(rows) {
                let mut at = 0;
                for t in &types {
                    data.push(t.read(&row[at..]));
                    at += t.size();
                }
            }
        }
        Ok(Self {
            comments,
            names,
            types,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn float_tables_round_trip_and_bad_layouts_are_errors() {
        let t = PlyTable::floats(
            vec!["hello 1 2".into()],
            vec!["x".into(), "y".into()],
            vec![1.0, -2.5, f32::MIN_POSITIVE, 7.0],
        );
        let bytes = t.encode();
        let back = PlyTable::decode(&bytes).unwrap();
        assert_eq!(back, t);
        assert_eq!(back.rows(), 2);
        assert_eq!(back.comment_value("hello"), Some("1 2"));
        assert!(matches!(
            PlyTable::decode(&bytes[..bytes.len() - 1]),
            Err(PlyFormatError::Truncated {
                expected: 16,
                found: 15
            })
        ));
        assert!(PlyTable::decode(b"ply\nformat ascii 1.0\nend_header\n").is_err());
        let list = b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty list uchar int i\nend_header\n";
        assert!(PlyTable::decode(list).is_err());
    }

    #[test]
    fn every_scalar_type_reads_and_mixed_tables_keep_their_types() {
        let all = [
            Scalar::I8,
            Scalar::U8,
            Scalar::I16,
            Scalar::U16,
            Scalar::I32,
            Scalar::U32,
            Scalar::F32,
            Scalar::F64,
        ];
        let names: Vec<String> = (0..all.len()).map(|i| format!("p{i}")).collect();
        let row = [-7.0, 250.0, -300.0, 60000.0, -70000.0, 4e6, 0.25, -1.5];
        let t = PlyTable {
            comments: vec![],
            names,
            types: all.to_vec(),
            data: [row, row].concat(),
        };
        let bytes = t.encode();
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.contains("property uchar p1\n") && text.contains("property double p7\n"));
        // Header + 2 rows of 1+1+2+2+4+4+4+8 bytes, then an empty face element is allowed.
        let stride = 26;
        let end = bytes.len() - 2 * stride;
        assert_eq!(PlyTable::decode(&bytes).unwrap(), t);
        let mut with_face = bytes[..end - "end_header\n".len()].to_vec();
        with_face.extend_from_slice(
            b"element face 0\nproperty list uchar int vertex_indices\nend_header\n",
        );
        with_face.extend_from_slice(&bytes[end..]);
        assert_eq!(PlyTable::decode(&with_face).unwrap().data, t.data);
    }
}
