//! A build without the `onnx` feature: no ONNX model can be loaded, and asking for one
//! (`[eval] lpips = "model.onnx"`) is [`LpipsError::OnnxNotBuilt`].

use std::convert::Infallible;
use std::path::Path;

use super::LpipsError;

/// An LPIPS ONNX model; none can exist in this build.
#[derive(Debug)]
pub struct OnnxLpips(Infallible);

impl OnnxLpips {
    /// Always [`LpipsError::OnnxNotBuilt`].
    pub fn load(path: &Path) -> Result<Self, LpipsError> {
        Err(LpipsError::OnnxNotBuilt {
            path: path.to_path_buf(),
        })
    }

    pub fn path(&self) -> &Path {
        match self.0 {}
    }

    pub fn distance(&self, _: &[f32], _: &[f32], _: usize, _: usize) -> Result<f64, LpipsError> {
        match self.0 {}
    }
}
