//! A minimal table-shaped PLY codec: one `vertex` element whose properties are all
//! `float` (binary little-endian), plus `comment` lines. Both the 3DGS frames and the
//! native 4D model are such tables; this module knows nothing about Gaussians.

/// Rows of named `f32` properties, row-major, plus the header's comment lines.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyTable {
    /// `comment` lines of the header, without the `comment ` prefix.
    pub comments: Vec<String>,
    /// Property names in file order.
    pub names: Vec<String>,
    /// `rows × names.len()` values.
    pub data: Vec<f32>,
}

impl PlyTable {
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
        for n in &self.names {
            header.push_str(&format!("property float {n}\n"));
        }
        header.push_str("end_header\n");
        let mut out = Vec::with_capacity(header.len() + 4 * self.data.len());
        out.extend_from_slice(header.as_bytes());
        for v in &self.data {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// Parse a file written by [`PlyTable::encode`] (or any PLY of that shape: one vertex
    /// element of float properties). The error says what is wrong with the layout.
    pub fn decode(bytes: &[u8]) -> Result<Self, String> {
        const END: &[u8] = b"end_header\n";
        let end = bytes
            .windows(END.len())
            .position(|w| w == END)
            .ok_or("no `end_header` line")?;
        let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
        let mut lines = header.lines();
        if lines.next().map(str::trim) != Some("ply") {
            return Err("missing `ply` magic".into());
        }
        let (mut comments, mut names) = (Vec::new(), Vec::new());
        let mut count: Option<usize> = None;
        let mut format_ok = false;
        for line in lines {
            if let Some(c) = line.strip_prefix("comment ") {
                comments.push(c.to_string());
                continue;
            }
            let w: Vec<&str> = line.split_whitespace().collect();
            match w.as_slice() {
                ["format", "binary_little_endian", _] => format_ok = true,
                ["format", f, ..] => return Err(format!("format `{f}` is not supported")),
                ["element", "vertex", n] if count.is_none() => {
                    count = Some(n.parse().map_err(|_| "bad vertex count")?);
                }
                ["element", name, _] => return Err(format!("unexpected element `{name}`")),
                ["property", "float" | "float32", name] => names.push(name.to_string()),
                ["property", ty, name] => {
                    return Err(format!("property `{name}` has type `{ty}`, expected float"));
                }
                [] | ["obj_info", ..] => {}
                _ => return Err(format!("unexpected header line `{line}`")),
            }
        }
        if !format_ok {
            return Err("not binary little-endian".into());
        }
        let rows = count.ok_or("no vertex element")?;
        let body = &bytes[end + END.len()..];
        let need = rows
            .checked_mul(names.len() * 4)
            .ok_or("vertex count too large")?;
        if body.len() < need {
            return Err(format!(
                "truncated: {need} bytes of vertices expected, {} present",
                body.len()
            ));
        }
        let data = body[..need]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        Ok(Self {
            comments,
            names,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let t = PlyTable {
            comments: vec!["hello 1 2".into()],
            names: vec!["x".into(), "y".into()],
            data: vec![1.0, -2.5, f32::MIN_POSITIVE, 7.0],
        };
        let bytes = t.encode();
        let back = PlyTable::decode(&bytes).unwrap();
        assert_eq!(back, t);
        assert_eq!(back.rows(), 2);
        assert_eq!(back.comment_value("hello"), Some("1 2"));
        assert!(PlyTable::decode(&bytes[..bytes.len() - 1]).is_err());
        assert!(PlyTable::decode(b"ply\nformat ascii 1.0\nend_header\n").is_err());
    }
}
