//! LPIPS (learned perceptual image patch similarity, lower is more alike) between two
//! interleaved RGB images in `[0, 1]`, by one of two networks behind [`Lpips`]:
//! - `alex`: LPIPS v0.1 on AlexNet, computed natively from the weights
//!   `scripts/setup.sh` installs (`weights`: the file format and where it is looked for;
//!   `conv`: the layers). The default. It runs on the CPU, or on a GPU (`gpu`, WGSL
//!   kernels) when the caller names one ([`LpipsDevice`]); the CPU path is the reference.
//! - `onnx`: a user-supplied ONNX model (`[eval] lpips = "model.onnx"`), run with tract
//!   in a build with the `onnx` feature (`onnx_absent` without it: a clear error).
//!
//! [`Lpips::installed`] is the default network, or `None` when no weights are installed
//! (callers then report LPIPS as skipped with [`weights::INSTALL_HINT`], never a number).
//! No other IO here.

mod alex;
mod conv;
mod gpu;
mod maps;
#[cfg(feature = "onnx")]
mod onnx;
#[cfg(not(feature = "onnx"))]
#[path = "onnx_absent.rs"]
mod onnx;
pub mod weights;
mod winograd;

use std::path::{Path, PathBuf};

use crate::gpu::Gpu;

pub use alex::{AlexLpips, BATCH_PIXELS, MIN_SIDE};
pub use onnx::OnnxLpips;
pub use weights::{INSTALL_HINT, WEIGHTS_ENV, WEIGHTS_FILE, find_weights, weight_locations};

/// Why LPIPS could not be loaded or computed.
#[derive(Debug, thiserror::Error)]
pub enum LpipsError {
    #[error("cannot read LPIPS weights {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path} is not a usable ONNX model: {message}; re-export it as docs/render-eval.md shows"
    )]
    Corrupt { path: PathBuf, message: String },
    #[error(
        "LPIPS model {path} has the wrong interface: {message}; it must take two 1×3×H×W images in [-1, 1] and return one number (docs/render-eval.md)"
    )]
    WrongInterface { path: PathBuf, message: String },
    #[error(
        "{path} is not an LPIPS-alex weights file: {message}; delete it and {}",
        weights::INSTALL_HINT
    )]
    BadWeights { path: PathBuf, message: String },
    #[error(
        "LPIPS_WEIGHTS is {path}, which is not a file; point it at an LPIPS-alex weights file (scripts/setup.sh writes weights/lpips-alex-v0.1.safetensors), or unset it"
    )]
    EnvWeightsMissing { path: PathBuf },
    #[error(
        "LPIPS images must both be {width}×{height} RGB ({expected} values); got {got_a} and {got_b}"
    )]
    ImageSize {
        width: usize,
        height: usize,
        expected: usize,
        got_a: usize,
        got_b: usize,
    },
    #[error("LPIPS-alex needs images of at least {min}×{min} pixels; this one is {width}×{height}")]
    TooSmall {
        width: usize,
        height: usize,
        min: usize,
    },
    #[error(
        "LPIPS-alex on the GPU ({adapter}) failed: {message}; evaluate with backend = \"cpu\" to compute it on the CPU"
    )]
    Gpu { adapter: String, message: String },
    #[error(
        "{path}: this build runs no ONNX models; build with the `onnx` feature (`cargo build --release -p pipeline --features onnx`), or leave [eval] lpips unset for the built-in LPIPS-alex"
    )]
    OnnxNotBuilt { path: PathBuf },
    #[error("running LPIPS model {path} on a {width}×{height} image failed: {message}")]
    Run {
        path: PathBuf,
        width: usize,
        height: usize,
        message: String,
    },
}

/// An LPIPS network: the native AlexNet or a user's ONNX model.
#[derive(Debug)]
pub enum Lpips {
    Alex(AlexLpips),
    Onnx(OnnxLpips),
}

