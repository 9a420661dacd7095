//! Procedural textures baked into tileable square images: multi-octave value noise,
//! checkers and glyph-like blocks, rich enough at image scale for SIFT matching.
//! Deterministic: a texture is a pure function of its spec, the scene seed and its size.

use super::schema::TextureSpec;

/// A baked, tileable RGB texture sampled with wrap-around bilinear filtering.
#[derive(Clone, Debug)]
pub struct Texture {
    size: usize,
    texels: Vec<[f32; 3]>,
    /// Seed of the non-periodic large-scale variation (`None` for solid colours).
    macro_seed: Option<u64>,
}

/// `x.floor()` as an integer without a libm call (hot in texture sampling).
#[inline(always)]
fn floor_i(x: f32) -> i64 {
    let i = x as i64;
    if (i as f32) > x { i - 1 } else { i }
}

/// Non-periodic value noise on the unbounded lattice (breaks the tiling of textures).
#[inline]
fn open_noise(seed: u64, x: f32, y: f32) -> f32 {
    let (ix, iy) = (floor_i(x), floor_i(y));
    let (tx, ty) = (x - ix as f32, y - iy as f32);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let at = |i: i64, j: i64| unit(hash(seed, i as u64, j as u64));
    let (v00, v10, v01, v11) = (
        at(ix, iy),
        at(ix + 1, iy),
        at(ix, iy + 1),
        at(ix + 1, iy + 1),
    );
    let top = v00 + (v10 - v00) * sx;
    let bottom = v01 + (v11 - v01) * sx;
    top + (bottom - top) * sy
}

/// Lattice cells per tile side of the non-periodic spots.
const SPOT_CELLS: f32 = 7.0;

/// Non-periodic spots laid over colour `c` at `(u, v)` (tile units): in about half of the
/// cells of an unbounded lattice, a soft-edged disc, dark or light, of random size and
/// place. Brightness changes alone do not stop SIFT from matching repeated tiles (its
/// descriptors ignore them); these change the local structure, so no two neighbourhoods
/// look alike, while staying a pure function of the seed and the coordinates.
#[inline]
fn open_spots(seed: u64, u: f32, v: f32, c: [f32; 3]) -> [f32; 3] {
    let (x, y) = (u * SPOT_CELLS, v * SPOT_CELLS);
    let (ix, iy) = (floor_i(x), floor_i(y));
    let h = hash(seed, ix as u64, iy as u64);
    if h % 16 < 7 {
        return c;
    }
    let r = 0.12 + 0.22 * unit(h.rotate_left(17));
    let cx = r + (1.0 - 2.0 * r) * unit(h.rotate_left(29));
    let cy = r + (1.0 - 2.0 * r) * unit(h.rotate_left(41));
    let (dx, dy) = (x - ix as f32 - cx, y - iy as f32 - cy);
    let d = (dx * dx + dy * dy).sqrt();
    // Soft edge over 0.05 cell: no aliasing at the simulator's supersampling.
    let w = ((r - d) / 0.05 + 0.5).clamp(0.0, 1.0);
    if w == 0.0 {
        return c;
    }
    let target = if (h >> 8).is_multiple_of(2) {
        [0.06, 0.05, 0.07]
    } else {
        let t = unit(h.rotate_left(53));
        [0.95, 0.8 + 0.15 * t, 0.6 + 0.3 * t]
    };
    [0, 1, 2].map(|k| c[k] + (target[k] - c[k]) * w)
}

