//! Running a MASt3R-style point-map model (ONNX) in pure Rust with `tract-onnx`, in a
//! build with the `onnx` feature; without it, [`PointMapModel::load`] is
//! [`OnnxError::NotBuilt`].
//!
//! The model takes two images (`1×3×H×W` float32, normalised like MASt3R:
//! `(rgb/255 − 0.5) / 0.5`) and returns both views' point maps (`1×H'×W'×3`) in the first
//! image's camera frame plus their confidences (`1×H'×W'`); input and output names and the
//! input size come from [`ModelConfig`]. Anything wrong with the file or its shapes is an
//! [`OnnxError`], never a panic (tract's own panics on malformed graphs are caught too).

use std::path::{Path, PathBuf};

use image::RgbImage;
use serde::{Deserialize, Serialize};
#[cfg(feature = "onnx")]
use tract_onnx::prelude::*;

#[cfg(feature = "onnx")]
use super::npy::{Array, point_map};
use super::npy::{OutputNames, PairMaps};

/// Names and input size of a point-map model.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Names of the two image inputs (first, second).
    pub input_names: [String; 2],
    /// Names of the four outputs (also the array names of exported `.npz` files).
    pub output_names: OutputNames,
    /// `[width, height]` the images are resized to before the model (MASt3R: 512×384).
    pub input_size: [u32; 2],
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            input_names: ["img1".into(), "img2".into()],
            output_names: OutputNames::default(),
            input_size: [512, 384],
        }
    }
}

/// Why a model could not be loaded or run.
#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error(
        "{path}: this build runs no ONNX models; build with the `onnx` feature (`cargo build --release -p pipeline --features onnx`), or export the point maps to .npz and set [init] source = \"npz\""
    )]
    NotBuilt { path: PathBuf },
    #[error("cannot read ONNX model {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path} is not a usable ONNX point-map model: {reason}; check the file and [init] input_names/output_names/input_size"
    )]
    Load { path: PathBuf, reason: String },
    #[error("running {path} failed: {reason}")]
    Run { path: PathBuf, reason: String },
    #[error(
        "{path} output `{name}` has shape {shape:?}, expected {expected}; check [init] output_names"
    )]
    OutputShape {
        path: PathBuf,
        name: String,
        shape: Vec<usize>,
        expected: &'static str,
    },
}

/// The optimised graph (none can exist without the `onnx` feature).
#[cfg(feature = "onnx")]
type Plan = std::sync::Arc<TypedRunnableModel>;
#[cfg(not(feature = "onnx"))]
type Plan = std::convert::Infallible;

/// A loaded, optimised point-map model ready to run on image pairs.
pub struct PointMapModel {
    path: PathBuf,
    plan: Plan,
    config: ModelConfig,
}

impl std::fmt::Debug for PointMapModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PointMapModel")
            .field("path", &self.path)
            .field("config", &self.config)
            .finish()
    }
}

#[cfg(feature = "onnx")]
fn caught<T>(f: impl FnOnce() -> TractResult<T>) -> Result<T, String> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(format!("{e:#}")),
        Err(p) => Err(format!(
            "tract panicked: {}",
            p.downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| p.downcast_ref::<&str>().copied())
                .unwrap_or("unknown")
        )),
    }
}

impl PointMapModel {
    /// Without the `onnx` feature: [`OnnxError::NotBuilt`].
    #[cfg(not(feature = "onnx"))]
    pub fn load(path: &Path, _config: &ModelConfig) -> Result<Self, OnnxError> {
        Err(OnnxError::NotBuilt { path: path.into() })
    }

    #[cfg(not(feature = "onnx"))]
    pub fn run(&self, _first: &RgbImage, _second: &RgbImage) -> Result<PairMaps, OnnxError> {
        match self.plan {}
    }

    /// Load and optimise `path` for inputs of `config.input_size`.
    #[cfg(feature = "onnx")]
    pub fn load(path: &Path, config: &ModelConfig) -> Result<Self, OnnxError> {
        let bytes = std::fs::read(path).map_err(|source| OnnxError::Io {
            path: path.into(),
            source,
        })?;
        let [w, h] = config.input_size;
        if w == 0 || h == 0 {
            return Err(OnnxError::Load {
                path: path.into(),
                reason: format!("input_size {w}×{h} is empty"),
            });
        }
        let names = &config.output_names;
        let outputs = [&names.pts1, &names.conf1, &names.pts2, &names.conf2];
        let plan = caught(|| {
            let mut model = tract_onnx::onnx().model_for_read(&mut &bytes[..])?;
            model.set_input_names(&config.input_names)?;
            model.select_outputs_by_name(outputs)?;
            let fact = f32::fact([1, 3, h as usize, w as usize]);
            for i in 0..2 {
                model.set_input_fact(i, fact.clone().into())?;
            }
            model.into_optimized()?.into_runnable()
        })
        .map_err(|reason| OnnxError::Load {
            path: path.into(),
            reason,
        })?;
        Ok(Self {
            path: path.into(),
            plan,
            config: config.clone(),
        })
    }

