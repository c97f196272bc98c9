//! Adapter selection and the device handle every other GPU type hangs off.

use std::sync::{Arc, Mutex};

use super::pipeline::PipelineCache;
use super::GpuError;

/// Environment variable that picks an adapter by (case-insensitive) name substring,
/// e.g. `IASTGCN_ADAPTER=llvmpipe` or `IASTGCN_ADAPTER=nvidia`.
pub const ADAPTER_ENV: &str = "IASTGCN_ADAPTER";

/// Environment variable that, set to `0`, opens the device without subgroup operations,
/// so that every product runs on the portable block kernel (to compare the two, or to
/// work around a driver's subgroup bug).
pub const SUBGROUPS_ENV: &str = "IASTGCN_SUBGROUPS";

/// The backends we ask for. GL is left out on purpose: it only adds a second
/// llvmpipe adapter and 30-300 ms of EGL probing (see docs/lavapipe.md).
pub const BACKENDS: wgpu::Backends = wgpu::Backends::VULKAN
    .union(wgpu::Backends::METAL)
    .union(wgpu::Backends::DX12);

/// How to get a software Vulkan driver when no adapter exists at all.
pub const INSTALL_HINT: &str = "install a Vulkan driver; for the software one (Mesa lavapipe) \
on Debian/Ubuntu run as root: apt-get update && apt-get install -y mesa-vulkan-drivers libvulkan1 \
(or run `make test`, which does it for you)";

/// A device, its queue and the pipelines compiled on it.
///
/// Create one per process (or per test); everything else borrows it.
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    adapter_features: wgpu::Features,
    pub(crate) pipelines: Mutex<PipelineCache>,
    /// Every buffer created while [`Gpu::allocations_during`] runs (None otherwise).
    pub(crate) allocations: Mutex<Option<Vec<Allocation>>>,
    /// Errors no scope caught and the device's loss, reported by the next
    /// [`Gpu::check`] (wgpu's default handler would panic instead).
    faults: Arc<Faults>,
    /// Which kind of device the planners shape launches for ([`Gpu::with_planning`]).
    planning: Planning,
}

/// Which kind of device the kernels' planners shape their launches for: `ops::matmul`'s
/// split reductions (how many reduction steps an invocation sums, how many lanes add
/// each output's partial sums). Results differ only by the order of f32 additions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Planning {
    /// The adapter's own kind: [`Planning::Cpu`] on a CPU implementation (lavapipe,
    /// WARP), else [`Planning::Gpu`].
    #[default]
    Adapter,
    /// As for a CPU adapter: long invocations, one lane adding each output's partial sums.
    Cpu,
    /// As for a GPU: short invocations, up to 64 lanes per output (tests run a GPU's
    /// plan on lavapipe with it).
    Gpu,
}

/// What the device reported outside any error scope.
#[derive(Default)]
struct Faults {
    /// The first uncaptured error since the last [`Gpu::check`].
    uncaptured: Mutex<Option<String>>,
    /// Why the device was lost, once it is.
    lost: Mutex<Option<String>>,
}

/// Locks a mutex whether or not a panicking thread poisoned it (the data are plain
/// strings and logs, valid either way).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// One device buffer: its label and size in bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Allocation {
    /// The tensor's name.
    pub name: String,
    /// Bytes (rounded up to whole 16-byte vectors).
    pub bytes: u64,
}

/// Rank of an adapter type: a real GPU first, the CPU (lavapipe) last.
fn preference(kind: wgpu::DeviceType) -> u8 {
    match kind {
        wgpu::DeviceType::DiscreteGpu => 4,
        wgpu::DeviceType::IntegratedGpu => 3,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 1,
        wgpu::DeviceType::Cpu => 0,
    }
}

/// Picks an adapter: the one whose name contains `wanted` (case-insensitive) when given,
/// else the most GPU-like one; ties keep enumeration order. Pure, so it is testable
/// without a driver.
pub fn choose_adapter(
    infos: &[wgpu::AdapterInfo],
    wanted: Option<&str>,
) -> Result<usize, GpuError> {
    if infos.is_empty() {
        return Err(GpuError::NoAdapter {
            hint: INSTALL_HINT.to_string(),
        });
    }
    match wanted {
        Some(w) => {
            let needle = w.to_lowercase();
            infos
                .iter()
                .position(|i| i.name.to_lowercase().contains(&needle))
                .ok_or_else(|| GpuError::AdapterNotFound {
                    wanted: w.to_string(),
                    available: infos.iter().map(describe).collect(),
                })
        }
        None => {
            let mut best = 0;
            for (i, info) in infos.iter().enumerate() {
                if preference(info.device_type) > preference(infos[best].device_type) {
                    best = i;
                }
            }
            Ok(best)
        }
    }
}

/// One-line description of an adapter: `name (backend, type, driver)`.
pub fn describe(info: &wgpu::AdapterInfo) -> String {
    format!(
        "{} ({:?}, {:?}, {} {})",
        info.name, info.backend, info.device_type, info.driver, info.driver_info
    )
}

