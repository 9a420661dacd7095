//! 16×16 tile binning: which projected Gaussians touch which tile (by their 3σ box),
//! and the per-tile front-to-back depth order. Knows nothing about colour or gradients.

use crate::math::numerics::Real;
use rayon::prelude::*;

/// Tile side in pixels.
pub const TILE: u32 = 16;

/// Per-tile lists of splat indices, each sorted by depth (ties by index).
#[derive(Clone, Debug, Default)]
pub struct TileBins {
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// `entries[offsets[t]..offsets[t+1]]` are the splats of tile `t` (row-major tiles).
    pub offsets: Vec<usize>,
    pub entries: Vec<u32>,
}

impl TileBins {
    pub fn tile_count(&self) -> usize {
        (self.tiles_x * self.tiles_y) as usize
    }

    /// The depth-sorted splat indices of tile `t`.
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.entries[self.offsets[t]..self.offsets[t + 1]]
    }
}

/// An inclusive pixel box `[x0, x1, y0, y1]` clipped to the image; `None` if empty.
#[inline]
pub fn pixel_rect(rect: [i32; 4], width: u32, height: u32) -> Option<[u32; 4]> {
    let x0 = rect[0].max(0);
    let x1 = rect[1].min(width as i32 - 1);
    let y0 = rect[2].max(0);
    let y1 = rect[3].min(height as i32 - 1);
    if x0 > x1 || y0 > y1 {
        return None;
    }
    Some([x0 as u32, x1 as u32, y0 as u32, y1 as u32])
}

/// Bin splats (given by their clipped pixel box `[x0, x1, y0, y1]`, inclusive, and depth)
/// into tiles. Counting and filling run in parallel over chunks of splats; each tile's
/// list is then sorted by (depth, index), so the result does not depend on the chunking.
pub fn bin_tiles<F: Real>(rects: &[[u32; 4]], depths: &[F], width: u32, height: u32) -> TileBins {
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let n_tiles = (tiles_x * tiles_y) as usize;
    // The tiles (row-major indices) a pixel box touches.
    let tiles_of = move |r: &[u32; 4]| {
        let [tx0, tx1, ty0, ty1] = [r[0] / TILE, r[1] / TILE, r[2] / TILE, r[3] / TILE];
        (ty0..=ty1).flat_map(move |ty| (tx0..=tx1).map(move |tx| (ty * tiles_x + tx) as usize))
    };
    // Per chunk of splats: how many entries it adds to each tile.
    let chunk = rects
        .len()
        .div_ceil(rayon::current_num_threads().max(1) * 4)
        .max(4096);
    let mut chunk_counts: Vec<Vec<usize>> = rects
        .par_chunks(chunk)
        .map(|rs| {
            let mut counts = vec![0usize; n_tiles];
            for t in rs.iter().flat_map(tiles_of) {
                counts[t] += 1;
            }
            counts
        })
        .collect();
    // Tile offsets, and each chunk's start inside every tile (chunks in splat order).
    let mut offsets = vec![0usize; n_tiles + 1];
    for t in 0..n_tiles {
        let mut cursor = offsets[t];
        for counts in chunk_counts.iter_mut() {
            let c = counts[t];
            counts[t] = cursor;
            cursor += c;
        }
        offsets[t + 1] = cursor;
    }
    let total = offsets[n_tiles];
    let mut keys = vec![0u64; total];
    {
        // Each (chunk, tile) range of `keys` is written by exactly one chunk.
        struct Shared(*mut u64);
        // SAFETY: the pointer is only used for disjoint writes (see below).
        unsafe impl Sync for Shared {}
        let out = Shared(keys.as_mut_ptr());
        let out = &out;
        rects
            .par_chunks(chunk)
            .zip(chunk_counts.par_iter_mut())
            .enumerate()
            .for_each(|(c, (rs, cursor))| {
                for (j, r) in rs.iter().enumerate() {
                    let i = c * chunk + j;
                    let depth_bits = (depths[i].f64() as f32).max(0.0).to_bits() as u64;
                    let key = (depth_bits << 32) | i as u64;
                    for t in tiles_of(r) {
                        // SAFETY: chunk c's cursor for tile t runs over the range
                        // [start(c, t), start(c + 1, t)) that only this chunk owns, and
                        // stays below `total` (the counts above bound it).
                        unsafe { *out.0.add(cursor[t]) = key };
                        cursor[t] += 1;
                    }
                }
            });
    }
    // Split the key array into per-tile slices and sort each in parallel.
    let mut slices: Vec<&mut [u64]> = Vec::with_capacity(n_tiles);
    let mut rest: &mut [u64] = &mut keys;
    for t in 0..n_tiles {
        let (head, tail) = rest.split_at_mut(offsets[t + 1] - offsets[t]);
        slices.push(head);
        rest = tail;
    }
    slices.par_iter_mut().for_each(|s| s.sort_unstable());
    let entries = keys.par_iter().map(|k| (*k & 0xffff_ffff) as u32).collect();
    TileBins {
        tiles_x,
        tiles_y,
        offsets,
        entries,
    }
}
