//! A capture's training views stretched in time and size (`pipeline bench tradeoff
//! --stretch FRAMES:WxH`): what training a long, large capture costs, measured from a short,
//! small one that fits where the long one does not (a GPU node reached with a few tens of
//! MB). Each camera gets `FRAMES` frames spread evenly over the time its own frames span,
//! each a copy of its frame nearest in time resized to W×H, with the intrinsics rescaled.
//! The cost of a training step depends on the image size, the Gaussians and the number of
//! distinct frames, not on the pixels' content; the novel views of such a model are no
//! better than the short capture's.

use std::str::FromStr;

use rayon::prelude::*;
use splat4d::train::{Dataset, View};

/// Frames per camera and their size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stretch {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
}

impl FromStr for Stretch {
    type Err = String;

    /// `FRAMES:WxH`, e.g. `300:1352x1014`.
    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || {
            format!(
                "'{text}' is not FRAMES:WxH (frames per camera and their size, e.g. 300:1352x1014)"
            )
        };
        let (frames, size) = text.trim().split_once(':').ok_or_else(bad)?;
        let (width, height) = size.split_once(['x', '×']).ok_or_else(bad)?;
        let stretch = Self {
            frames: frames.trim().parse().map_err(|_| bad())?,
            width: width.trim().parse().map_err(|_| bad())?,
            height: height.trim().parse().map_err(|_| bad())?,
        };
        if stretch.frames == 0 || stretch.width == 0 || stretch.height == 0 {
            return Err(format!(
                "{}: frames, width and height must be above 0",
                bad()
            ));
        }
        Ok(stretch)
    }
}

impl std::fmt::Display for Stretch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}x{}", self.frames, self.width, self.height)
    }
}

impl Stretch {
    /// `dataset`'s views stretched: per camera (in the order cameras first appear),
    /// `self.frames` views at times spread evenly from its first frame's to its last's,
    /// each its frame nearest in time (the earlier on a tie) at `width × height`.
    pub fn apply(&self, dataset: &Dataset) -> Dataset {
        let mut cameras: Vec<&str> = Vec::new();
        for v in &dataset.views {
            if !cameras.contains(&v.camera.name.as_str()) {
                cameras.push(&v.camera.name);
            }
        }
        let picks: Vec<(&View, f32)> = cameras
            .iter()
            .flat_map(|name| {
                let own: Vec<&View> = dataset
                    .views
                    .iter()
                    .filter(|v| v.camera.name == *name)
                    .collect();
                let first = own.iter().map(|v| v.time).fold(f32::INFINITY, f32::min);
                let last = own.iter().map(|v| v.time).fold(f32::NEG_INFINITY, f32::max);
                (0..self.frames).map(move |k| {
                    let f = if self.frames > 1 {
                        k as f32 / (self.frames - 1) as f32
                    } else {
                        0.0
                    };
                    let time = first + (last - first) * f;
                    let nearest = own
                        .iter()
                        .copied()
                        .min_by(|a, b| (a.time - time).abs().total_cmp(&(b.time - time).abs()))
                        .expect("a camera with views");
                    (nearest, time)
                })
            })
            .collect();
        let views = picks
            .into_par_iter()
            .map(|(v, time)| {
                View::at_image_size(
                    v.camera.clone(),
                    time,
                    v.image.resized(self.width, self.height),
                )
            })
            .collect();
        Dataset {
            views,
            time_mapping: dataset.time_mapping,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::{Camera, Intrinsics, WorldToCamera};
    use splat4d::TimeMapping;
    use splat4d::train::ImageU8;

    fn view(camera: &str, time: f32, grey: u8) -> View {
        let camera = Camera {
            name: camera.into(),
            intrinsics: Intrinsics::from_hfov(8, 6, 60.0),
            distortion: Default::default(),
            world_to_camera: WorldToCamera::IDENTITY,
        };
        let image = ImageU8 {
            width: 8,
            height: 6,
            data: vec![grey; 8 * 6 * 3],
        };
        View::at_image_size(camera, time, image)
    }

    #[test]
    fn each_camera_gets_its_frames_spread_over_its_time_from_the_nearest_frame() {
        // cam0 filmed at 0, 0.5, 1 (grey 10, 20, 30); cam1 at 0.2 and 0.8 (grey 40, 50).
        let dataset = Dataset {
            views: vec![
                view("cam0", 0.0, 10),
                view("cam1", 0.2, 40),
                view("cam0", 0.5, 20),
                view("cam1", 0.8, 50),
                view("cam0", 1.0, 30),
            ],
            time_mapping: TimeMapping::frames_over_30(0.0, 30.0, 1.0),
        };
        let stretch: Stretch = "5:16x12".parse().unwrap();
        let out = stretch.apply(&dataset);
        assert_eq!(out.views.len(), 10);
        let got: Vec<(&str, f32, u8)> = out
            .views
            .iter()
            .map(|v| (v.camera.name.as_str(), v.time, v.image.data[0]))
            .collect();
        let want = [
            ("cam0", 0.0, 10),
            ("cam0", 0.25, 10), // a tie between 0 and 0.5: the earlier frame
            ("cam0", 0.5, 20),
            ("cam0", 0.75, 20),
            ("cam0", 1.0, 30),
            ("cam1", 0.2, 40),
            ("cam1", 0.35, 40),
            ("cam1", 0.5, 40),
            ("cam1", 0.65, 50),
            ("cam1", 0.8, 50),
        ];
        for ((name, time, grey), (wn, wt, wg)) in got.iter().zip(want) {
            assert_eq!((*name, *grey), (wn, wg), "{got:?}");
            assert!((time - wt).abs() < 1e-6, "{got:?}");
        }
        for v in &out.views {
            assert_eq!((v.image.width, v.image.height), (16, 12));
            assert_eq!(v.image.data.len(), 16 * 12 * 3);
            assert_eq!(v.camera.intrinsics.width, 16);
            let fx = dataset.views[0].camera.intrinsics.fx;
            assert!((v.camera.intrinsics.fx - 2.0 * fx).abs() < 1e-9);
        }
        assert_eq!(out.time_mapping, dataset.time_mapping);
        // One frame per camera: its first.
        let one = Stretch {
            frames: 1,
            ..stretch
        }
        .apply(&dataset);
        assert_eq!(one.views.len(), 2);
        assert_eq!((one.views[1].time, one.views[1].image.data[0]), (0.2, 40));
    }

    #[test]
    fn stretches_are_read_from_the_command_line_or_refused_saying_the_form() {
        assert_eq!(
            "300:1352x1014".parse::<Stretch>(),
            Ok(Stretch {
                frames: 300,
                width: 1352,
                height: 1014
            })
        );
        assert_eq!(
            "300:1352x1014".parse::<Stretch>().unwrap().to_string(),
            "300:1352x1014"
        );
        for bad in ["300", "300:1352", "x:1x1", "0:10x10", "3:0x5", "3:4x"] {
            let err = bad.parse::<Stretch>().unwrap_err();
            assert!(err.contains("FRAMES:WxH") && err.contains(bad), "{err}");
        }
    }
}