/// An instance over [`BACKENDS`]; `WGPU_BACKEND` and the debug flags still work for
/// people who know wgpu.
fn instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = BACKENDS;
    wgpu::Instance::new(desc.with_env())
}

/// Where the engine's work runs: a wgpu adapter (a GPU, or a CPU adapter such as
/// lavapipe), or the native CPU path alone on a machine with no GPU driver at all.
///
/// Training, refinement, prediction, evaluation and the experiments take a `Device`:
/// on [`Device::Native`] every step that has a native path takes it, and a step that
/// exists only as WGSL fails with [`GpuError::NeedsAdapter`]. Cheap to clone.
#[derive(Clone)]
pub enum Device {
    /// An opened adapter.
    Adapter(Arc<Gpu>),
    /// No adapter: the native CPU path.
    Native,
}

impl Device {
    /// Opens the adapter whose name contains `wanted`, else the one `IASTGCN_ADAPTER`
    /// names, else the best there is; with no adapter at all and none asked for by name,
    /// the native CPU ([`Device::Native`]). An adapter asked for by name that is not
    /// there stays an error.
    pub fn open(wanted: Option<&str>) -> Result<Device, GpuError> {
        let from_env = adapter_from_env();
        let wanted = wanted.or(from_env.as_deref());
        match Gpu::with_adapter(wanted) {
            Ok(gpu) => Ok(Device::Adapter(Arc::new(gpu))),
            Err(GpuError::NoAdapter { .. }) if wanted.is_none() => Ok(Device::Native),
            Err(e) => Err(e),
        }
    }

    /// The adapter, or [`GpuError::NeedsAdapter`] naming `what` on the native device.
    pub fn gpu(&self, what: &str) -> Result<&Arc<Gpu>, GpuError> {
        match self {
            Device::Adapter(gpu) => Ok(gpu),
            Device::Native => Err(GpuError::NeedsAdapter {
                what: what.to_string(),
                hint: INSTALL_HINT.to_string(),
            }),
        }
    }

    /// True where the native CPU path is the faster (or the only) one: no adapter, or a
    /// CPU adapter (lavapipe, WARP).
    pub fn prefers_native(&self) -> bool {
        match self {
            Device::Adapter(gpu) => gpu.is_software(),
            Device::Native => true,
        }
    }

    /// The adapter's name, or `native CPU (no GPU adapter)`.
    pub fn name(&self) -> String {
        match self {
            Device::Adapter(gpu) => gpu.info().name.clone(),
            Device::Native => NATIVE_NAME.to_string(),
        }
    }
}

/// The adapter name `IASTGCN_ADAPTER` asks for, if set and not empty.
fn adapter_from_env() -> Option<String> {
    std::env::var(ADAPTER_ENV).ok().filter(|s| !s.is_empty())
}

/// What [`Device::name`] says of the native device.
pub const NATIVE_NAME: &str = "native CPU (no GPU adapter)";

impl From<Gpu> for Device {
    fn from(gpu: Gpu) -> Device {
        Device::Adapter(Arc::new(gpu))
    }
}

impl From<Arc<Gpu>> for Device {
    fn from(gpu: Arc<Gpu>) -> Device {
        Device::Adapter(gpu)
    }
}

impl Gpu {
    /// Opens the adapter named by `IASTGCN_ADAPTER` if set, else the best one available.
    pub fn new() -> Result<Gpu, GpuError> {
        Gpu::with_adapter(adapter_from_env().as_deref())
    }

