//! Finding a GPU: a wgpu device on a hardware adapter (or, only when asked, a software
//! one such as Mesa's lavapipe, which is slower than the CPU engine and serves for tests),
//! and the pipelines other owners build for it ([`Gpu::pipelines`]).

use super::compute::read_buffer;
use super::pool::{BufferPool, Pooled};
use super::profile::{PROFILE_FEATURES, Profile, Recording};
use std::any::Any;
use std::sync::{Arc, Mutex, PoisonError};

/// Which adapters may be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterPolicy {
    /// Discrete, integrated or virtual GPUs only.
    HardwareOnly,
    /// A hardware adapter if there is one, else a software (CPU) adapter.
    AllowSoftware,
}

impl AdapterPolicy {
    /// `HardwareOnly`, unless `SPLAT4D_GPU_SOFTWARE=1` asks for software adapters (tests).
    pub fn from_env() -> Self {
        match std::env::var("SPLAT4D_GPU_SOFTWARE") {
            Ok(v) if v == "1" || v == "true" => Self::AllowSoftware,
            _ => Self::HardwareOnly,
        }
    }
}

/// Why no GPU device could be had, or one stopped answering.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found (Vulkan, Metal or DX12); install the GPU's Vulkan driver, or use backend = \"cpu\""
    )]
    NoAdapter,
    #[error(
        "only software GPU adapters were found ({found}); they are slower than the CPU engine, so they are not used unless SPLAT4D_GPU_SOFTWARE=1 (tests); use backend = \"cpu\" or \"auto\""
    )]
    SoftwareOnly { found: String },
    #[error("could not open the GPU device '{adapter}': {reason}")]
    Device { adapter: String, reason: String },
    #[error("reading a result back from the GPU failed ({0}); the device may have been lost")]
    ReadBack(String),
    #[error("the GPU '{0}' cannot time kernels (it lacks timestamp queries inside compute passes)")]
    NoProfiling(String),
}

/// An open device and what it is.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// Pipelines built for this device by owners other than the renderer, one set per
    /// type ([`Gpu::pipelines`]).
    pipelines: Mutex<Vec<Arc<dyn Any + Send + Sync>>>,
    /// Scratch buffers between uses ([`Gpu::scratch`]).
    pool: BufferPool,
}

impl Gpu {
    /// Open the best adapter the policy allows: discrete before integrated before virtual,
    /// software last (and only when allowed).
    pub fn open(policy: AdapterPolicy) -> Result<Arc<Self>, GpuError> {
        Self::open_nth(policy, 0)
    }

    /// How many adapters [`Gpu::open_nth`] can open under `policy` (0 when there is none):
    /// the GPUs that can train side by side.
    pub fn count(policy: AdapterPolicy) -> usize {
        usable_adapters(policy).map_or(0, |a| a.len())
    }

