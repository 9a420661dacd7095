//! Read-only look into COLMAP's SQLite database (`database.db`): images, keypoint counts and
//! matches per image pair, for diagnosing failed reconstructions. Never writes to it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rusqlite::{Connection, OpenFlags};

/// COLMAP packs an image pair into one integer: `id1 · 2147483647 + id2` with `id1 < id2`.
const MAX_IMAGE_ID: i64 = 2_147_483_647;

/// What the database knows about the images and their matches.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MatchGraph {
    /// image ID → name (as COLMAP stores it, relative to the image folder).
    pub names: BTreeMap<u32, String>,
    /// image ID → number of SIFT keypoints.
    pub keypoints: BTreeMap<u32, u32>,
    /// (id1, id2) with id1 < id2 → raw descriptor matches.
    pub raw_matches: BTreeMap<(u32, u32), u32>,
    /// (id1, id2) → geometrically verified inlier matches (two-view geometry).
    pub verified_matches: BTreeMap<(u32, u32), u32>,
}

#[derive(Debug, thiserror::Error)]
#[error(
    "cannot read COLMAP database {path}: {source} (delete the colmap/ folder and rerun the poses stage)"
)]
pub struct DatabaseError {
    pub path: PathBuf,
    #[source]
    pub source: rusqlite::Error,
}

impl MatchGraph {
    /// Read the match graph from a COLMAP database.
    pub fn read(path: &Path) -> Result<Self, DatabaseError> {
        let err = |source| DatabaseError {
            path: path.to_path_buf(),
            source,
        };
        let db = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(err)?;
        let mut graph = MatchGraph::default();
        let mut q = db
            .prepare("SELECT image_id, name FROM images")
            .map_err(err)?;
        for row in q
            .query_map([], |r| Ok((r.get::<_, u32>(0)?, r.get::<_, String>(1)?)))
            .map_err(err)?
        {
            let (id, name) = row.map_err(err)?;
            graph.names.insert(id, name);
        }
        let mut q = db
            .prepare("SELECT image_id, rows FROM keypoints")
            .map_err(err)?;
        for row in q
            .query_map([], |r| Ok((r.get::<_, u32>(0)?, r.get::<_, u32>(1)?)))
            .map_err(err)?
        {
            let (id, n) = row.map_err(err)?;
            graph.keypoints.insert(id, n);
        }
        for (table, map) in [
            ("matches", &mut graph.raw_matches),
            ("two_view_geometries", &mut graph.verified_matches),
        ] {
            let mut q = db
                .prepare(&format!("SELECT pair_id, rows FROM {table} WHERE rows > 0"))
                .map_err(err)?;
            for row in q
                .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, u32>(1)?)))
                .map_err(err)?
            {
                let (pair_id, n) = row.map_err(err)?;
                map.insert(pair_from_id(pair_id), n);
            }
        }
        Ok(graph)
    }

    /// The image ID for a name.
    pub fn id_of(&self, name: &str) -> Option<u32> {
        self.names
            .iter()
            .find(|(_, n)| n.as_str() == name)
            .map(|(&id, _)| id)
    }

    /// Verified matches of `id` with each other image, most first.
    pub fn partners(&self, id: u32) -> Vec<(u32, u32)> {
        let mut out: Vec<(u32, u32)> = self
            .verified_matches
            .iter()
            .filter_map(|(&(a, b), &n)| {
                if a == id {
                    Some((b, n))
                } else if b == id {
                    Some((a, n))
                } else {
                    None
                }
            })
            .collect();
        out.sort_by(|x, y| y.1.cmp(&x.1).then(x.0.cmp(&y.0)));
        out
    }
}

/// Split COLMAP's pair ID into its two image IDs.
pub fn pair_from_id(pair_id: i64) -> (u32, u32) {
    let id2 = pair_id % MAX_IMAGE_ID;
    let id1 = (pair_id - id2) / MAX_IMAGE_ID;
    (id1 as u32, id2 as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_ids_split_like_colmap() {
        // COLMAP: pair_id = 2147483647 * image_id1 + image_id2 (image_id1 < image_id2).
        assert_eq!(pair_from_id(MAX_IMAGE_ID * 3 + 7), (3, 7));
        assert_eq!(pair_from_id(MAX_IMAGE_ID + 2), (1, 2));
    }
}