    /// Run on one image pair (any size: resized to the model's input size).
    #[cfg(feature = "onnx")]
    pub fn run(&self, first: &RgbImage, second: &RgbImage) -> Result<PairMaps, OnnxError> {
        let [w, h] = self.config.input_size;
        let outputs = caught(|| {
            let inputs: TVec<TValue> = tvec![
                image_tensor(first, w, h)?.into(),
                image_tensor(second, w, h)?.into()
            ];
            self.plan.run(inputs)
        })
        .map_err(|reason| OnnxError::Run {
            path: self.path.clone(),
            reason,
        })?;
        let names = &self.config.output_names;
        let mut arrays = Vec::with_capacity(4);
        for (i, name) in [&names.pts1, &names.conf1, &names.pts2, &names.conf2]
            .into_iter()
            .enumerate()
        {
            let t = outputs.get(i).ok_or_else(|| OnnxError::Run {
                path: self.path.clone(),
                reason: format!("output `{name}` missing"),
            })?;
            let data = caught(|| {
                let t = t.cast_to::<f32>()?;
                Ok(t.to_plain_array_view::<f32>()?
                    .iter()
                    .copied()
                    .collect::<Vec<f32>>())
            })
            .map_err(|reason| OnnxError::Run {
                path: self.path.clone(),
                reason: format!("output `{name}`: {reason}"),
            })?;
            arrays.push(Array {
                shape: t.shape().to_vec(),
                data,
            });
        }
        let shape_err = |name: &String, a: &Array, expected| OnnxError::OutputShape {
            path: self.path.clone(),
            name: name.clone(),
            shape: a.shape.clone(),
            expected,
        };
        let [pts1, conf1, pts2, conf2]: [Array; 4] =
            arrays.try_into().map_err(|_| OnnxError::Run {
                path: self.path.clone(),
                reason: "wrong number of outputs".into(),
            })?;
        if !matches!(pts1.shape.as_slice(), [1, _, _, 3]) {
            return Err(shape_err(&names.pts1, &pts1, "1×H×W×3"));
        }
        if !matches!(pts2.shape.as_slice(), [1, _, _, 3]) {
            return Err(shape_err(&names.pts2, &pts2, "1×H×W×3"));
        }
        for (n, c, p) in [(&names.conf1, &conf1, &pts1), (&names.conf2, &conf2, &pts2)] {
            if c.shape.len() != 3 || c.shape[0] != 1 || c.shape[1..] != p.shape[1..3] {
                return Err(shape_err(n, c, "1×H×W matching its point map"));
            }
        }
        let to_run = |e: super::npy::NpyError| OnnxError::Run {
            path: self.path.clone(),
            reason: e.to_string(),
        };
        Ok(PairMaps {
            first: point_map(pts1, Some(conf1), &self.path).map_err(to_run)?,
            second: point_map(pts2, Some(conf2), &self.path).map_err(to_run)?,
        })
    }

    /// The model's input size `[width, height]`.
    pub fn input_size(&self) -> [u32; 2] {
        self.config.input_size
    }
}

/// `1×3×h×w` MASt3R-normalised tensor of `img` resized to `w×h` (bilinear).
#[cfg(feature = "onnx")]
pub fn image_tensor(img: &RgbImage, w: u32, h: u32) -> TractResult<Tensor> {
    let resized;
    let img = if img.dimensions() == (w, h) {
        img
    } else {
        resized = image::imageops::resize(img, w, h, image::imageops::FilterType::Triangle);
        &resized
    };
    let (w, h) = (w as usize, h as usize);
    let mut data = vec![0f32; 3 * w * h];
    for (x, y, p) in img.enumerate_pixels() {
        for c in 0..3 {
            data[c * w * h + y as usize * w + x as usize] = (p[c] as f32 / 255.0 - 0.5) / 0.5;
        }
    }
    Tensor::from_shape(&[1, 3, h, w], &data)
}
