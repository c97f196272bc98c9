//! The device layer: adapter choice, tensors, pipeline cache, recorder, readback.
//!
//! Knows nothing about robots or training; it moves tensors and runs kernels.

mod device;
mod pipeline;
mod recorder;
mod tensor;
mod timestamps;
mod uniform;

/// Declares a kernel's uniform block (see [`Uniform`]); defined in `gpu/uniform.rs`, at the
/// crate's root only because `#[macro_export]` puts it there.
pub use super::uniform;
pub use device::{
    choose_adapter, describe, Allocation, Device, Gpu, Planning, ADAPTER_ENV, BACKENDS,
    INSTALL_HINT, NATIVE_NAME, SUBGROUPS_ENV,
};
pub use pipeline::{validate_wgsl, Access, Binding, Kernel, PipelineCache, Shader, COMMON_WGSL};
pub use recorder::{Dispatch, Recorder};
pub use tensor::{DType, Readback, Tensor};
pub use timestamps::{Interval, Timestamps};
pub use uniform::{
    check as check_uniform, reflect as reflect_uniforms, Layout as UniformLayout,
    Member as UniformMember, Scalar, ScalarType, ShaderUniforms, Uniform, WgslStruct,
};

use wgpu::util::DeviceExt;

/// Everything that can go wrong in the device layer, with the name of what was involved.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter of any backend.
    #[error("no GPU adapter found (Vulkan, Metal or DX12): {hint}")]
    NoAdapter {
        /// What to try (drivers, a software adapter).
        hint: String,
    },
    /// No adapter's name contains the one asked for.
    #[error(
        "no adapter name contains {wanted:?} (set by {ADAPTER_ENV} or --adapter); available: {}",
        if available.is_empty() { "none".to_string() } else { available.join("; ") }
    )]
    AdapterNotFound {
        /// The name fragment asked for.
        wanted: String,
        /// The names of the adapters there are.
        available: Vec<String>,
    },
    /// The adapter refused to open a device (limits, features, driver).
    #[error("could not open a device on {adapter}: {reason}")]
    RequestDevice {
        /// The adapter's name.
        adapter: String,
        /// What wgpu said.
        reason: String,
    },
    /// A WGSL shader that does not parse or validate.
    #[error("{location}: {message}")]
    Shader {
        /// `shaders/<file>.wgsl:line:column`.
        location: String,
        /// What naga said.
        message: String,
    },
    /// A tensor of the wrong size or shape for the kernel or the data given.
    #[error("tensor {tensor}: expected {expected}, got {got}")]
    Shape {
        /// The tensor's name.
        tensor: String,
        /// The shape or length expected.
        expected: String,
        /// The one it has.
        got: String,
    },
    /// A Rust uniform block that does not match the WGSL struct it is bound to.
    #[error("uniform block {rust} does not match {wgsl}: {what}")]
    Uniform {
        /// The Rust type.
        rust: String,
        /// The shader file, kernel or struct it was compared with.
        wgsl: String,
        /// What differs.
        what: String,
    },
    /// A dispatch larger than the device allows.
    #[error("{kernel}: {count} workgroups along one axis exceed the device limit of {limit}")]
    TooManyWorkgroups {
        /// The kernel's name.
        kernel: String,
        /// The workgroups asked for along the axis.
        count: u32,
        /// The device's limit per axis.
        limit: u32,
    },
    /// A tensor larger than one buffer of this adapter may be.
    #[error(
        "tensor {tensor} needs {}; this adapter allows {} per buffer ({limit_name})",
        human_bytes(*bytes), human_bytes(*limit)
    )]
    TooLarge {
        /// The tensor's name.
        tensor: String,
        /// The bytes it needs.
        bytes: u64,
        /// The adapter's limit in bytes.
        limit: u64,
        /// Which wgpu limit that is.
        limit_name: &'static str,
    },
    /// The device had no memory left for a buffer.
    #[error("out of device memory allocating {tensor} ({}): {message}", human_bytes(*bytes))]
    OutOfMemory {
        /// The tensor's name.
        tensor: String,
        /// The bytes asked for.
        bytes: u64,
        /// What wgpu said.
        message: String,
    },
    /// wgpu refused to build or run something; names the kernel or step.
    #[error("{what}: {message}")]
    Validation {
        /// The kernel, pipeline or submit involved.
        what: String,
        /// What wgpu said.
        message: String,
    },
    /// The device is gone (driver reset, GPU removed, destroyed); nothing on it can be
    /// used again. Open a new [`Gpu`] and rebuild (e.g. `Predictor::rebuild`).
    #[error("the device on {adapter} was lost ({reason}); open a new device and rebuild")]
    DeviceLost {
        /// The adapter's name.
        adapter: String,
        /// What the driver said.
        reason: String,
    },
    /// Copying a tensor back to the host failed; the text names the tensor.
    #[error("readback of {0} failed")]
    Readback(String),
    /// Any other failure of the device, or a call it cannot serve; the text says which.
    #[error("device error: {0}")]
    Device(String),
    /// Something that runs only as WGSL was asked of the native CPU device (a machine
    /// without a GPU driver).
    #[error(
        "{what} needs a GPU adapter (Vulkan, Metal or DX12), and this machine has none: {hint}"
    )]
    NeedsAdapter {
        /// What was asked.
        what: String,
        /// What to try (drivers, a software adapter).
        hint: String,
    },
}

