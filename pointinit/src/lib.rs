//! The `init` stage: the starting point cloud of the 4D Gaussians, from MASt3R-style point
//! maps (an ONNX model run here with [`onnx`], or its outputs exported as `.npy`/`.npz`,
//! [`npy`]), each pair scaled into the posed cameras' world frame ([`pair_scale`]) and
//! fused ([`fuse`]); or triangulated with COLMAP and the known cameras at several moments
//! of the clip ([`moments`]) or swept ([`sweep`]), static points told from moving ones by
//! each camera's static plate ([`plates`]) or by repetition ([`statics`]); with the
//! fallback chain point maps → triangulated moments → sparse COLMAP points → a random
//! cloud in the cameras' common view volume, each fallback announced with `tracing::warn!`.
//!
//! Call [`run_init`] with [`InitInputs`] and an [`InitConfig`]; it writes
//! `<out_dir>/points.ply` (xyz, rgb, time; atomically) and returns an [`InitReport`].
//! The user-facing description is `docs/init.md`. This crate reads no pipeline files
//! itself (frames index, stage manifests): the caller passes plain inputs.
//!
//! The stage, one concern per file: `config` ([`InitConfig`], the `[init]` settings),
//! `inputs` ([`InitInputs`]), `views` (frames read and undistorted to pinhole), `stage`
//! ([`run_init`]: the source choice and the fallback chain), `pairs` (point-map pairs
//! aligned into the world frame), `report` ([`InitReport`], `init.json`), `error`
//! ([`InitError`]). The algorithms are the public modules.
//! Depends on `calib` (COLMAP, undistortion) and `shared-types`; nothing depends on it but
//! the pipeline.

mod config;
mod error;
mod grid;
mod inputs;
mod pairs;
mod report;
mod stage;
mod views;

pub mod fuse;
pub mod moment_maps;
pub mod moments;
pub mod npy;
pub mod onnx;
pub mod pair_scale;
pub mod plates;
pub mod statics;
pub mod sweep;

pub use config::{InitConfig, Pairs, PairsKeyword, Source};
pub use error::InitError;
pub use inputs::{InitInputs, Moment, StillImage, ViewImage};
pub use moments::MomentReport;
pub use report::{InitReport, PairReport, UsedSource};
pub use stage::run_init;
pub use views::View;
