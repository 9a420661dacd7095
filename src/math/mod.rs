//! The per-Gaussian math that every render backend follows, each op beside its backward:
//! [`numerics`] (the float trait, stable sigmoid/exp), [`rotation4d`] (the 4D rotation from
//! two quaternions), [`slice`] (the conditional 3D Gaussian at time t and its temporal
//! weight), [`sh`] (spherical + spherindrical colour), [`project`] (EWA projection to a 2D
//! conic with the near-plane and degenerate-covariance guards).

/// This module's per-Gaussian math in WGSL (constants, guards, the time slice), for the
/// kernels that evaluate a Gaussian: prepended by their owners (`gpu::compute::shader`).
pub const GAUSSIAN_WGSL: &str = include_str!("gaussian.wgsl");

pub mod numerics;
pub mod project;
pub mod rotation4d;
pub mod sh;
pub mod slice;
