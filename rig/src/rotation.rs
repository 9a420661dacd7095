//! How a video asks to be shown: the display matrix a phone writes when it films held in
//! portrait or upside down. The pixels are stored as the sensor read them and the matrix
//! says how a player turns them; frames come out of this crate as a player shows them, so
//! an imported calibration made from displayed frames fits, and so do the sizes in
//! `streams.json`. Right angles only, as FFmpeg's own command line applies them; any other
//! angle is ignored (no camera writes one).

#[cfg(feature = "ffmpeg")]
use ffmpeg::codec::packet::side_data::Type as SideDataType;
#[cfg(feature = "ffmpeg")]
use ffmpeg_next as ffmpeg;
use serde::{Deserialize, Serialize};

/// The quarter turns, clockwise, that make a stored frame look as displayed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(into = "u32", try_from = "u32")]
pub enum Rotation {
    #[default]
    None,
    Clockwise90,
    Half,
    Clockwise270,
}

impl Rotation {
    /// The rotation a video stream's display matrix asks for (`None` without one).
    #[cfg(feature = "ffmpeg")]
    pub fn of_stream(stream: &ffmpeg::format::stream::Stream) -> Self {
        stream
            .side_data()
            .find(|s| s.kind() == SideDataType::DisplayMatrix)
            .and_then(|s| display_matrix(s.data()))
            .map_or(Self::None, |m| Self::of_matrix(&m))
    }

    /// The rotation of a 3×3 display matrix in FFmpeg's layout (row-major, 16.16 fixed
    /// point in the first two columns): the clockwise angle a player turns the frame by,
    /// snapped to a right angle within 1°, else `None`.
    pub fn of_matrix(m: &[i32; 9]) -> Self {
        let fp = |v: i32| f64::from(v) / 65536.0;
        let (sx, sy) = (fp(m[0]).hypot(fp(m[3])), fp(m[1]).hypot(fp(m[4])));
        if sx == 0.0 || sy == 0.0 {
            return Self::None;
        }
        // FFmpeg's av_display_rotation_get is the counter-clockwise angle; a player turns
        // clockwise by its negation.
        let ccw = (fp(m[1]) / sy).atan2(fp(m[0]) / sx).to_degrees();
        let clockwise = ccw.rem_euclid(360.0);
        let quarter = (clockwise / 90.0).round();
        if (clockwise - quarter * 90.0).abs() > 1.0 {
            return Self::None;
        }
        match quarter as u32 % 4 {
            1 => Self::Clockwise90,
            2 => Self::Half,
            3 => Self::Clockwise270,
            _ => Self::None,
        }
    }

    /// Degrees clockwise.
    pub fn degrees(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Clockwise90 => 90,
            Self::Half => 180,
            Self::Clockwise270 => 270,
        }
    }

    /// Whether width and height trade places.
    pub fn swaps_axes(self) -> bool {
        matches!(self, Self::Clockwise90 | Self::Clockwise270)
    }

    /// The displayed size of a frame stored as `(w, h)`, or the stored size of one
    /// displayed as `(w, h)` (the same swap).
    pub fn turn_size(self, (w, h): (u32, u32)) -> (u32, u32) {
        if self.swaps_axes() { (h, w) } else { (w, h) }
    }

    /// `data` (packed rows of `w × h` pixels of `channels` bytes) turned as displayed.
    pub fn apply(self, data: &[u8], (w, h): (u32, u32), channels: usize) -> Vec<u8> {
        let (w, h) = (w as usize, h as usize);
        let (ow, _) = self.turn_size((w as u32, h as u32));
        let ow = ow as usize;
        let mut out = vec![0u8; data.len()];
        for y in 0..h {
            for x in 0..w {
                let (ox, oy) = match self {
                    Self::None => (x, y),
                    Self::Clockwise90 => (h - 1 - y, x),
                    Self::Half => (w - 1 - x, h - 1 - y),
                    Self::Clockwise270 => (y, w - 1 - x),
                };
                let src = (y * w + x) * channels;
                let dst = (oy * ow + ox) * channels;
                out[dst..dst + channels].copy_from_slice(&data[src..src + channels]);
            }
        }
        out
    }
}

impl From<Rotation> for u32 {
    fn from(r: Rotation) -> u32 {
        r.degrees()
    }
}

impl TryFrom<u32> for Rotation {
    type Error = String;
    fn try_from(degrees: u32) -> Result<Self, String> {
        match degrees {
            0 => Ok(Self::None),
            90 => Ok(Self::Clockwise90),
            180 => Ok(Self::Half),
            270 => Ok(Self::Clockwise270),
            d => Err(format!("rotation {d} is not 0, 90, 180 or 270")),
        }
    }
}

/// The nine little-endian `i32`s of a display-matrix side-data block.
fn display_matrix(bytes: &[u8]) -> Option<[i32; 9]> {
    let mut m = [0i32; 9];
    if bytes.len() < 36 {
        return None;
    }
    for (v, c) in m.iter_mut().zip(bytes.chunks_exact(4)) {
        *v = i32::from_ne_bytes([c[0], c[1], c[2], c[3]]);
    }
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The matrix FFmpeg's av_display_rotation_set writes for `ccw` degrees.
    fn matrix(ccw: f64) -> [i32; 9] {
        let (s, c) = ccw.to_radians().sin_cos();
        let fp = |v: f64| (v * 65536.0).round() as i32;
        [fp(c), fp(-s), 0, fp(s), fp(c), 0, 0, 0, 1 << 30]
    }

    #[test]
    fn right_angles_and_others() {
        assert_eq!(Rotation::of_matrix(&matrix(0.0)), Rotation::None);
        assert_eq!(Rotation::of_matrix(&matrix(-90.0)), Rotation::Clockwise90);
        assert_eq!(Rotation::of_matrix(&matrix(90.0)), Rotation::Clockwise270);
        assert_eq!(Rotation::of_matrix(&matrix(180.0)), Rotation::Half);
        assert_eq!(Rotation::of_matrix(&matrix(-89.6)), Rotation::Clockwise90);
        assert_eq!(Rotation::of_matrix(&matrix(30.0)), Rotation::None);
        assert_eq!(Rotation::of_matrix(&[0; 9]), Rotation::None);
    }

    #[test]
    fn turns_pixels_and_sizes() {
        // 3×2 frame, one byte per pixel: rows [0 1 2] [3 4 5].
        let data = [0u8, 1, 2, 3, 4, 5];
        let cw = Rotation::Clockwise90.apply(&data, (3, 2), 1);
        assert_eq!(cw, [3, 0, 4, 1, 5, 2]);
        let ccw = Rotation::Clockwise270.apply(&data, (3, 2), 1);
        assert_eq!(ccw, [2, 5, 1, 4, 0, 3]);
        assert_eq!(Rotation::Half.apply(&data, (3, 2), 1), [5, 4, 3, 2, 1, 0]);
        assert_eq!(Rotation::Clockwise90.turn_size((3, 2)), (2, 3));
        // Four quarter turns are the identity (RGB pixels).
        let rgb: Vec<u8> = (0..3 * 5 * 4).map(|v| v as u8).collect();
        let mut img = rgb.clone();
        let mut size = (5, 4);
        for _ in 0..4 {
            img = Rotation::Clockwise90.apply(&img, size, 3);
            size = Rotation::Clockwise90.turn_size(size);
        }
        assert_eq!(img, rgb);
    }

    #[test]
    fn degrees_round_trip() {
        for d in [0, 90, 180, 270] {
            assert_eq!(Rotation::try_from(d).unwrap().degrees(), d);
        }
        assert!(Rotation::try_from(45).is_err());
    }
}
