//! WGSL sources, their validation with naga, and the per-device pipeline cache.
//!
//! Every op shader is compiled with `shaders/common.wgsl` prepended, so shared helpers
//! (indexing, activations) are written once. Errors are reported against the original
//! file and line, not the concatenation.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use super::uniform::{self, ShaderUniforms, Uniform};
use super::{Gpu, GpuError};

/// The helpers every op shader may use; prepended by [`Shader::full_source`].
pub const COMMON_WGSL: &str = include_str!("../../shaders/common.wgsl");

/// One `.wgsl` file of `shaders/`.
#[derive(Debug)]
pub struct Shader {
    /// File stem: `matmul` for `shaders/matmul.wgsl`.
    pub name: &'static str,
    /// The WGSL text (without the common prelude).
    pub source: &'static str,
    /// A shader whose declarations this one uses, compiled before it (after the common
    /// prelude): an entry point that needs a device feature lives in its own module, so
    /// that a device without the feature still compiles the base.
    pub base: Option<&'static Shader>,
}

impl Shader {
    /// The text handed to the compiler: common helpers, the base shader, then this file.
    pub fn full_source(&self) -> String {
        compose(self.base.map_or("", |b| b.source), self.source)
    }

    /// Parses and validates the shader (with the common prelude and its base) with naga.
    pub fn validate(&self) -> Result<naga::Module, GpuError> {
        self.reflect().map(|(module, _)| module)
    }

    /// [`Shader::validate`], with what the validator learned of the module (which globals
    /// each entry point uses).
    pub fn reflect(&self) -> Result<(naga::Module, naga::valid::ModuleInfo), GpuError> {
        validate_with_base(
            self.name,
            self.source,
            self.base.map(|b| (b.name, b.source)),
        )
    }
}

/// How a kernel uses one storage binding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// One storage binding of a kernel: its `@binding` slot and access. Slot 0 is always
/// the kernel's uniform parameter block.
#[derive(Clone, Copy, Debug)]
pub struct Binding {
    /// The `@binding` number (from 1; 0 is the uniform block).
    pub slot: u32,
    /// Read-only or read-write.
    pub access: Access,
}

impl Binding {
    /// A read-only storage binding at `slot`.
    pub const fn read(slot: u32) -> Binding {
        Binding {
            slot,
            access: Access::Read,
        }
    }

    /// A read-write storage binding at `slot`.
    pub const fn read_write(slot: u32) -> Binding {
        Binding {
            slot,
            access: Access::ReadWrite,
        }
    }
}

/// A compute entry point together with its bind layout.
#[derive(Debug)]
pub struct Kernel {
    /// The shader that defines it.
    pub shader: &'static Shader,
    /// The `@compute` entry point's name.
    pub entry: &'static str,
    /// Storage bindings in the order tensors are passed to [`crate::gpu::Gpu::dispatch`].
    pub bindings: &'static [Binding],
}

/// Validates `source` (with the common prelude) and maps error positions back to
/// `shaders/<name>.wgsl:line:col` (or `shaders/common.wgsl`). Needs no GPU.
///
/// ```
/// use iastgcn::gpu::validate_wgsl;
///
/// assert!(validate_wgsl("empty", "@compute @workgroup_size(64) fn main() {}").is_ok());
/// let err = validate_wgsl("broken", "fn main( {}").unwrap_err();
/// assert!(err.to_string().starts_with("shaders/broken.wgsl:1:"));
/// ```
pub fn validate_wgsl(name: &str, source: &str) -> Result<naga::Module, GpuError> {
    validate_with_base(name, source, None).map(|(module, _)| module)
}

/// The compiler's text: the common prelude, a base shader's source (or nothing), then
/// `source`, each followed by a newline (the line mapping of validation relies on it).
fn compose(base_source: &str, source: &str) -> String {
    format!("{COMMON_WGSL}\n{base_source}\n{source}")
}

/// [`validate_wgsl`] for a shader compiled after a base shader (`(name, source)`).
fn validate_with_base(
    name: &str,
    source: &str,
    base: Option<(&str, &str)>,
) -> Result<(naga::Module, naga::valid::ModuleInfo), GpuError> {
    let (base_name, base_source) = base.unwrap_or(("", ""));
    let full = compose(base_source, source);
    // Each part ends at the separator newline after it: (file, its last line in `full`).
    let common_end = COMMON_WGSL.matches('\n').count() + 1;
    let base_end = common_end + base_source.matches('\n').count() + 1;
    let locate = |span: Option<naga::Span>| -> String {
        match span.filter(|s| s.is_defined()) {
            Some(s) => {
                let loc = s.location(&full);
                let line = loc.line_number as usize;
                let (file, first) = if line <= common_end {
                    ("common", 0)
                } else if line <= base_end {
                    (base_name, common_end)
                } else {
                    (name, base_end)
                };
                format!("shaders/{file}.wgsl:{}:{}", line - first, loc.line_position)
            }
            None => format!("shaders/{name}.wgsl"),
        }
    };
    let module = naga::front::wgsl::parse_str(&full).map_err(|e| GpuError::Shader {
        location: locate(e.labels().next().map(|(span, _)| span)),
        message: e.message().to_string(),
    })?;
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    );
    let info = validator.validate(&module).map_err(|e| GpuError::Shader {
        location: locate(e.spans().next().map(|(span, _)| *span)),
        message: format!("{}", e.as_inner()),
    })?;
    Ok((module, info))
}

