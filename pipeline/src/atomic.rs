//! Atomic file writes: the workspace's one implementation, `splat4d::atomic`.

pub use splat4d::atomic::{temp_sibling, write_atomic};
