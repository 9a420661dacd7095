//! Finding a GPU: a wgpu device on a hardware adapter (or, only when asked, a software
//! one such as Mesa's lavapipe, which is slower than the CPU engine and serves for tests),
//! and the pipelines other owners build for it ([`Gpu::pipelines`]).

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
}

impl Gpu {
    /// Open the best adapter the policy allows: discrete before integrated before virtual,
    /// software last (and only when allowed).
    pub fn open(policy: AdapterPolicy) -> Result<Arc<Self>, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::PRIMARY,
            ..wgpu::InstanceDescriptor::new_without_display_handle_from_env()
        });
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
        if adapters.is_empty() {
            return Err(GpuError::NoAdapter);
        }
        let rank = |t: wgpu::DeviceType| match t {
            wgpu::DeviceType::DiscreteGpu => 0,
            wgpu::DeviceType::IntegratedGpu => 1,
            wgpu::DeviceType::VirtualGpu => 2,
            wgpu::DeviceType::Other => 3,
            wgpu::DeviceType::Cpu => 4,
        };
        let best = adapters
            .into_iter()
            .min_by_key(|a| rank(a.get_info().device_type))
            .ok_or(GpuError::NoAdapter)?;
        let info = best.get_info();
        if info.device_type == wgpu::DeviceType::Cpu && policy == AdapterPolicy::HardwareOnly {
            return Err(GpuError::SoftwareOnly {
                found: format!("{} ({:?})", info.name, info.backend),
            });
        }
        let limits = best.limits();
        let (device, queue) = pollster::block_on(best.request_device(&wgpu::DeviceDescriptor {
            label: Some("splat4d"),
            required_features: best.features()
                & (super::profile::PROFILE_FEATURES | wgpu::Features::SUBGROUP),
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

    /// The adapter in words, e.g. `NVIDIA H100 (Vulkan, DiscreteGpu)`.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }
}