/// A 64-bit mix of the inputs (splitmix64 finaliser): the noise lattice values.
pub(crate) fn hash(seed: u64, a: u64, b: u64) -> u64 {
    let mut z =
        seed ^ a.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ b.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn unit(h: u64) -> f32 {
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Tileable value noise with `period` lattice cells per tile, at `(x, y)` in tile units.
fn value_noise(seed: u64, period: u32, x: f32, y: f32) -> f32 {
    let (fx, fy) = (x * period as f32, y * period as f32);
    let (ix, iy) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - ix, fy - iy);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let p = period as i64;
    let at = |i: f32, j: f32| {
        let (a, b) = (
            (i as i64).rem_euclid(p) as u64,
            (j as i64).rem_euclid(p) as u64,
        );
        unit(hash(seed, a, b))
    };
    let v00 = at(ix, iy);
    let v10 = at(ix + 1.0, iy);
    let v01 = at(ix, iy + 1.0);
    let v11 = at(ix + 1.0, iy + 1.0);
    let top = v00 + (v10 - v00) * sx;
    let bottom = v01 + (v11 - v01) * sx;
    top + (bottom - top) * sy
}

/// Fractal sum of value noise, in [0, 1].
fn fbm(seed: u64, base_period: u32, octaves: u32, x: f32, y: f32) -> f32 {
    let (mut sum, mut norm, mut amp) = (0.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * value_noise(seed.wrapping_add(o as u64 * 7919), base_period << o, x, y);
        norm += amp;
        amp *= 0.55;
    }
    sum / norm
}

/// A 5×7 glyph-like block pattern in a cell (`gx, gy` in [0, 1)), or `None` outside strokes.
fn glyph(seed: u64, cell: (u64, u64), gx: f32, gy: f32) -> bool {
    let h = hash(seed ^ 0x6C79_7068, cell.0, cell.1);
    // Margins around the glyph, then a 5×7 grid of strokes.
    let (u, v) = ((gx - 0.15) / 0.7, (gy - 0.1) / 0.8);
    if !(0.0..1.0).contains(&u) || !(0.0..1.0).contains(&v) {
        return false;
    }
    let (col, row) = ((u * 5.0) as u64, (v * 7.0) as u64);
    let bits = hash(h, col, row);
    // About 45% of blocks on; whole cells left blank now and then.
    !h.is_multiple_of(7) && bits % 100 < 45
}

impl Texture {
    /// Bake `spec` at `size × size` texels; `scene_seed` and `salt` make textures differ.
    pub fn bake(spec: &TextureSpec, size: u32, scene_seed: u64, salt: u64) -> Self {
        use rayon::prelude::*;
        let n = size as usize;
        let seed = hash(scene_seed, spec.seed, salt);
        let c0 = spec.colors[0].map(|v| v as f32);
        let c1 = spec.colors[1].map(|v| v as f32);
        let cells = spec.cells;
        let kind = spec.kind.as_str();
        let mut texels = vec![[0.0f32; 3]; n * n];
        texels.par_chunks_mut(n).enumerate().for_each(|(j, row)| {
            for (i, texel) in row.iter_mut().enumerate() {
                let (x, y) = ((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                let noise = || fbm(seed, 3, 4, x, y);
                let checker = || {
                    let (cx, cy) = ((x * cells as f32) as u32, (y * cells as f32) as u32);
                    (cx + cy) % 2 == 0
                };
                let glyph_on = || {
                    let g = (cells / 2).max(1);
                    let (fx, fy) = (x * g as f32, y * g as f32);
                    glyph(seed, (fx as u64, fy as u64), fx.fract(), fy.fract())
                };
                let t = match kind {
                    "solid" => 0.0,
                    "noise" => noise(),
                    "checker" => {
                        if checker() {
                            0.15 + 0.2 * noise()
                        } else {
                            0.65 + 0.2 * noise()
                        }
                    }
                    "glyphs" => {
                        if glyph_on() {
                            0.1 * noise()
                        } else {
                            0.7 + 0.3 * noise()
                        }
                    }
                    _ => {
                        // mix: noise, darkened on alternate checker squares, glyphs on top.
                        let base = 0.25 + 0.75 * noise();
                        let base = if checker() { base * 0.7 } else { base };
                        if glyph_on() { 0.08 + 0.15 * base } else { base }
                    }
                };
                // A slow colour drift per channel keeps matches unambiguous across tiles.
                let tint = value_noise(seed ^ 0x7469_6E74, 2, x, y) - 0.5;
                *texel = [0, 1, 2].map(|c| {
                    let v = c0[c] + (c1[c] - c0[c]) * t;
                    let drift = if kind == "solid" {
                        0.0
                    } else {
                        tint * 0.15 * (c as f32 - 1.0)
                    };
                    (v + drift).clamp(0.0, 1.0)
                });
            }
        });
        Texture {
            size: n,
            texels,
            macro_seed: (kind != "solid").then_some(seed ^ 0x6D61_6372),
        }
    }

    /// Colour at texture coordinates in tile units: the tile (bilinear, wrapping) under a
    /// non-periodic brightness and tint variation a few tiles across, so that repeated
    /// tiles do not look alike to feature matchers.
    #[inline]
    pub fn sample(&self, u: f32, v: f32) -> [f32; 3] {
        let c = self.sample_tile(u, v);
        match self.macro_seed {
            None => c,
            Some(seed) => {
                let m = open_noise(seed, u * 0.53, v * 0.53);
                let tint = open_noise(seed ^ 2, u * 0.29, v * 0.29) - 0.5;
                let g = 0.65 + 0.7 * m;
                let c = [
                    (c[0] * g * (1.0 + 0.3 * tint)).min(1.0),
                    (c[1] * g).min(1.0),
                    (c[2] * g * (1.0 - 0.3 * tint)).min(1.0),
                ];
                open_spots(seed ^ 0x7370_6F74, u, v, c)
            }
        }
    }

    /// Bilinear sample of the tile alone (wrapping).
    #[inline]
    fn sample_tile(&self, u: f32, v: f32) -> [f32; 3] {
        let n = self.size;
        let x = u * n as f32 - 0.5;
        let y = v * n as f32 - 0.5;
        let (fx, fy) = (floor_i(x), floor_i(y));
        let (tx, ty) = (x - fx as f32, y - fy as f32);
        let wrap = |a: i64| a.rem_euclid(n as i64) as usize;
        let (x0, y0) = (wrap(fx), wrap(fy));
        let (x1, y1) = (
            if x0 + 1 == n { 0 } else { x0 + 1 },
            if y0 + 1 == n { 0 } else { y0 + 1 },
        );
        let (a, b, c, d) = (
            self.texels[y0 * n + x0],
            self.texels[y0 * n + x1],
            self.texels[y1 * n + x0],
            self.texels[y1 * n + x1],
        );
        [0, 1, 2].map(|k| {
            let top = a[k] + (b[k] - a[k]) * tx;
            let bottom = c[k] + (d[k] - c[k]) * tx;
            top + (bottom - top) * ty
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn textures_are_deterministic_and_tile_seamlessly() {
        let spec = TextureSpec::default();
        let a = Texture::bake(&spec, 64, 7, 1);
        let b = Texture::bake(&spec, 64, 7, 1);
        assert_eq!(a.texels, b.texels);
        let c = Texture::bake(&spec, 64, 8, 1);
        assert_ne!(a.texels, c.texels);
        // Wrapping: sampling one tile over equals sampling here.
        let (s0, s1) = (a.sample_tile(0.3, 0.7), a.sample_tile(1.3, -0.3));
        for k in 0..3 {
            assert!((s0[k] - s1[k]).abs() < 1e-4);
        }
        // Rich: the texture is far from flat.
        let mean: f32 = a.texels.iter().map(|t| t[1]).sum::<f32>() / a.texels.len() as f32;
        let var: f32 =
            a.texels.iter().map(|t| (t[1] - mean).powi(2)).sum::<f32>() / a.texels.len() as f32;
        assert!(var.sqrt() > 0.08, "std {}", var.sqrt());
    }
}
