//! Points bucketed in cubes, for radius searches and voxel averages. Keys are hashed with
//! FxHash: the init hashes millions of cell keys, and SipHash's protection against
//! crafted keys buys nothing for coordinates.

use glam::DVec3;
use rustc_hash::FxHashMap;

/// A map keyed by grid cells (the one place the hasher is chosen).
pub type CellMap<V> = FxHashMap<[i64; 3], V>;

/// The cube of edge `cell` that holds `p`.
pub fn cell_key(p: DVec3, cell: f64) -> [i64; 3] {
    (p / cell).floor().as_i64vec3().to_array()
}

/// Point indices bucketed in cubes of edge `cell`.
pub struct Grid {
    cell: f64,
    cells: CellMap<Vec<usize>>,
}

impl Grid {
    pub fn new(points: impl Iterator<Item = (usize, DVec3)>, cell: f64) -> Self {
        let mut cells: CellMap<Vec<usize>> = CellMap::default();
        for (i, p) in points {
            cells.entry(cell_key(p, cell)).or_default().push(i);
        }
        Self { cell, cells }
    }

    /// Indices in the 27 cells around `p` (a superset of those within one `cell` of it).
    pub fn near(&self, p: DVec3) -> impl Iterator<Item = usize> + '_ {
        let [x, y, z] = cell_key(p, self.cell);
        (-1..=1)
            .flat_map(move |dx| {
                (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| [x + dx, y + dy, z + dz]))
            })
            .filter_map(|k| self.cells.get(&k))
            .flatten()
            .copied()
    }
}
