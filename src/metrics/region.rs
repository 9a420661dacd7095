//! The part of an image a metric that needs whole windows (LPIPS) can measure for a mask:
//! the mask's bounding box with a margin, grown to a least side and kept inside the image,
//! and the crop of an RGB image to it.

/// A pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

impl Rect {
    pub fn width(&self) -> usize {
        self.x1 - self.x0
    }

    pub fn height(&self) -> usize {
        self.y1 - self.y0
    }
}

/// The bounding box of the set pixels of `mask` (`width × height`, row-major), `margin`
/// pixels wider on every side, then grown about its centre to at least `min_side` along
/// each axis (as far as the image allows) and clipped to the image; `None` for an empty
/// mask.
pub fn mask_box(
    mask: &[bool],
    width: usize,
    height: usize,
    margin: usize,
    min_side: usize,
) -> Option<Rect> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = (i % width, i / width);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x + 1);
        y1 = y1.max(y + 1);
    }
    if x0 == usize::MAX {
        return None;
    }
    let (x0, x1) = grow(x0, x1, margin, min_side, width);
    let (y0, y1) = grow(y0, y1, margin, min_side, height);
    Some(Rect { x0, y0, x1, y1 })
}

/// `[a, b)` widened by `margin` each side and to at least `min_side` about its centre,
/// inside `[0, size)`.
fn grow(a: usize, b: usize, margin: usize, min_side: usize, size: usize) -> (usize, usize) {
    let (a, b) = (a.saturating_sub(margin), (b + margin).min(size));
    let want = min_side.min(size);
    if b - a >= want {
        return (a, b);
    }
    let start = ((a + b).saturating_sub(want) / 2).min(size - want);
    (start, start + want)
}

/// The pixels of `rect` of an interleaved RGB image of width `width`, row-major.
pub fn crop_rgb<F: Copy>(image: &[F], width: usize, rect: Rect) -> Vec<F> {
    let mut out = Vec::with_capacity(rect.width() * rect.height() * 3);
    for y in rect.y0..rect.y1 {
        let row = (y * width + rect.x0) * 3;
        out.extend_from_slice(&image[row..row + rect.width() * 3]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(width: usize, height: usize, on: &[(usize, usize)]) -> Vec<bool> {
        let mut m = vec![false; width * height];
        for &(x, y) in on {
            m[y * width + x] = true;
        }
        m
    }

    #[test]
    fn the_box_holds_the_mask_with_its_margin() {
        let m = mask(100, 80, &[(40, 30), (49, 35)]);
        let r = mask_box(&m, 100, 80, 4, 0).unwrap();
        assert_eq!(
            r,
            Rect {
                x0: 36,
                y0: 26,
                x1: 54,
                y1: 40
            }
        );
        assert!(mask_box(&vec![false; 100 * 80], 100, 80, 4, 32).is_none());
    }

    #[test]
    fn a_small_box_grows_to_the_least_side_inside_the_image() {
        // In the middle: grown about its centre.
        let r = mask_box(&mask(100, 80, &[(50, 40)]), 100, 80, 0, 32).unwrap();
        assert_eq!((r.width(), r.height()), (32, 32));
        assert!(r.x0 <= 50 && r.x1 > 50 && r.y0 <= 40 && r.y1 > 40);
        // In corners: pushed inside, still the least side.
        for &(x, y) in &[(0, 0), (99, 79), (0, 79), (99, 0)] {
            let r = mask_box(&mask(100, 80, &[(x, y)]), 100, 80, 2, 32).unwrap();
            assert_eq!((r.width(), r.height()), (32, 32), "{x},{y}: {r:?}");
            assert!(r.x1 <= 100 && r.y1 <= 80 && r.x0 <= x && x < r.x1 && r.y0 <= y && y < r.y1);
        }
        // An image smaller than the least side: the whole image.
        let r = mask_box(&mask(20, 10, &[(3, 3)]), 20, 10, 0, 32).unwrap();
        assert_eq!(
            r,
            Rect {
                x0: 0,
                y0: 0,
                x1: 20,
                y1: 10
            }
        );
    }

    #[test]
    fn the_crop_is_the_rectangle_row_by_row() {
        let (w, h) = (5, 4);
        let image: Vec<usize> = (0..w * h * 3).collect();
        let rect = Rect {
            x0: 1,
            y0: 2,
            x1: 3,
            y1: 4,
        };
        let c = crop_rgb(&image, w, rect);
        let expect: Vec<usize> = [(1, 2), (2, 2), (1, 3), (2, 3)]
            .iter()
            .flat_map(|&(x, y)| (0..3).map(move |k| (y * w + x) * 3 + k))
            .collect();
        assert_eq!(c, expect);
    }
}
