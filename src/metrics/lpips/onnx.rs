//! LPIPS from a user-supplied ONNX model (`[eval] lpips = "model.onnx"`), run with
//! `tract` (pure Rust). The model takes two images `1×3×H×W` with values in `[-1, 1]`
//! and returns one number (any shape with a single element). docs/render-eval.md shows
//! how to export one from the `lpips` Python package. The default LPIPS needs no ONNX
//! (`alex`).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use tract_onnx::prelude::*;

use super::LpipsError;

type Plan = Arc<TypedRunnableModel>;

/// A loaded LPIPS ONNX model. Plans are built per image size (the last one is cached), so
/// evaluating many frames of one size builds one plan.
pub struct OnnxLpips {
    path: PathBuf,
    model: InferenceModel,
    cache: Mutex<Option<((usize, usize), Plan)>>,
}

impl std::fmt::Debug for OnnxLpips {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxLpips")
            .field("path", &self.path)
            .finish()
    }
}

/// Size used to check the interface when loading (large enough for AlexNet/VGG).
const PROBE: usize = 64;

impl OnnxLpips {
    /// Load and check an LPIPS ONNX model: two inputs, one single-element output.
    pub fn load(path: &Path) -> Result<Self, LpipsError> {
        let bytes = std::fs::read(path).map_err(|source| LpipsError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let model = tract_onnx::onnx()
            .model_for_read(&mut bytes.as_slice())
            .map_err(|e| LpipsError::Corrupt {
                path: path.to_path_buf(),
                message: format!("{e:#}"),
            })?;
        let wrong = |message: String| LpipsError::WrongInterface {
            path: path.to_path_buf(),
            message,
        };
        let inputs = model
            .input_outlets()
            .map_err(|e| wrong(format!("{e:#}")))?
            .len();
        if inputs != 2 {
            return Err(wrong(format!("it has {inputs} input(s), expected 2")));
        }
        let outputs = model
            .output_outlets()
            .map_err(|e| wrong(format!("{e:#}")))?
            .len();
        if outputs != 1 {
            return Err(wrong(format!("it has {outputs} outputs, expected 1")));
        }
        let lpips = Self {
            path: path.to_path_buf(),
            model,
            cache: Mutex::new(None),
        };
        // Build a plan once so shape problems surface now, not in the middle of an eval.
        lpips.plan(PROBE, PROBE).map_err(|e| match e {
            LpipsError::Run { message, .. } => wrong(message),
            other => other,
        })?;
        Ok(lpips)
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn plan(&self, width: usize, height: usize) -> Result<Plan, LpipsError> {
        if let Ok(guard) = self.cache.lock()
            && let Some((size, plan)) = guard.as_ref()
            && *size == (width, height)
        {
            return Ok(plan.clone());
        }
        let run_err = |e: TractError| LpipsError::Run {
            path: self.path.clone(),
            width,
            height,
            message: format!("{e:#}"),
        };
        let fact = || -> InferenceFact { f32::fact([1, 3, height, width]).into() };
        let typed = self
            .model
            .clone()
            .with_input_fact(0, fact())
            .and_then(|m| m.with_input_fact(1, fact()))
            .and_then(|m| m.into_optimized())
            .map_err(run_err)?;
        let out = typed.output_fact(0).map_err(run_err)?;
        if let Some(shape) = out.shape.as_concrete()
            && shape.iter().product::<usize>() != 1
        {
            return Err(LpipsError::Run {
                path: self.path.clone(),
                width,
                height,
                message: format!("its output has shape {shape:?}, expected a single number"),
            });
        }
        let plan = typed.into_runnable().map_err(run_err)?;
        if let Ok(mut guard) = self.cache.lock() {
            *guard = Some(((width, height), plan.clone()));
        }
        Ok(plan)
    }

    /// LPIPS distance of two interleaved RGB images in `[0, 1]` (`width × height`).
    pub fn distance(
        &self,
        a: &[f32],
        b: &[f32],
        width: usize,
        height: usize,
    ) -> Result<f64, LpipsError> {
        let expected = 3 * width * height;
        if a.len() != expected || b.len() != expected || expected == 0 {
            return Err(LpipsError::ImageSize {
                width,
                height,
                expected,
                got_a: a.len(),
                got_b: b.len(),
            });
        }
        let plan = self.plan(width, height)?;
        let run_err = |message: String| LpipsError::Run {
            path: self.path.clone(),
            width,
            height,
            message,
        };
        let to_tensor = |img: &[f32]| -> Result<TValue, LpipsError> {
            let n = width * height;
            let mut planar = vec![0.0f32; expected];
            for (i, px) in img.chunks_exact(3).enumerate() {
                for c in 0..3 {
                    planar[c * n + i] = 2.0 * px[c] - 1.0;
                }
            }
            Tensor::from_shape(&[1, 3, height, width], &planar)
                .map(TValue::from)
                .map_err(|e| run_err(format!("{e:#}")))
        };
        let out = plan
            .run(tvec!(to_tensor(a)?, to_tensor(b)?))
            .map_err(|e| run_err(format!("{e:#}")))?;
        let first = out.first().ok_or_else(|| run_err("no output".into()))?;
        let view = first
            .to_plain_array_view::<f32>()
            .map_err(|e| run_err(format!("{e:#}")))?;
        match view.iter().next() {
            Some(v) if view.len() == 1 => Ok(*v as f64),
            _ => Err(run_err(format!(
                "output has {} values, expected one",
                view.len()
            ))),
        }
    }
}