    /// Open the `n`th adapter the policy allows, in [`Gpu::open`]'s order of preference
    /// (adapters of one kind in the order the driver lists them); `n` wraps around, so
    /// lane `n` of several always gets a device.
    pub fn open_nth(policy: AdapterPolicy, n: usize) -> Result<Arc<Self>, GpuError> {
        let mut adapters = usable_adapters(policy)?;
        let best = adapters.swap_remove(n % adapters.len());
        let info = best.get_info();
        let limits = best.limits();
        let (device, queue) = pollster::block_on(best.request_device(&wgpu::DeviceDescriptor {
            label: Some("splat4d"),
            required_features: best.features() & (PROFILE_FEATURES | wgpu::Features::SUBGROUP),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            reason: e.to_string(),
        })?;
        Ok(Arc::new(Self {
            device,
            queue,
            info,
            limits,
            pipelines: Mutex::new(Vec::new()),
            pool: BufferPool::default(),
        }))
    }

    /// The pipelines of type `T` for this device: built by `build` on the first call,
    /// shared afterwards. The trainer's and the decay's kernels are built this way, by
    /// their owners, once per device.
    pub fn pipelines<T: Any + Send + Sync>(
        &self,
        build: impl FnOnce(&wgpu::Device) -> T,
    ) -> Arc<T> {
        let mut built = self
            .pipelines
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(found) = built.iter().find_map(|p| p.clone().downcast::<T>().ok()) {
            return found;
        }
        let new = Arc::new(build(&self.device));
        built.push(new.clone());
        new
    }

    /// Wait for the submitted work and read the first `bytes` of `staging` (a
    /// `compute::read_buffer`) back as `u32` words.
    pub fn read_words(&self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<u32>, GpuError> {
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let slice = staging.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::ReadBack(format!("waiting for the GPU: {e}")))?;
        rx.recv()
            .map_err(|_| GpuError::ReadBack("the mapping was dropped".into()))?
            .map_err(|e| GpuError::ReadBack(e.to_string()))?;
        let words = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::ReadBack(e.to_string()))?;
            bytemuck::pod_collect_to_vec::<u8, u32>(&view)
        };
        staging.unmap();
        Ok(words)
    }

    /// Kernels may use subgroup operations: the device has them, in subgroups of 8 or more
    /// invocations, and `SPLAT4D_GPU_SUBGROUPS=0` does not turn them off (which gives the
    /// kernels that sum in the same order on every adapter).
    pub fn subgroups(&self) -> bool {
        let off = std::env::var("SPLAT4D_GPU_SUBGROUPS").is_ok_and(|v| v == "0" || v == "false");
        !off && self.device.features().contains(wgpu::Features::SUBGROUP)
            && self.info.subgroup_min_size >= 8
    }

    /// A storage buffer (STORAGE, COPY_SRC and COPY_DST) of at least `bytes` from this
    /// device's pool of scratch buffers (`gpu::pool`): one an earlier user returned when
    /// one of its size bucket is idle. Its contents are undefined; it returns to the pool
    /// when dropped.
    pub fn scratch(&self, bytes: u64, label: &str) -> Pooled {
        let cap = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        self.pool.take(&self.device, bytes, cap, label)
    }

    /// Buffers idle in the pool of scratch buffers, and their bytes.
    pub fn pooled(&self) -> (usize, u64) {
        self.pool.idle()
    }

    /// The adapter can time kernels ([`Gpu::profile`]).
    pub fn can_profile(&self) -> bool {
        self.device.features().contains(PROFILE_FEATURES)
    }

    /// Run `work` (on this thread) and time every kernel it dispatches on this device
    /// (`gpu::profile`). Profiles do not nest: an inner one takes the dispatches.
    pub fn profile<R>(&self, work: impl FnOnce() -> R) -> Result<(R, Profile), GpuError> {
        if !self.can_profile() {
            return Err(GpuError::NoProfiling(self.describe()));
        }
        let recording = Recording::start(&self.device);
        let result = work();
        let Some(recorded) = recording.stop() else {
            return Ok((result, Profile::default()));
        };
        let used = recorded.queries();
        if used == 0 {
            return Ok((result, recorded.profile(&[], 0.0)));
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
        enc.resolve_query_set(&recorded.set, 0..used, &resolved, 0);
        enc.copy_buffer_to_buffer(&resolved, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        let words = self.read_words(&staging, bytes)?;
        let tick_ns = self.queue.get_timestamp_period() as f64;
        Ok((result, recorded.profile(&words, tick_ns)))
    }

    /// The adapter in words, e.g. `NVIDIA H100 (Vulkan, DiscreteGpu)`.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }
}

/// The adapters `policy` allows, best first (discrete before integrated before virtual,
/// stable within a kind): the hardware ones when there are, else the software ones where
/// the policy allows them. An error when there is none, naming the software adapter found
/// where only hardware is allowed.
fn usable_adapters(policy: AdapterPolicy) -> Result<Vec<wgpu::Adapter>, GpuError> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::PRIMARY,
        ..wgpu::InstanceDescriptor::new_without_display_handle_from_env()
    });
    let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
    let rank = |t: wgpu::DeviceType| match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    adapters.sort_by_key(|a| rank(a.get_info().device_type));
    let Some(best) = adapters.first() else {
        return Err(GpuError::NoAdapter);
    };
    let best = best.get_info();
    if best.device_type != wgpu::DeviceType::Cpu {
        adapters.retain(|a| a.get_info().device_type != wgpu::DeviceType::Cpu);
    } else if policy == AdapterPolicy::HardwareOnly {
        return Err(GpuError::SoftwareOnly {
            found: format!("{} ({:?})", best.name, best.backend),
        });
    }
    Ok(adapters)
}
