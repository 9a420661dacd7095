//! Static plates: what each camera sees when nothing moves. Every camera of a capture
//! stands still for the whole clip, so the per-pixel temporal median of its aligned frames
//! is the static scene (people who keep moving drop out of it), and a frame's pixels that
//! differ from that median are where something moves at that moment. A point found at a
//! moment is moving when it lands on moving pixels in most of the cameras that frame it
//! ([`Plates::static_tags`]): noisy depths of a static wall cannot pass for motion.

use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use shared_types::{Camera, CameraSet};

use crate::error::InitError;
use crate::inputs::{Moment, ViewImage};
use crate::statics::TimedPoint;
use crate::views::read_frame;

/// Least difference (0..255, largest over the three channels) between a frame and its
/// camera's plate for a pixel to count as moving: the default of `[init] motion_threshold`.
pub const MOTION_THRESHOLD: u8 = 25;

/// Isolated moving pixels with fewer moving neighbours (of 8) than this are noise.
const MIN_NEIGHBOURS: usize = 2;
/// Moving masks grow by this many pixels (a moving outline's depths smear a little).
const GROW: u32 = 2;

/// Each training camera's static plate (at the frames' size, with the camera's lens).
pub struct Plates {
    plates: Vec<(Camera, RgbImage)>,
    threshold: u8,
}

impl Plates {
    /// The plate of every camera of `cameras` that has frames among `frames` (its
    /// median); `threshold` is the least channel difference that counts as motion.
    pub fn new(
        cameras: &CameraSet,
        frames: &[ViewImage],
        threshold: u8,
    ) -> Result<Self, InitError> {
        let mut plates = Vec::new();
        for cam in &cameras.cameras {
            let paths: Vec<&ViewImage> = frames.iter().filter(|f| f.camera == cam.name).collect();
            if paths.is_empty() {
                continue;
            }
            let images = paths
                .par_iter()
                .map(|f| read_frame(cam, &f.path))
                .collect::<Result<Vec<_>, _>>()?;
            plates.push((cam.clone(), median_plate(&images)));
        }
        Ok(Self { plates, threshold })
    }

    /// Cameras with a plate.
    pub fn len(&self) -> usize {
        self.plates.len()
    }

    pub fn is_empty(&self) -> bool {
        self.plates.is_empty()
    }

    /// Each camera with its plate (the frames' size, the camera's lens).
    pub fn images(&self) -> &[(Camera, RgbImage)] {
        &self.plates
    }

    /// The moving masks of `moment`'s frames, one per camera with a plate and a frame.
    fn moment_masks(&self, moment: &Moment) -> Result<Vec<(&Camera, Mask)>, InitError> {
        self.plates
            .par_iter()
            .filter_map(|(cam, plate)| {
                let view = moment.views.iter().find(|v| v.camera == cam.name)?;
                Some(
                    read_frame(cam, &view.path)
                        .map(|frame| (cam, moving_pixels(&frame, plate, self.threshold))),
                )
            })
            .collect()
    }

    /// Whether each of `points` (found at `moments[point.moment]`) is static: it is moving
    /// when it lands on moving pixels in more than half of the cameras whose frame
    /// contains it. Also each moment's moving fraction of the frames (mean over cameras).
    pub fn static_tags(
        &self,
        points: &[TimedPoint],
        moments: &[Moment],
    ) -> Result<(Vec<bool>, Vec<f64>), InitError> {
        let mut is_static = vec![true; points.len()];
        let mut fractions = Vec::with_capacity(moments.len());
        for (k, moment) in moments.iter().enumerate() {
            let masks = self.moment_masks(moment)?;
            fractions.push(
                masks.iter().map(|(_, m)| m.fraction()).sum::<f64>() / masks.len().max(1) as f64,
            );
            is_static
                .par_iter_mut()
                .zip(points)
                .filter(|(_, p)| p.moment == k)
                .for_each(|(tag, p)| {
                    let (mut framed, mut moving) = (0, 0);
                    for (cam, mask) in &masks {
                        let Some((px, _)) = cam.project(p.xyz) else {
                            continue;
                        };
                        if px.x >= 0.0
                            && px.y >= 0.0
                            && px.x < mask.width as f64
                            && px.y < mask.height as f64
                        {
                            framed += 1;
                            moving += usize::from(mask.at(px.x, px.y));
                        }
                    }
                    *tag = 2 * moving <= framed;
                });
        }
        Ok((is_static, fractions))
    }
}

/// The per-pixel, per-channel median of `frames` (all the same size; at least one). With
/// an even count the upper median is taken.
pub fn median_plate(frames: &[RgbImage]) -> RgbImage {
    let (w, h) = frames[0].dimensions();
    let mut plate = RgbImage::new(w, h);
    let mut values = Vec::with_capacity(frames.len());
    for (i, out) in plate.as_mut().iter_mut().enumerate() {
        values.clear();
        values.extend(frames.iter().map(|f| f.as_raw()[i]));
        let mid = values.len() / 2;
        *out = *values.select_nth_unstable(mid).1;
    }
    plate
}

/// A per-pixel mask, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<bool>,
}

impl Mask {
    /// Whether the pixel containing continuous coordinates `(x, y)` (pixel centres at
    /// integer + 0.5) is set; `false` outside.
    pub fn at(&self, x: f64, y: f64) -> bool {
        if !(x >= 0.0 && y >= 0.0) {
            return false;
        }
        let (x, y) = (x as u32, y as u32);
        x < self.width && y < self.height && self.pixels[(y * self.width + x) as usize]
    }