impl crate::error::StageError for GpuError {}

impl Gpu {
    /// Binds `tensors` to `kernel`'s storage slots (in [`Kernel::bindings`] order), with
    /// `params` as the uniform block at slot 0, ready to record.
    pub fn dispatch<P: Uniform>(
        &self,
        kernel: &Kernel,
        constants: &[(&'static str, f64)],
        params: &P,
        tensors: &[&Tensor],
        workgroups: [u32; 3],
    ) -> Result<Dispatch, GpuError> {
        let label = format!("{}::{}", kernel.shader.name, kernel.entry);
        if tensors.len() != kernel.bindings.len() {
            return Err(GpuError::Shape {
                tensor: format!("bindings of {label}"),
                expected: format!("{} tensors", kernel.bindings.len()),
                got: format!("{}", tensors.len()),
            });
        }
        let limit = self.limits().max_compute_workgroups_per_dimension;
        if let Some(&count) = workgroups.iter().find(|&&c| c > limit) {
            return Err(GpuError::TooManyWorkgroups {
                kernel: label,
                count,
                limit,
            });
        }
        let pipeline = {
            let mut cache = device::lock(&self.pipelines);
            let pipeline = cache.get(self, kernel, constants)?;
            cache.check_uniform::<P>(kernel)?;
            pipeline
        };
        let (made, error) = self.scoped(wgpu::ErrorFilter::Validation, || {
            self.bind(kernel, &label, &pipeline, params, tensors)
        });
        match error {
            Some(message) => Err(self.scope_error(format!("binding {label}"), message)),
            None => Ok(Dispatch {
                pipeline,
                bind_group: made.1,
                params: made.0,
                uniform: P::WGSL,
                workgroups,
                label,
                target: tensors
                    .last()
                    .map_or_else(String::new, |t| t.name().to_string()),
                flops: 0.0,
                next: None,
            }),
        }
    }

    /// The uniform block and the bind group of one dispatch.
    fn bind<P: bytemuck::Pod>(
        &self,
        kernel: &Kernel,
        label: &str,
        pipeline: &pipeline::Pipeline,
        params: &P,
        tensors: &[&Tensor],
    ) -> (wgpu::Buffer, wgpu::BindGroup) {
        let params = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::bytes_of(params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: params.as_entire_binding(),
        }];
        entries.extend(
            kernel
                .bindings
                .iter()
                .zip(tensors)
                .map(|(b, t)| wgpu::BindGroupEntry {
                    binding: b.slot,
                    resource: t.buffer.as_entire_binding(),
                }),
        );
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &pipeline.layout,
            entries: &entries,
        });
        (params, bind_group)
    }

    /// Number of pipelines compiled on this device so far.
    pub fn pipeline_count(&self) -> usize {
        device::lock(&self.pipelines).len()
    }

    /// Records `dispatches` into one command buffer, submits it and waits.
    pub fn run(&self, dispatches: &[Dispatch]) -> Result<(), GpuError> {
        let mut rec = Recorder::new(self);
        rec.dispatch_all(dispatches);
        rec.submit()?;
        self.wait()
    }
}

impl GpuError {
    /// For a [`GpuError::TooLarge`] of work that holds `count` items (windows in a
    /// batch) and grows in proportion to it: the largest power of two of items that
    /// fits the limit, to suggest (`None` for other errors, or when not even one fits).
    pub fn fitting_count(&self, count: usize) -> Option<usize> {
        let GpuError::TooLarge { bytes, limit, .. } = self else {
            return None;
        };
        let per_item = bytes.div_ceil(count.max(1) as u64).max(1);
        let fits = limit / per_item;
        (fits >= 1).then(|| 1usize << (usize::BITS - 1 - (fits as usize).leading_zeros()))
    }
}

/// Bytes as a short human number: `512 B`, `3.0 MiB`, `9.1 GiB`.
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

/// Workgroup grid that covers `threads` invocations of a 1-D kernel with `size` threads per
/// workgroup, folded into x and y so neither exceeds `max_per_dim`. The kernel recovers
/// the flat index as `(wg.y * num_wg.x + wg.x) * size + local`.
pub fn grid_1d(threads: usize, size: u32, max_per_dim: u32) -> [u32; 3] {
    let groups = threads.div_ceil(size as usize).max(1) as u64;
    let max = max_per_dim as u64;
    if groups <= max {
        [groups as u32, 1, 1]
    } else {
        let y = groups.div_ceil(max);
        [groups.div_ceil(y) as u32, y as u32, 1]
    }
}
