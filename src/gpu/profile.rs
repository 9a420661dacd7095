//! Where a GPU's time goes: every kernel dispatched through [`super::compute::Kernel`]
//! while [`Gpu::profile`] runs some work is bracketed by two device timestamps, and the
//! device time is summed per kernel. It needs an adapter with timestamp queries inside
//! compute passes (Vulkan, DX12 and Metal on most GPUs; [`Gpu::can_profile`]); the
//! timestamps are written only while a profile records, so other work pays nothing.
//! `scripts/gpu-check.sh` prints one training iteration's profile.

use super::compute::read_buffer;
use super::device::{Gpu, GpuError};
use std::cell::RefCell;

/// Device time of one kernel over the profiled work.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelTime {
    /// The kernel's entry point.
    pub name: String,
    pub dispatches: u32,
    /// Device time of its dispatches, summed, in milliseconds.
    pub ms: f64,
}

/// What [`Gpu::profile`] measured.
#[derive(Clone, Debug, Default)]
pub struct Profile {
    /// One entry per kernel, most time first.
    pub kernels: Vec<KernelTime>,
    /// Dispatches past the query set's capacity, not timed.
    pub untimed: u32,
}

impl Profile {
    /// Device time of every timed dispatch, in milliseconds.
    pub fn total_ms(&self) -> f64 {
        self.kernels.iter().map(|k| k.ms).sum()
    }

    /// A Markdown table: kernel, dispatches, milliseconds, share of the total.
    pub fn table(&self) -> String {
        let total = self.total_ms();
        let mut s = String::from("| kernel | dispatches | ms | share |\n|---|---|---|---|\n");
        for k in &self.kernels {
            let share = if total > 0.0 {
                100.0 * k.ms / total
            } else {
                0.0
            };
            s += &format!(
                "| {} | {} | {:.3} | {share:.1} % |\n",
                k.name, k.dispatches, k.ms
            );
        }
        s += &format!("| all | | {total:.3} | |\n");
        if self.untimed > 0 {
            s += &format!(
                "({} dispatches past the query set, not timed)\n",
                self.untimed
            );
        }
        s
    }
}

/// Timestamps (two per dispatch) in one query set.
const QUERIES: u32 = wgpu::QUERY_SET_MAX_QUERIES;

struct Recording {
    set: wgpu::QuerySet,
    /// The kernel of each timed dispatch, in order.
    names: Vec<String>,
    untimed: u32,
}

thread_local! {
    /// The profile this thread records into, while [`Gpu::profile`] runs.
    static RECORDING: RefCell<Option<Recording>> = const { RefCell::new(None) };
}

/// Dispatch through `dispatch`, bracketed by timestamps when a profile records.
pub(crate) fn timed(
    pass: &mut wgpu::ComputePass<'_>,
    name: &str,
    dispatch: impl FnOnce(&mut wgpu::ComputePass<'_>),
) {
    let slot = RECORDING.with_borrow_mut(|r| {
        let r = r.as_mut()?;
        let at = 2 * r.names.len() as u32;
        if at + 2 > QUERIES {
            r.untimed += 1;
            return None;
        }
        r.names.push(name.to_owned());
        pass.write_timestamp(&r.set, at);
        Some(at)
    });
    dispatch(pass);
    if let Some(at) = slot {
        RECORDING.with_borrow(|r| {
            if let Some(r) = r {
                pass.write_timestamp(&r.set, at + 1);
            }
        });
    }
}

/// Clears the recording when [`Gpu::profile`] leaves, also by a panic.
struct Stop;

impl Drop for Stop {
    fn drop(&mut self) {
        RECORDING.with_borrow_mut(|r| r.take());
    }
}

impl Gpu {
    /// The adapter can time kernels ([`Gpu::profile`]).
    pub fn can_profile(&self) -> bool {
        self.device.features().contains(PROFILE_FEATURES)
    }

    /// Run `work` (on this thread) and time every kernel it dispatches on this device.
    pub fn profile<R>(&self, work: impl FnOnce() -> R) -> Result<(R, Profile), GpuError> {
        if !self.can_profile() {
            return Err(GpuError::NoProfiling(self.describe()));
        }
        let set = self.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("profile"),
            ty: wgpu::QueryType::Timestamp,
            count: QUERIES,
        });
        RECORDING.with_borrow_mut(|r| {
            *r = Some(Recording {
                set,
                names: Vec::new(),
                untimed: 0,
            })
        });
        let stop = Stop;
        let result = work();
        let recording = RECORDING.with_borrow_mut(|r| r.take());
        drop(stop);
        let Some(recording) = recording else {
            return Ok((result, Profile::default()));
        };
        let used = 2 * recording.names.len() as u32;
        let mut profile = Profile {
            kernels: Vec::new(),
            untimed: recording.untimed,
        };
        if used == 0 {
            return Ok((result, profile));
        }
        let bytes = 8 * used as u64;
        let resolved = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("profile timestamps"),
            size: bytes,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = read_buffer(&self.device, bytes);
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.resolve_query_set(&recording.set, 0..used, &resolved, 0);
        enc.copy_buffer_to_buffer(&resolved, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        let words = self.read_words(&staging, bytes)?;
        let tick_ns = self.queue.get_timestamp_period() as f64;
        for (i, name) in recording.names.into_iter().enumerate() {
            let stamp = |q: usize| words[2 * q] as u64 | (words[2 * q + 1] as u64) << 32;
            let ms = stamp(2 * i + 1).saturating_sub(stamp(2 * i)) as f64 * tick_ns * 1e-6;
            match profile.kernels.iter_mut().find(|k| k.name == name) {
                Some(k) => {
                    k.dispatches += 1;
                    k.ms += ms;
                }
                None => profile.kernels.push(KernelTime {
                    name,
                    dispatches: 1,
                    ms,
                }),
            }
        }
        profile.kernels.sort_by(|a, b| b.ms.total_cmp(&a.ms));
        Ok((result, profile))
    }
}

/// The device features [`Gpu::profile`] needs; asked for where the adapter has them.
pub(crate) const PROFILE_FEATURES: wgpu::Features =
    wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES);
