//! Choosing and opening a GPU adapter.
//!
//! Policy (`--device auto|cpu|gpu`): `auto` takes a hardware adapter (discrete, then integrated,
//! then virtual) when there is one and otherwise leaves the run on the CPU; `gpu` insists on one
//! and fails with the adapters it saw. A software adapter (Mesa's lavapipe, WARP) is never taken
//! unless asked for by name: `SVGIR_GPU_ADAPTER=llvmpipe` picks the first adapter whose name
//! contains that text, case-insensitively, whatever its type. wgpu loads the system's Vulkan,
//! Metal or DX12 driver at run time, so a binary built with this crate still runs where there is
//! none.

use serde::{Deserialize, Serialize};
use std::fmt;

/// Where a run's kernels run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DeviceChoice {
    /// A hardware GPU when there is one, else the CPU.
    #[default]
    Auto,
    /// The CPU kernels.
    Cpu,
    /// A GPU, or an error.
    Gpu,
}

impl std::str::FromStr for DeviceChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "cpu" => Ok(Self::Cpu),
            "gpu" => Ok(Self::Gpu),
            _ => Err(format!("unknown device {s:?}: expected auto, cpu or gpu")),
        }
    }
}

impl fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Auto => "auto",
            Self::Cpu => "cpu",
            Self::Gpu => "gpu",
        })
    }
}

/// The environment variable naming the adapter to use (a substring of its name).
pub const ADAPTER_ENV: &str = "SVGIR_GPU_ADAPTER";

/// What a run records of the adapter it used (`config.json`) and prints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdapterReport {
    /// The adapter's name, e.g. `NVIDIA H200` or `llvmpipe (LLVM 15.0.6, 256 bits)`.
    pub name: String,
    /// Graphics API: `Vulkan`, `Metal`, `Dx12`.
    pub backend: String,
    /// `DiscreteGpu`, `IntegratedGpu`, `VirtualGpu`, `Cpu` or `Other`.
    pub device_type: String,
    /// Driver name and version as the driver reports them.
    pub driver: String,
    /// Whether the adapter has float atomics on storage buffers (`SHADER_FLOAT32_ATOMIC`). The
    /// kernels need none (see the crate docs); recorded for the reader.
    pub float_atomics: bool,
    /// Subgroup sizes the adapter reports, `[min, max]`.
    pub subgroup_sizes: [u32; 2],
    /// Largest storage-buffer binding, bytes.
    pub max_storage_binding: u64,
}

impl fmt::Display for AdapterReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ({}, {}, driver {}; float atomics {}, subgroups {}-{}, storage bindings up to {} MiB)",
            self.name,
            self.backend,
            self.device_type,
            self.driver,
            if self.float_atomics { "yes" } else { "no" },
            self.subgroup_sizes[0],
            self.subgroup_sizes[1],
            self.max_storage_binding >> 20
        )
    }
}

/// Why no GPU could be opened.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// `--device gpu` and no adapter fits.
    #[error("no usable GPU adapter{}: saw {}. Use --device cpu, or name an adapter with {ADAPTER_ENV} (e.g. {ADAPTER_ENV}=llvmpipe for Mesa's software Vulkan)", .asked.as_ref().map(|a| format!(" named like {a:?}")).unwrap_or_default(), if .seen.is_empty() { "none (is a Vulkan, Metal or DX12 driver installed?)".to_string() } else { .seen.join("; ") })]
    NoAdapter {
        /// The name asked for through the environment, if any.
        asked: Option<String>,
        /// Adapters seen, `name (type)`.
        seen: Vec<String>,
    },
    /// The adapter lacks a feature or limit the kernels need.
    #[error("GPU adapter {name} cannot run svgir's kernels: {why}")]
    Unsupported {
        /// The adapter's name.
        name: String,
        /// What is missing.
        why: String,
    },
    /// The driver refused the device.
    #[error("GPU adapter {name}: could not open a device: {why}")]
    Device {
        /// The adapter's name.
        name: String,
        /// The driver's message.
        why: String,
    },
    /// A kernel or buffer operation failed (validation, out of memory, lost device).
    #[error("GPU error: {0}")]
    Runtime(String),
    /// A buffer the kernels need is larger than the adapter's binding limit.
    #[error("{what} needs {bytes} bytes on the GPU, over the adapter's {limit}-byte binding limit: use --device cpu or fewer pixels")]
    TooLarge {
        /// The buffer's name.
        what: &'static str,
        /// Bytes it needs.
        bytes: u64,
        /// The adapter's limit.
        limit: u64,
    },
}

/// An open GPU: device, queue and what was recorded about the adapter.
#[derive(Clone)]
pub struct Gpu {
    /// The wgpu device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter, for printing and `config.json`.
    pub report: AdapterReport,
    /// The first error wgpu reported outside a call that returns one (validation, out of
    /// memory), kept for [`Gpu::check`] instead of wgpu's default panic.
    errors: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    /// What `guard_loops` (shaders/loop_guard.wgsl) found: per kernel a bit when a driver cut
    /// its loops short, and a word that stays 0. Zero when the device is opened.
    pub(crate) status: wgpu::Buffer,
}

impl Gpu {
    /// Bytes of GPU memory the device's buffers hold now, from wgpu's allocator report (Vulkan,
    /// DX12; `None` where the backend gives none).
    pub fn allocated_bytes(&self) -> Option<u64> {
        self.device.generate_allocator_report().map(|r| r.total_allocated_bytes)
    }