/// A compiled pipeline and the bind layout its dispatches use.
#[derive(Debug)]
pub struct Pipeline {
    pub(crate) pipeline: wgpu::ComputePipeline,
    pub(crate) layout: wgpu::BindGroupLayout,
}

type PipelineKey = (&'static str, &'static str, Vec<(&'static str, u64)>);

/// Shader modules and pipelines of one device; each is compiled once.
#[derive(Default)]
pub struct PipelineCache {
    modules: HashMap<&'static str, wgpu::ShaderModule>,
    pipelines: HashMap<PipelineKey, Arc<Pipeline>>,
    /// Each compiled shader's uniform structs, as naga reads them.
    uniforms: HashMap<&'static str, ShaderUniforms>,
    /// Kernels (shader, entry) whose Rust block has been compared with their WGSL struct.
    checked: HashSet<(&'static str, &'static str)>,
}

impl PipelineCache {
    /// Checks that `P` is the uniform block `kernel` reads, member for member, on the
    /// kernel's first dispatch (its pipeline compiled by [`PipelineCache::get`]); later
    /// dispatches compare the struct's name only.
    pub(crate) fn check_uniform<P: Uniform>(&mut self, kernel: &Kernel) -> Result<(), GpuError> {
        let label = || format!("{}::{}", kernel.shader.name, kernel.entry);
        let mismatch = |wgsl: String, what: String| GpuError::Uniform {
            rust: std::any::type_name::<P>().to_string(),
            wgsl,
            what,
        };
        let uniforms = self.uniforms.get(kernel.shader.name).ok_or_else(|| {
            mismatch(
                label(),
                "the kernel's shader is not compiled yet".to_string(),
            )
        })?;
        let Some(name) = uniforms.entries.get(kernel.entry) else {
            return Err(mismatch(
                label(),
                "the entry point reads no uniform block".to_string(),
            ));
        };
        let wgsl = format!("{}: struct {name}", label());
        // The block belongs to the kernel's shader (or to the base whose struct it reads):
        // two shaders may each have a struct of the same name.
        let owner = |s: &Shader| std::ptr::eq(s, P::SHADER);
        if !owner(kernel.shader) && !kernel.shader.base.is_some_and(owner) {
            return Err(mismatch(
                wgsl,
                format!("dispatched with a block of shaders/{}.wgsl", P::SHADER.name),
            ));
        }
        if name != P::WGSL {
            return Err(mismatch(wgsl, format!("dispatched with `{}`", P::WGSL)));
        }
        if self.checked.insert((kernel.shader.name, kernel.entry)) {
            let layout = P::layout();
            let compared = match uniforms.structs.get(name) {
                Some(wgsl) => uniform::compare(&layout, wgsl),
                None => Err("the uniform is not a struct".to_string()),
            };
            if let Err(what) = compared {
                self.checked.remove(&(kernel.shader.name, kernel.entry));
                return Err(mismatch(wgsl, what));
            }
        }
        Ok(())
    }

    /// Number of distinct pipelines compiled so far.
    pub fn len(&self) -> usize {
        self.pipelines.len()
    }

    /// True when no pipeline has been compiled yet.
    pub fn is_empty(&self) -> bool {
        self.pipelines.is_empty()
    }

    /// Returns the pipeline for `kernel` with the given override constants, compiling the
    /// shader module and the pipeline on first use.
    pub fn get(
        &mut self,
        gpu: &Gpu,
        kernel: &Kernel,
        constants: &[(&'static str, f64)],
    ) -> Result<Arc<Pipeline>, GpuError> {
        let key: PipelineKey = (
            kernel.shader.name,
            kernel.entry,
            constants.iter().map(|(k, v)| (*k, v.to_bits())).collect(),
        );
        if let Some(p) = self.pipelines.get(&key) {
            return Ok(p.clone());
        }
        let device = &gpu.device;
        if !self.modules.contains_key(kernel.shader.name) {
            self.uniforms
                .insert(kernel.shader.name, uniform::reflect(kernel.shader)?);
            let (module, error) = gpu.scoped(wgpu::ErrorFilter::Validation, || {
                device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(kernel.shader.name),
                    source: wgpu::ShaderSource::Wgsl(kernel.shader.full_source().into()),
                })
            });
            if let Some(message) = error {
                return Err(
                    gpu.scope_error(format!("shader module {}", kernel.shader.name), message)
                );
            }
            self.modules.insert(kernel.shader.name, module);
        }
        let module = &self.modules[kernel.shader.name];
        let mut entries = vec![wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        }];
        entries.extend(kernel.bindings.iter().map(|b| wgpu::BindGroupLayoutEntry {
            binding: b.slot,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage {
                    read_only: b.access == Access::Read,
                },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        }));
        let label = format!("{}::{}", kernel.shader.name, kernel.entry);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(&label),
            entries: &entries,
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(&label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let (pipeline, error) = gpu.scoped(wgpu::ErrorFilter::Validation, || {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(&label),
                layout: Some(&pipeline_layout),
                module,
                entry_point: Some(kernel.entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    zero_initialize_workgroup_memory: false,
                },
                cache: None,
            })
        });
        if let Some(message) = error {
            return Err(gpu.scope_error(format!("pipeline {label}"), message));
        }
        let p = Arc::new(Pipeline { pipeline, layout });
        self.pipelines.insert(key, p.clone());
        Ok(p)
    }
}
