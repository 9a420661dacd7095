//! What is composited behind the Gaussians while training, and what every render of the
//! trained model is drawn on. Where four cameras leave part of a held-out view unseen, that
//! part shows it: a learned backdrop (the default, [`crate::render::backdrop`]) draws the
//! far walls the cameras saw, from wherever one looks, and fades to the training images'
//! mean colour where they saw nothing; the mean colour alone is the least wrong flat guess,
//! black the most wrong for a bright room.

use serde::{Deserialize, Serialize};

use crate::train::Dataset;

/// `[train] background`: `"mean"`, `"learned"` or an `[r, g, b]` colour in `0..1`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Spelling", into = "Spelling")]
pub enum Background {
    /// The mean colour of every training image, resolved when training starts.
    Mean,
    /// The Gaussians train on the mean colour; then a backdrop is fitted behind them: a
    /// texture on a sphere around the rig at the static scene's far walls.
    #[default]
    Learned,
    /// A fixed colour.
    Colour([f32; 3]),
}

/// How a [`Background`] is written in `capture.toml`.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum Spelling {
    Word(String),
    Colour([f32; 3]),
}

impl TryFrom<Spelling> for Background {
    type Error = String;
    fn try_from(s: Spelling) -> Result<Self, String> {
        match s {
            Spelling::Word(w) if w == "mean" => Ok(Self::Mean),
            Spelling::Word(w) if w == "learned" => Ok(Self::Learned),
            Spelling::Word(w) => Err(format!(
                "unknown background {w:?}: use \"mean\", \"learned\" or a colour [r, g, b] in 0..1"
            )),
            Spelling::Colour(c) => Ok(Self::Colour(c)),
        }
    }
}

impl From<Background> for Spelling {
    fn from(b: Background) -> Self {
        match b {
            Background::Mean => Spelling::Word("mean".into()),
            Background::Learned => Spelling::Word("learned".into()),
            Background::Colour(c) => Spelling::Colour(c),
        }
    }
}

impl Background {
    /// The colour this background is for `dataset` (`Mean`: its images' mean colour, black
    /// for an empty dataset; `Learned`: the same, which the Gaussians train on and the
    /// backdrop starts from and fades to).
    pub fn resolve(&self, dataset: &Dataset) -> [f32; 3] {
        match *self {
            Self::Colour(c) => c,
            Self::Mean | Self::Learned => mean_colour(dataset),
        }
    }
}

/// The mean colour of every pixel of every view (each view weighs by its pixel count).
pub fn mean_colour(dataset: &Dataset) -> [f32; 3] {
    let mut sum = [0u64; 3];
    let mut pixels = 0u64;
    for view in &dataset.views {
        for px in view.image.data.chunks_exact(3) {
            for c in 0..3 {
                sum[c] += u64::from(px[c]);
            }
        }
        pixels += (view.image.data.len() / 3) as u64;
    }
    if pixels == 0 {
        return [0.0; 3];
    }
    sum.map(|s| (s as f64 / pixels as f64 / 255.0) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::{ImageU8, View};

    #[derive(serde::Deserialize)]
    struct Section {
        background: Background,
    }

    fn parse(text: &str) -> Result<Background, String> {
        toml::from_str::<Section>(text)
            .map(|s| s.background)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn the_keyword_and_colours_parse_and_round_trip() {
        assert_eq!(parse("background = \"mean\""), Ok(Background::Mean));
        assert_eq!(parse("background = \"learned\""), Ok(Background::Learned));
        assert_eq!(
            parse("background = [0.5, 0.25, 1.0]"),
            Ok(Background::Colour([0.5, 0.25, 1.0]))
        );
        assert!(parse("background = \"grey\"").is_err());
        assert!(parse("background = [0.5, 0.25]").is_err());
        for b in [
            Background::Mean,
            Background::Learned,
            Background::Colour([0.1, 0.2, 0.3]),
        ] {
            let json = serde_json::to_string(&b).unwrap();
            assert_eq!(serde_json::from_str::<Background>(&json).unwrap(), b);
        }
        assert_eq!(
            serde_json::to_string(&Background::Mean).unwrap(),
            "\"mean\""
        );
    }

    #[test]
    fn the_mean_weighs_every_pixel_of_every_view() {
        let camera = crate::Camera {
            name: "cam0".into(),
            intrinsics: shared_types::Intrinsics::from_hfov(4, 1, 60.0),
            distortion: Default::default(),
            world_to_camera: shared_types::WorldToCamera::IDENTITY,
        };
        let view = |w: u32, rgb: [u8; 3]| {
            let image = ImageU8 {
                width: w,
                height: 1,
                data: rgb.repeat(w as usize),
            };
            View::at_image_size(camera.clone(), 0.0, image)
        };
        let data = Dataset {
            views: vec![view(1, [255, 0, 0]), view(3, [0, 255, 51])],
            time_mapping: crate::model::TimeMapping::frames_over_30(0.0, 30.0, 1.0),
        };
        let m = Background::Mean.resolve(&data);
        let want = [0.25f32, 0.75, 0.15];
        for c in 0..3 {
            assert!((m[c] - want[c]).abs() < 1e-6, "{m:?}");
        }
        assert_eq!(
            Background::Colour([0.1, 0.2, 0.3]).resolve(&data),
            [0.1, 0.2, 0.3]
        );
        let empty = Dataset {
            views: vec![],
            time_mapping: crate::model::TimeMapping::frames_over_30(0.0, 30.0, 1.0),
        };
        assert_eq!(Background::Mean.resolve(&empty), [0.0; 3]);
    }
}