    /// Opens the first adapter whose name contains `wanted`, or the best one when `None`.
    pub fn with_adapter(wanted: Option<&str>) -> Result<Gpu, GpuError> {
        let adapters = pollster::block_on(instance().enumerate_adapters(BACKENDS));
        let infos: Vec<_> = adapters.iter().map(|a| a.get_info()).collect();
        let index = choose_adapter(&infos, wanted)?;
        let adapter = &adapters[index];
        let limits = adapter.limits();
        let adapter_features = adapter.features();
        let subgroups = std::env::var(SUBGROUPS_ENV).map_or(true, |v| v.trim() != "0");
        let wanted_features = if subgroups {
            adapter_features & wgpu::Features::SUBGROUP
        } else {
            wgpu::Features::empty()
        } | (adapter_features & wgpu::Features::TIMESTAMP_QUERY);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("iastgcn"),
            // Subgroup operations where offered: the matmul's lavapipe kernel shares
            // operand loads across a subgroup's lanes (ops/matmul/plan.rs picks it).
            // Timestamp queries where offered: profiles time each launch in one submit
            // (gpu/timestamps.rs); nothing else writes them.
            required_features: wanted_features,
            // wgpu's defaults are far below what compute needs (256 MiB buffers, 16 KiB
            // workgroup memory); ask for everything the adapter offers.
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice {
            adapter: describe(&infos[index]),
            reason: e.to_string(),
        })?;
        let faults = Arc::new(Faults::default());
        let sink = faults.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            lock(&sink.uncaptured).get_or_insert_with(|| e.to_string());
        }));
        let sink = faults.clone();
        device.set_device_lost_callback(move |reason, message| {
            *lock(&sink.lost) = Some(format!("{reason:?}: {message}"));
        });
        Ok(Gpu {
            device,
            queue,
            info: infos[index].clone(),
            limits,
            adapter_features,
            pipelines: Mutex::new(PipelineCache::default()),
            allocations: Mutex::new(None),
            faults,
            planning: Planning::Adapter,
        })
    }

    /// Lists every adapter the instance can see, without opening any.
    pub fn list_adapters() -> Vec<wgpu::AdapterInfo> {
        pollster::block_on(instance().enumerate_adapters(BACKENDS))
            .iter()
            .map(|a| a.get_info())
            .collect()
    }

    /// The adapter's name, backend and device type.
    pub fn info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// The limits the device was opened with (all the adapter offers).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Features the adapter supports (not all of them are enabled on the device).
    pub fn adapter_features(&self) -> wgpu::Features {
        self.adapter_features
    }

    /// The wgpu device, for work outside this crate's kernels.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The device's queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The lanes of every subgroup when the device runs subgroup operations and its
    /// subgroups have one fixed size (8 on lavapipe with 256-bit vectors); else `None`.
    pub fn subgroup_size(&self) -> Option<u32> {
        let fixed = self.info.subgroup_min_size == self.info.subgroup_max_size;
        let enabled = self.device.features().contains(wgpu::Features::SUBGROUP);
        (enabled && fixed).then_some(self.info.subgroup_min_size)
    }

    /// True when the device was opened with timestamp queries (the adapter offers them),
    /// so [`super::Timestamps`] can time launches.
    pub fn has_timestamps(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// True when the adapter is a CPU implementation (lavapipe, WARP, ...).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The same device with its launches planned for another kind of device (see
    /// [`Planning`]; [`Planning::Adapter`] when opened).
    pub fn with_planning(self, planning: Planning) -> Gpu {
        Gpu { planning, ..self }
    }

    /// Whether the planners shape launches for a CPU adapter ([`Gpu::with_planning`]).
    pub fn plans_for_cpu(&self) -> bool {
        match self.planning {
            Planning::Adapter => self.is_software(),
            Planning::Cpu => true,
            Planning::Gpu => false,
        }
    }

    /// Blocks until all submitted work has finished, then reports what went wrong in
    /// the meantime ([`Gpu::check`]).
    pub fn wait(&self) -> Result<(), GpuError> {
        let polled = self.device.poll(wgpu::PollType::wait_indefinitely());
        self.check()?;
        polled
            .map(|_| ())
            .map_err(|e| GpuError::Device(e.to_string()))
    }

    /// [`GpuError::DeviceLost`] once the device is lost (driver reset, removed GPU,
    /// `destroy`); else the first error no error scope caught since the last call, as
    /// [`GpuError::Device`]; else Ok. A lost device stays lost: build a new [`Gpu`].
    pub fn check(&self) -> Result<(), GpuError> {
        let lost = || {
            lock(&self.faults.lost)
                .clone()
                .map(|reason| GpuError::DeviceLost {
                    adapter: self.info.name.clone(),
                    reason,
                })
        };
        if let Some(e) = lost() {
            return Err(e);
        }
        let Some(message) = lock(&self.faults.uncaptured).take() else {
            return Ok(());
        };
        // An error on a destroyed or reset device: wgpu reports the loss itself only
        // when the device is next maintained, so let it, and report the loss first.
        let _ = self.device.poll(wgpu::PollType::Poll);
        Err(lost().unwrap_or(GpuError::Device(message)))
    }

    /// The error to report for `message`, captured by a scope around work on this
    /// device: [`GpuError::DeviceLost`] when the device turns out to be lost, else
    /// [`GpuError::Validation`] naming `what`.
    pub(crate) fn scope_error(&self, what: String, message: String) -> GpuError {
        let _ = self.device.poll(wgpu::PollType::Poll);
        match lock(&self.faults.lost).clone() {
            Some(reason) => GpuError::DeviceLost {
                adapter: self.info.name.clone(),
                reason,
            },
            None => GpuError::Validation { what, message },
        }
    }

    /// True once the device is lost.
    pub fn is_lost(&self) -> bool {
        lock(&self.faults.lost).is_some()
    }

    /// Runs `f` inside an error scope for `filter` and returns the error it captured,
    /// if any, as text. wgpu-core reports errors synchronously, so the pop resolves at
    /// once.
    pub(crate) fn scoped<T>(
        &self,
        filter: wgpu::ErrorFilter,
        f: impl FnOnce() -> T,
    ) -> (T, Option<String>) {
        let scope = self.device.push_error_scope(filter);
        let out = f();
        let error = pollster::block_on(scope.pop()).map(|e| e.to_string());
        (out, error)
    }
}