/// Where LPIPS-alex runs. An ONNX model always runs on the CPU (tract).
#[derive(Clone, Copy, Default)]
pub enum LpipsDevice<'a> {
    /// The native network on rayon (the reference).
    #[default]
    Cpu,
    /// WGSL kernels on this device; the weights are uploaded once per device.
    Gpu(&'a Gpu),
}

impl std::fmt::Debug for LpipsDevice<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => f.write_str("Cpu"),
            Self::Gpu(gpu) => write!(f, "Gpu({})", gpu.describe()),
        }
    }
}

/// Two same-sized interleaved RGB images in `[0, 1]` to compare.
#[derive(Clone, Copy, Debug)]
pub struct ImagePair<'a> {
    pub a: &'a [f32],
    pub b: &'a [f32],
    pub width: usize,
    pub height: usize,
}

impl Lpips {
    /// Load the network in `path`: LPIPS-alex weights for a `.safetensors` file (as
    /// `scripts/setup.sh` installs), otherwise an ONNX model.
    pub fn load(path: &Path) -> Result<Self, LpipsError> {
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("safetensors"))
        {
            AlexLpips::load(path).map(Self::Alex)
        } else {
            OnnxLpips::load(path).map(Self::Onnx)
        }
    }

    /// LPIPS-alex from the installed weights (the first file of [`weight_locations`]);
    /// `None` when none are installed. A file that is there but unreadable is an error.
    pub fn installed() -> Result<Option<Self>, LpipsError> {
        find_weights()?
            .map(|path| AlexLpips::load(&path).map(Self::Alex))
            .transpose()
    }

    /// The weights or model file.
    pub fn path(&self) -> &Path {
        match self {
            Self::Alex(net) => net.path(),
            Self::Onnx(net) => net.path(),
        }
    }

    /// What the network is, for reports: `"alex (native)"` or `"onnx"`.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Alex(_) => "alex (native)",
            Self::Onnx(_) => "onnx",
        }
    }

    /// LPIPS distance of two interleaved RGB images in `[0, 1]` (`width × height`).
    pub fn distance(
        &self,
        a: &[f32],
        b: &[f32],
        width: usize,
        height: usize,
    ) -> Result<f64, LpipsError> {
        match self {
            Self::Alex(net) => net.distance(a, b, width, height),
            Self::Onnx(net) => {
                check_pair(&ImagePair {
                    a,
                    b,
                    width,
                    height,
                })?;
                net.distance(a, b, width, height)
            }
        }
    }

    /// The distance of each pair, in order, on the CPU. The native network takes
    /// same-sized pairs through its layers together; an ONNX model runs them one after
    /// another.
    pub fn distances(&self, pairs: &[ImagePair]) -> Vec<Result<f64, LpipsError>> {
        self.distances_on(LpipsDevice::Cpu, pairs)
    }

    /// [`Self::distances`] on `device`: LPIPS-alex takes the pairs through WGSL kernels
    /// when it is a GPU; an ONNX model runs on the CPU whatever the device.
    pub fn distances_on(
        &self,
        device: LpipsDevice<'_>,
        pairs: &[ImagePair],
    ) -> Vec<Result<f64, LpipsError>> {
        match (self, device) {
            (Self::Alex(net), LpipsDevice::Cpu) => net.distances(pairs),
            (Self::Alex(net), LpipsDevice::Gpu(gpu)) => net.distances_on_gpu(gpu, pairs),
            (Self::Onnx(_), _) => pairs
                .iter()
                .map(|p| self.distance(p.a, p.b, p.width, p.height))
                .collect(),
        }
    }
}

/// `ImageSize` unless both images hold `width × height` RGB values (and that is not 0).
fn check_pair(pair: &ImagePair) -> Result<(), LpipsError> {
    let expected = 3 * pair.width * pair.height;
    if pair.a.len() != expected || pair.b.len() != expected || expected == 0 {
        return Err(LpipsError::ImageSize {
            width: pair.width,
            height: pair.height,
            expected,
            got_a: pair.a.len(),
            got_b: pair.b.len(),
        });
    }
    Ok(())
}
