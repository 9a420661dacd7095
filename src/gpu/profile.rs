//! Where a GPU's time goes: every kernel dispatched through [`super::compute::Kernel`]
//! while [`Gpu::profile`](super::Gpu::profile) runs some work is bracketed by two device
//! timestamps, and the device time is summed per kernel. It needs an adapter with
//! timestamp queries inside compute passes (Vulkan, DX12 and Metal on most GPUs;
//! [`Gpu::can_profile`](super::Gpu::can_profile)); the timestamps are written only while
//! a profile records, so other work pays nothing. `scripts/gpu-check.sh` prints one
//! training iteration's profile.

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

/// What [`Gpu::profile`](super::Gpu::profile) measured.
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

    /// The profile of `n` repetitions of the same work as the mean of one: times and
    /// dispatch counts divided by `n`.
    pub fn per_repetition(mut self, n: u32) -> Self {
        let n = n.max(1);
        for k in &mut self.kernels {
            k.ms /= n as f64;
            k.dispatches /= n;
        }
        self.untimed /= n;
        self
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

/// What a profile has recorded: the timestamps' query set, the kernel of each timed
/// dispatch in order, and the dispatches past the set.
pub(crate) struct Recorded {
    pub(crate) set: wgpu::QuerySet,
    names: Vec<String>,
    untimed: u32,
}

thread_local! {
    /// The profile this thread records into, while a [`Recording`] lives.
    static RECORDING: RefCell<Option<Recorded>> = const { RefCell::new(None) };
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

/// This thread's profile while it lives: dispatches are timed until [`Recording::stop`],
/// or until it is dropped (also by a panic). One at a time per thread.
pub(crate) struct Recording;

impl Recording {
    pub(crate) fn start(device: &wgpu::Device) -> Self {
        let set = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("profile"),
            ty: wgpu::QueryType::Timestamp,
            count: QUERIES,
        });
        RECORDING.with_borrow_mut(|r| {
            *r = Some(Recorded {
                set,
                names: Vec::new(),
                untimed: 0,
            })
        });
        Self
    }

    /// What was recorded; `None` when a nested recording took it (profiles do not nest).
    pub(crate) fn stop(self) -> Option<Recorded> {
        RECORDING.with_borrow_mut(|r| r.take())
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        RECORDING.with_borrow_mut(|r| r.take());
    }
}

impl Recorded {
    /// Timestamps written (two per timed dispatch).
    pub(crate) fn queries(&self) -> u32 {
        2 * self.names.len() as u32
    }

    /// The profile from the resolved timestamps (`words`: two u32 per query) and the
    /// length of a tick in nanoseconds.
    pub(crate) fn profile(self, words: &[u32], tick_ns: f64) -> Profile {
        let mut profile = Profile {
            kernels: Vec::new(),
            untimed: self.untimed,
        };
        let stamp = |q: usize| words[2 * q] as u64 | (words[2 * q + 1] as u64) << 32;
        for (i, name) in self.names.into_iter().enumerate() {
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
        profile
    }
}

/// The device features a profile needs; asked for where the adapter has them.
pub(crate) const PROFILE_FEATURES: wgpu::Features =
    wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES);