    /// An error if wgpu has reported one since the device was opened (a kernel or buffer the
    /// driver refused, memory exhausted): the run stops with it instead of going on with
    /// results that were never computed.
    ///
    /// Also an error once a driver has cut a kernel's loops short (Mesa's lavapipe stops every
    /// loop of an invocation after 65535 iterations in all, without a word; the kernels find
    /// it out, `shaders/loop_guard.wgsl`): that kernel's results are partial, and the run stops
    /// instead of training on them.
    pub fn check(&self) -> Result<(), GpuError> {
        match self.errors.lock().map(|e| e.clone()) {
            Ok(None) => {}
            Ok(Some(e)) => return Err(GpuError::Runtime(format!("{}: {e}", self.report.name))),
            Err(_) => return Err(GpuError::Runtime("the GPU error handler panicked".into())),
        }
        // Only software adapters are known to cap loops, and reading the status waits for the
        // queue: on hardware `check` stays free to call every iteration (GpuStage1::step does).
        if self.report.device_type != "Cpu" {
            return Ok(());
        }
        let bits = crate::buffers::read_back::<u32>(&self.device, &self.queue, &[(&self.status, 1)])?.remove(0)[0];
        if bits == 0 {
            return Ok(());
        }
        let cut: Vec<&str> = crate::loop_guard::GUARDED
            .iter()
            .enumerate()
            .filter(|(i, _)| bits >> i & 1 == 1)
            .map(|(_, k)| *k)
            .collect();
        Err(GpuError::Runtime(format!(
            "{}: the driver cut the loops of {} short (a loop-iteration cap, as Mesa's lavapipe has at 65535 \
             per invocation): the results are partial. The scene is too dense for this adapter at this \
             size: use a hardware GPU, --device cpu, or fewer Gaussians per pixel",
            self.report.name,
            cut.join(", ")
        )))
    }
}

impl fmt::Debug for Gpu {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Gpu").field("report", &self.report).finish_non_exhaustive()
    }
}

/// Whether the adapter of this type is hardware (taken by `auto`).
fn is_hardware(t: wgpu::DeviceType) -> bool {
    matches!(t, wgpu::DeviceType::DiscreteGpu | wgpu::DeviceType::IntegratedGpu | wgpu::DeviceType::VirtualGpu)
}

fn rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        _ => 3,
    }
}

/// Features the kernels need: subgroup reductions in the backward (sizes are read at run
/// time, never assumed).
pub(crate) const REQUIRED: wgpu::Features = wgpu::Features::SUBGROUP;

/// Opens the adapter `choice` and the environment select: `Ok(None)` for `cpu`, and for `auto`
/// when no hardware adapter fits.
pub fn open(choice: DeviceChoice) -> Result<Option<Gpu>, GpuError> {
    if choice == DeviceChoice::Cpu {
        return Ok(None);
    }
    let asked = std::env::var(ADAPTER_ENV).ok().filter(|s| !s.trim().is_empty());
    match open_named(asked.as_deref()) {
        Ok(g) => Ok(Some(g)),
        // `auto` without a fitting adapter stays on the CPU, unless one was asked for by name.
        Err(GpuError::NoAdapter { .. }) if choice == DeviceChoice::Auto && asked.is_none() => Ok(None),
        Err(e) => Err(e),
    }
}

/// Opens the adapter whose name contains `name` (any type), or without a name the best hardware
/// adapter.
pub fn open_named(name: Option<&str>) -> Result<Gpu, GpuError> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12,
        // No validation layers or GPU-assisted validation: the latter corrupts SPIR-V on some
        // Mesa versions (wgpu issue 5253).
        flags: wgpu::InstanceFlags::empty(),
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
    let seen: Vec<String> = adapters
        .iter()
        .map(|a| {
            let i = a.get_info();
            format!("{} ({:?}, {:?})", i.name, i.device_type, i.backend)
        })
        .collect();
    let mut candidates: Vec<&wgpu::Adapter> = match name {
        Some(n) => {
            let n = n.to_lowercase();
            adapters.iter().filter(|a| a.get_info().name.to_lowercase().contains(&n)).collect()
        }
        None => adapters.iter().filter(|a| is_hardware(a.get_info().device_type)).collect(),
    };
    candidates.sort_by_key(|a| rank(a.get_info().device_type));
    let Some(adapter) = candidates.first() else {
        return Err(GpuError::NoAdapter { asked: name.map(str::to_string), seen });
    };
    let info = adapter.get_info();
    let features = adapter.features();
    if !features.contains(REQUIRED) {
        return Err(GpuError::Unsupported { name: info.name, why: "no subgroup operations (wgpu SUBGROUP)".into() });
    }
    let limits = adapter.limits();
    let float_atomics = features.contains(wgpu::Features::SHADER_FLOAT32_ATOMIC);
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("svgir"),
        required_features: REQUIRED,
        // The adapter's own limits: the kernels bind up to eleven storage buffers, over the
        // WebGPU default of eight, and large scenes need large bindings.
        required_limits: limits.clone(),
        ..Default::default()
    }))
    .map_err(|e| GpuError::Device { name: info.name.clone(), why: e.to_string() })?;
    let report = AdapterReport {
        subgroup_sizes: [info.subgroup_min_size, info.subgroup_max_size],
        name: info.name,
        backend: format!("{:?}", info.backend),
        device_type: format!("{:?}", info.device_type),
        driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        float_atomics,
        max_storage_binding: limits.max_storage_buffer_binding_size,
    };
    let errors = std::sync::Arc::new(std::sync::Mutex::new(None::<String>));
    let slot = errors.clone();
    device.on_uncaptured_error(std::sync::Arc::new(move |e: wgpu::Error| {
        if let Ok(mut s) = slot.lock() {
            s.get_or_insert_with(|| e.to_string());
        }
    }));
    // Storage for guard_loops, copied from for Gpu::check; wgpu zeroes new buffers.
    let status = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("loop guard status"),
        size: 8,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    Ok(Gpu { device, queue, report, errors, status })
}