    /// As an 8-bit grey image: 255 where set, else 0.
    pub fn to_grey(&self) -> GrayImage {
        let pixels = self
            .pixels
            .iter()
            .map(|&m| if m { 255 } else { 0 })
            .collect();
        GrayImage::from_raw(self.width, self.height, pixels).expect("one byte per pixel")
    }

    /// Fraction of pixels set.
    pub fn fraction(&self) -> f64 {
        self.pixels.iter().filter(|&&m| m).count() as f64 / self.pixels.len().max(1) as f64
    }

    /// Every pixel within `r` pixels (a square window) of a set pixel is set.
    pub fn dilated(&self, r: u32) -> Mask {
        let (w, h) = (self.width as usize, self.height as usize);
        let r = r as usize;
        let mut rows = vec![false; w * h];
        for y in 0..h {
            let row = &self.pixels[y * w..(y + 1) * w];
            for x in 0..w {
                let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
                rows[y * w + x] = row[a..=b].iter().any(|&m| m);
            }
        }
        let mut out = vec![false; w * h];
        for y in 0..h {
            let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
            for x in 0..w {
                out[y * w + x] = (a..=b).any(|yy| rows[yy * w + x]);
            }
        }
        Mask {
            width: self.width,
            height: self.height,
            pixels: out,
        }
    }

    /// Set pixels with fewer than `min` set pixels among their 8 neighbours are cleared
    /// (isolated noise), then the mask is dilated by `grow` pixels.
    pub fn cleaned(&self, min: usize, grow: u32) -> Mask {
        let (w, h) = (self.width as i64, self.height as i64);
        let set = |x: i64, y: i64| {
            x >= 0 && y >= 0 && x < w && y < h && self.pixels[(y * w + x) as usize]
        };
        let pixels = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                set(x, y)
                    && (-1..=1)
                        .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
                        .filter(|&(dx, dy)| (dx, dy) != (0, 0) && set(x + dx, y + dy))
                        .count()
                        >= min
            })
            .collect();
        Mask {
            width: self.width,
            height: self.height,
            pixels,
        }
        .dilated(grow)
    }
}

/// Where something moves in `frame`: its [`motion_mask`] against its camera's `plate`,
/// isolated pixels dropped and outlines grown a little.
pub fn moving_pixels(frame: &RgbImage, plate: &RgbImage, threshold: u8) -> Mask {
    motion_mask(frame, plate, threshold).cleaned(MIN_NEIGHBOURS, GROW)
}

/// Where `frame` differs from `plate` by at least `threshold` in some channel.
pub fn motion_mask(frame: &RgbImage, plate: &RgbImage, threshold: u8) -> Mask {
    let pixels = frame
        .pixels()
        .zip(plate.pixels())
        .map(|(a, b)| (0..3).any(|c| a[c].abs_diff(b[c]) >= threshold))
        .collect();
    Mask {
        width: frame.width(),
        height: frame.height(),
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: u32, h: u32, v: u8) -> RgbImage {
        RgbImage::from_pixel(w, h, image::Rgb([v, v, v]))
    }

    #[test]
    fn the_median_drops_what_passes_through() {
        // A grey scene; a dark square visits a different place in each of five frames.
        let frames: Vec<RgbImage> = (0..5)
            .map(|k| {
                let mut f = flat(20, 10, 128);
                for y in 2..6 {
                    for x in 4 * k..4 * k + 3 {
                        f.put_pixel(x, y, image::Rgb([10, 200, 30]));
                    }
                }
                f
            })
            .collect();
        assert_eq!(median_plate(&frames), flat(20, 10, 128));
        let mask = motion_mask(&frames[2], &median_plate(&frames), MOTION_THRESHOLD);
        let expected: Vec<bool> = (0..10)
            .flat_map(|y| (0..20).map(move |x| (2..6).contains(&y) && (8..11).contains(&x)))
            .collect();
        assert_eq!(mask.pixels, expected);
        assert!((mask.fraction() - 12.0 / 200.0).abs() < 1e-12);
    }

    #[test]
    fn the_median_of_an_even_count_is_the_upper_one() {
        let frames = [
            flat(2, 2, 10),
            flat(2, 2, 40),
            flat(2, 2, 20),
            flat(2, 2, 30),
        ];
        assert_eq!(median_plate(&frames), flat(2, 2, 30));
    }

    #[test]
    fn cleaning_drops_lone_pixels_and_grows_blobs() {
        let mut pixels = vec![false; 100];
        pixels[11] = true; // a lone pixel at (1, 1)
        for y in 5..8 {
            for x in 5..8 {
                pixels[y * 10 + x] = true; // a 3×3 blob
            }
        }
        let mask = Mask {
            width: 10,
            height: 10,
            pixels,
        };
        let clean = mask.cleaned(2, 1);
        assert!(!clean.at(1.5, 1.5));
        assert!(clean.at(4.5, 4.5) && clean.at(8.5, 8.5) && clean.at(6.5, 6.5));
        assert!(!clean.at(3.5, 6.5) && !clean.at(9.5, 9.5));
        assert!(!clean.at(-0.5, 1.0) && !clean.at(10.0, 1.0));
    }
}
