//! Training views: a pinhole camera, the exact model time of the frame and its image,
//! kept as `u8` RGB at the working resolution (a quarter of the memory of `f32`).

use crate::Camera;
use crate::model::TimeMapping;
use std::path::{Path, PathBuf};

/// An 8-bit RGB image, row-major, 3 bytes per pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImageU8 {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

/// Why an image could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ImageLoadError {
    #[error("cannot read image {path}: {source}; check that the frames stage finished")]
    Decode {
        path: PathBuf,
        source: image::ImageError,
    },
}

impl ImageU8 {
    /// From `f32` RGB in `[0, 1]` (rounded, clamped).
    pub fn from_f32(width: u32, height: u32, rgb: &[f32]) -> Self {
        Self {
            width,
            height,
            data: rgb
                .iter()
                .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
                .collect(),
        }
    }

    /// As `f32` RGB in `[0, 1]`, written into `out`.
    pub fn to_f32_into(&self, out: &mut Vec<f32>) {
        out.clear();
        out.extend(self.data.iter().map(|&v| v as f32 * (1.0 / 255.0)));
    }

    /// This image resized to `width`×`height` (triangle filter); a copy when the size is
    /// unchanged.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        let resized =
            image::RgbImage::from_raw(self.width, self.height, self.data.clone()).map(|img| {
                image::imageops::resize(&img, width, height, image::imageops::FilterType::Triangle)
            });
        match resized {
            Some(img) => Self {
                width,
                height,
                data: img.into_raw(),
            },
            // A buffer that does not hold width × height pixels: nothing to resample.
            None => self.clone(),
        }
    }

    /// Load a PNG/JPEG, resized (Lanczos-free triangle filter) to `size` when given.
    pub fn load(path: &Path, size: Option<(u32, u32)>) -> Result<Self, ImageLoadError> {
        let err = |source| ImageLoadError::Decode {
            path: path.to_path_buf(),
            source,
        };
        let mut img = image::open(path).map_err(err)?.into_rgb8();
        if let Some((w, h)) = size
            && (w, h) != img.dimensions()
        {
            img = image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
        }
        let (width, height) = img.dimensions();
        Ok(Self {
            width,
            height,
            data: img.into_raw(),
        })
    }
}

/// One training image.
#[derive(Clone, Debug)]
pub struct View {
    /// Pinhole camera whose intrinsics match the image size.
    pub camera: Camera,
    /// Model time of this exact frame (see [`TimeMapping::model_time`]).
    pub time: f32,
    pub image: ImageU8,
}

impl View {
    /// A view whose camera intrinsics are rescaled to the image's size (working resolution).
    pub fn at_image_size(mut camera: Camera, time: f32, image: ImageU8) -> Self {
        camera.intrinsics = camera.intrinsics.scaled_to(image.width, image.height);
        Self {
            camera,
            time,
            image,
        }
    }
}

/// Every training view and the sequence's time mapping.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub views: Vec<View>,
    pub time_mapping: TimeMapping,
}

impl Dataset {
    /// Every view resized to `factor` of its width and height (triangle filter, at least
    /// 1×1 pixel), with its intrinsics rescaled to match.
    pub fn downscaled(&self, factor: f64) -> Self {
        use rayon::prelude::*;
        let views = self
            .views
            .par_iter()
            .map(|v| {
                let size = |n: u32| ((n as f64 * factor).round() as u32).max(1);
                let (w, h) = (size(v.image.width), size(v.image.height));
                View::at_image_size(v.camera.clone(), v.time, v.image.resized(w, h))
            })
            .collect();
        Self {
            views,
            time_mapping: self.time_mapping,
        }
    }

    /// One camera per camera name, in the order the views first show them.
    pub fn cameras(&self) -> Vec<Camera> {
        let mut cameras: Vec<Camera> = Vec::new();
        for v in &self.views {
            if !cameras.iter().any(|c| c.name == v.camera.name) {
                cameras.push(v.camera.clone());
            }
        }
        cameras
    }

    /// Radius of the camera centres around their mean × 1.1 (3DGS "scene extent"), at
    /// least 1e-3; 1 for a single camera.
    pub fn scene_extent(&self) -> f64 {
        let centres: Vec<_> = self
            .views
            .iter()
            .map(|v| v.camera.world_to_camera.centre())
            .collect();
        if centres.is_empty() {
            return 1.0;
        }
        let mean = centres.iter().copied().sum::<glam::DVec3>() / centres.len() as f64;
        let r = centres
            .iter()
            .map(|c| (*c - mean).length())
            .fold(0.0, f64::max)
            * 1.1;
        if r > 1e-3 { r } else { 1.0 }
    }
}

/// Where one training frame lives on disk.
#[derive(Clone, Debug)]
pub struct FrameSource {
    pub camera: Camera,
    /// Model time of the frame.
    pub time: f32,
    pub path: PathBuf,
}

impl Dataset {
    /// Load every frame (in parallel) at the working resolution `width` (height keeps the
    /// camera's aspect ratio; `None`: the camera's own size), rescaling the intrinsics.
    pub fn load(
        frames: &[FrameSource],
        width: Option<u32>,
        time_mapping: TimeMapping,
    ) -> Result<Self, ImageLoadError> {
        use rayon::prelude::*;
        let views = frames
            .par_iter()
            .map(|f| {
                let i = &f.camera.intrinsics;
                let size = match width {
                    Some(w) if w > 0 && w != i.width => {
                        let h = ((i.height as f64 * w as f64 / i.width.max(1) as f64).round()
                            as u32)
                            .max(1);
                        (w, h)
                    }
                    _ => (i.width, i.height),
                };
                let image = ImageU8::load(&f.path, Some(size))?;
                Ok(View::at_image_size(f.camera.clone(), f.time, image))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            views,
            time_mapping,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::TimeMapping;

    #[test]
    fn downscaling_averages_pixels_and_rescales_the_camera() {
        let camera = crate::Camera {
            name: "cam0".into(),
            intrinsics: shared_types::Intrinsics::from_hfov(4, 2, 60.0),
            distortion: Default::default(),
            world_to_camera: shared_types::WorldToCamera::IDENTITY,
        };
        // Left half black, right half grey 200: the filter keeps the mean and the edge.
        let mut data = Vec::new();
        for _ in 0..2 {
            for x in 0..4 {
                data.extend([if x < 2 { 0u8 } else { 200 }; 3]);
            }
        }
        let image = ImageU8 {
            width: 4,
            height: 2,
            data,
        };
        let dataset = Dataset {
            views: vec![View::at_image_size(camera.clone(), 0.5, image)],
            time_mapping: TimeMapping::frames_over_30(0.0, 30.0, 1.0),
        };
        let half = dataset.downscaled(0.5);
        let v = &half.views[0];
        assert_eq!((v.image.width, v.image.height), (2, 1));
        let d = &v.image.data;
        assert!(d[0] < 50 && d[3] > 150, "{d:?}");
        assert!((d[0] as i32 + d[3] as i32 - 200).abs() <= 1, "{d:?}");
        assert_eq!(v.camera.intrinsics.width, 2);
        assert!((v.camera.intrinsics.fx - camera.intrinsics.fx / 2.0).abs() < 1e-12);
        assert!((v.camera.intrinsics.cx - camera.intrinsics.cx / 2.0).abs() < 1e-12);
        assert_eq!(v.time, 0.5);
        // A tiny factor keeps at least one pixel.
        assert_eq!(dataset.downscaled(0.01).views[0].image.data.len(), 3);
    }
}
