//! Storage buffers reused from one iteration to the next. A training iteration needs the
//! same large scratch buffers every time (sort keys, per-tile gradients, image planes:
//! hundreds of MB at a million Gaussians); allocating them afresh each time costs a real
//! GPU more than the kernels that use them (new memory is mapped, zeroed and freed every
//! iteration). [`Gpu::scratch`](super::Gpu::scratch) hands out a buffer of the asked
//! size's bucket, taken from the buffers returned by earlier [`Pooled`] handles when one
//! of that bucket is idle.
//!
//! A pooled buffer's contents are whatever its last user left: callers that need zeros
//! clear it. It goes back to the pool when its handle is dropped, so a handle must live
//! as long as any bind group that reaches it is still to be recorded; work already
//! recorded or submitted is safe, since the queue runs it before any later reuse.

use std::sync::{Arc, Mutex, PoisonError};

/// Takes after which an idle buffer is freed (a training iteration takes a few dozen).
const IDLE_TAKES: u64 = 256;

/// A storage buffer from [`Gpu::scratch`](super::Gpu::scratch); it returns to the pool
/// when dropped.
pub struct Pooled {
    buffer: Option<wgpu::Buffer>,
    pool: Arc<Mutex<Idle>>,
}

impl std::ops::Deref for Pooled {
    type Target = wgpu::Buffer;

    fn deref(&self) -> &wgpu::Buffer {
        self.buffer
            .as_ref()
            .expect("a pooled buffer is present until dropped")
    }
}

impl Drop for Pooled {
    fn drop(&mut self) {
        if let Some(buffer) = self.buffer.take() {
            let mut idle = self.pool.lock().unwrap_or_else(PoisonError::into_inner);
            let now = idle.clock;
            idle.buffers.push((now, buffer));
        }
    }
}

/// The idle buffers, each with the take count when it came back.
#[derive(Default)]
struct Idle {
    clock: u64,
    buffers: Vec<(u64, wgpu::Buffer)>,
}

/// The pool of one device.
#[derive(Default)]
pub(crate) struct BufferPool(Arc<Mutex<Idle>>);

/// The size a request of `bytes` is served at: at least 256 bytes, rounded up to a
/// sixteenth of the power of two above it (at most 12.5 % more), so that sizes that differ
/// a little from one iteration to the next share buffers.
pub fn bucket(bytes: u64) -> u64 {
    let bytes = bytes.max(256);
    let step = bytes.next_power_of_two() / 16;
    bytes.div_ceil(step) * step
}

/// The size a request of `bytes` gets: its bucket, unless that is more than `cap` (the
/// most a kernel may bind; a limit such as 4 GiB − 1 is no bucket), then the exact size.
fn size_for(bytes: u64, cap: u64) -> u64 {
    let size = bucket(bytes);
    if size > cap {
        bytes.max(256).next_multiple_of(4)
    } else {
        size
    }
}

impl BufferPool {
    /// A storage buffer (STORAGE, COPY_SRC and COPY_DST) of at least `bytes`, reused when
    /// one of its bucket is idle; its contents are undefined. A bucket larger than `cap`
    /// (the most a kernel may bind) gives way to the exact size.
    pub(crate) fn take(&self, device: &wgpu::Device, bytes: u64, cap: u64, label: &str) -> Pooled {
        let size = size_for(bytes, cap);
        let reused = {
            let mut idle = self.0.lock().unwrap_or_else(PoisonError::into_inner);
            idle.clock += 1;
            let now = idle.clock;
            idle.buffers.retain(|(at, _)| at + IDLE_TAKES > now);
            let found = idle.buffers.iter().rposition(|(_, b)| b.size() == size);
            found.map(|i| idle.buffers.swap_remove(i).1)
        };
        let buffer = reused.unwrap_or_else(|| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        Pooled {
            buffer: Some(buffer),
            pool: self.0.clone(),
        }
    }

    /// Buffers idle in the pool, and their bytes.
    pub(crate) fn idle(&self) -> (usize, u64) {
        let idle = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let bytes = idle.buffers.iter().map(|(_, b)| b.size()).sum();
        (idle.buffers.len(), bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_round_up_by_at_most_an_eighth() {
        assert_eq!(bucket(0), 256);
        assert_eq!(bucket(256), 256);
        assert_eq!(bucket(257), 288);
        assert_eq!(bucket(1000), 1024);
        assert_eq!(bucket(1025), 1152);
        for bytes in (1..200_000u64).step_by(97).chain([40_000_000, 123_456_789]) {
            let b = bucket(bytes);
            assert!(b >= bytes && b.is_multiple_of(4), "{bytes} → {b}");
            assert!(b <= (bytes.max(256) * 9).div_ceil(8), "{bytes} → {b}");
            assert_eq!(bucket(b), b, "a bucket is its own bucket");
        }
    }

    #[test]
    fn no_bucket_is_more_than_a_kernel_may_bind() {
        let cap = u32::MAX as u64;
        assert_eq!(size_for(cap - 3, cap), cap - 3);
        assert_eq!(size_for(3_000_000_000, cap), bucket(3_000_000_000));
        assert_eq!(size_for(1000, 1024), 1024);
        assert_eq!(size_for(1025, 1100), 1028);
    }
}
