//! The GPU, apart from what runs on it: finding and opening a device ([`Gpu`], software
//! adapters only when asked) and the toolkit every owner of WGSL kernels builds with
//! ([`compute`]), scratch buffers reused between iterations ([`Gpu::scratch`]), and
//! per-kernel device time ([`Gpu::profile`]). The renderer (`render::gpu`), the trainer's device step (`train::gpu`),
//! the decay's device side (`decay::gpu`) and LPIPS (`metrics::lpips::gpu`) each build
//! their own pipelines on it.

pub mod compute;
mod device;
pub mod pool;
pub mod profile;

pub use device::{AdapterPolicy, Gpu, GpuError};
pub use pool::Pooled;
pub use profile::{KernelTime, Profile};
