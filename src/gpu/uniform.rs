//! The uniform parameter blocks of the kernels, written once in WGSL and once in Rust, and
//! the check that the two agree.
//!
//! A Rust block is declared with [`uniform!`](crate::uniform!): the macro adds
//! `#[repr(C)]` and `bytemuck`'s derives and implements [`Uniform`], which names the shader
//! and the WGSL struct the block mirrors and lists its members (name, byte offset, scalar
//! type). [`check`] reads the WGSL struct through naga's reflection and compares the size
//! and every member. [`Gpu::dispatch`](crate::gpu::Gpu::dispatch) takes only a
//! [`Uniform`] and makes the same comparison on the first dispatch of each kernel, against
//! the struct that kernel's entry point actually binds at slot 0, so a block that drifts
//! from its shader is an error before anything runs. `ops::uniforms()` and `model::block::uniforms()` list every block
//! for the test that checks them all without a device.

use std::collections::HashMap;
use std::fmt;

use super::{GpuError, Shader};

/// The scalar type of one member of a uniform block (every block is made of 4-byte
/// scalars).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    /// `u32`.
    U32,
    /// `i32`.
    I32,
    /// `f32`.
    F32,
}

impl fmt::Display for Scalar {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Scalar::U32 => "u32",
            Scalar::I32 => "i32",
            Scalar::F32 => "f32",
        })
    }
}

/// A Rust type that may be a member of a uniform block.
pub trait ScalarType {
    /// Its WGSL counterpart.
    const SCALAR: Scalar;
}

impl ScalarType for u32 {
    const SCALAR: Scalar = Scalar::U32;
}
impl ScalarType for i32 {
    const SCALAR: Scalar = Scalar::I32;
}
impl ScalarType for f32 {
    const SCALAR: Scalar = Scalar::F32;
}

/// One member of a uniform block: its name, byte offset and type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Member {
    /// The field's name (the same in Rust and WGSL).
    pub name: String,
    /// Byte offset from the start of the block.
    pub offset: usize,
    /// Its scalar type.
    pub scalar: Scalar,
}

/// The layout of a Rust uniform block and what it mirrors.
#[derive(Clone, Debug)]
pub struct Layout {
    /// The Rust type's path, for messages.
    pub rust: &'static str,
    /// The shader that declares the WGSL struct (a derived shader's blocks are its base's).
    pub shader: &'static Shader,
    /// The WGSL struct's name.
    pub wgsl: &'static str,
    /// `size_of` the Rust type.
    pub size: usize,
    /// Every field, in declaration order.
    pub members: Vec<Member>,
}

/// A kernel's uniform parameter block on the Rust side; implemented by
/// [`uniform!`](crate::uniform!).
pub trait Uniform: bytemuck::Pod {
    /// The shader that declares the WGSL struct.
    const SHADER: &'static Shader;
    /// The WGSL struct's name.
    const WGSL: &'static str;
    /// Size and members, read from the Rust type.
    fn layout() -> Layout;
}

/// Declares a kernel's uniform block: `#[repr(C)]`, `bytemuck`'s `Pod` and `Zeroable`,
/// `Clone` and `Copy`, and [`Uniform`](crate::gpu::Uniform) naming the WGSL struct it
/// mirrors. Members are 4-byte scalars (`u32`, `i32`, `f32`) with the WGSL struct's names,
/// padding included.
///
/// ```ignore
/// uniform! {
///     /// The block of `shaders/head.wgsl`.
///     struct Params = HeadParams in SHADER {
///         rows: u32,
///         steps: u32,
///         _pad0: u32,
///         _pad1: u32,
///     }
/// }
/// ```
#[macro_export]
macro_rules! uniform {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident = $wgsl:ident in $shader:path {
            $($(#[$fmeta:meta])* $field:ident : $ty:ty),* $(,)?
        }
    ) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
        $vis struct $name {
            $($(#[$fmeta])* $field: $ty),*
        }

        impl $crate::gpu::Uniform for $name {
            const SHADER: &'static $crate::gpu::Shader = &$shader;
            const WGSL: &'static str = stringify!($wgsl);
            fn layout() -> $crate::gpu::UniformLayout {
                $crate::gpu::UniformLayout {
                    rust: concat!(module_path!(), "::", stringify!($name)),
                    shader: &$shader,
                    wgsl: stringify!($wgsl),
                    size: ::std::mem::size_of::<$name>(),
                    members: vec![$($crate::gpu::UniformMember {
                        name: stringify!($field).to_string(),
                        offset: ::std::mem::offset_of!($name, $field),
                        scalar: <$ty as $crate::gpu::ScalarType>::SCALAR,
                    }),*],
                }
            }
        }
    };
}

/// A WGSL struct as naga lays it out: its size (span) and members, or why one of its
/// members is not a 4-byte scalar.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WgslStruct {
    /// The struct's span in bytes.
    pub size: usize,
    /// Every member in order; `Err` holds a member's name and type when it is not a scalar.
    pub members: Vec<Result<Member, String>>,
}

/// What naga reads of one shader's uniform blocks: each struct bound as `var<uniform>`,
/// and which of them each entry point uses.
#[derive(Clone, Debug, Default)]
pub struct ShaderUniforms {
    /// Struct name → its layout, for every struct of a `var<uniform>`.
    pub structs: HashMap<String, WgslStruct>,
    /// Entry point → the struct of the uniform it reads (absent when it reads none).
    pub entries: HashMap<String, String>,
}

/// Reads every uniform struct of `shader` (with its prelude and base) and the entry points
/// that read each.
pub fn reflect(shader: &Shader) -> Result<ShaderUniforms, GpuError> {
    let (module, info) = shader.reflect()?;
    let mut out = ShaderUniforms::default();
    let mut uniform_of = HashMap::new();
    for (handle, global) in module.global_variables.iter() {
        if global.space != naga::AddressSpace::Uniform {
            continue;
        }
        let ty = &module.types[global.ty];
        let name = ty.name.clone().unwrap_or_default();
        if let naga::TypeInner::Struct { members, span } = &ty.inner {
            let members = members
                .iter()
                .map(|m| {
                    let member = m.name.clone().unwrap_or_default();
                    match module.types[m.ty].inner {
                        naga::TypeInner::Scalar(s) if s.width == 4 => {
                            let scalar = match s.kind {
                                naga::ScalarKind::Uint => Scalar::U32,
                                naga::ScalarKind::Sint => Scalar::I32,
                                naga::ScalarKind::Float => Scalar::F32,
                                _ => return Err(format!("{member}: {:?}", s.kind)),
                            };
                            Ok(Member {
                                name: member,
                                offset: m.offset as usize,
                                scalar,
                            })
                        }
                        ref other => Err(format!("{member}: {other:?}")),
                    }
                })
                .collect();
            out.structs.insert(
                name.clone(),
                WgslStruct {
                    size: *span as usize,
                    members,
                },
            );
        }
        uniform_of.insert(handle, name);
    }
    for (index, entry) in module.entry_points.iter().enumerate() {
        let uses = info.get_entry_point(index);
        if let Some(name) = uniform_of
            .iter()
            .find(|(handle, _)| !uses[**handle].is_empty())
            .map(|(_, name)| name.clone())
        {
            out.entries.insert(entry.name.clone(), name);
        }
    }
    Ok(out)
}

/// Compares a Rust block with the WGSL struct it names; the error says what differs.
pub fn compare(layout: &Layout, wgsl: &WgslStruct) -> Result<(), String> {
    let mut wrong = Vec::new();
    if layout.size != wgsl.size {
        wrong.push(format!(
            "size {} bytes in Rust, {} in WGSL",
            layout.size, wgsl.size
        ));
    }
    let count = layout.members.len().max(wgsl.members.len());
    for i in 0..count {
        match (layout.members.get(i), wgsl.members.get(i)) {
            (Some(r), Some(Ok(w))) if r == w => {}
            (Some(r), Some(Ok(w))) => wrong.push(format!(
                "member {i}: `{}: {}` at byte {} in Rust, `{}: {}` at byte {} in WGSL",
                r.name, r.scalar, r.offset, w.name, w.scalar, w.offset
            )),
            (_, Some(Err(what))) => wrong.push(format!(
                "member {i} of the WGSL struct is not a 4-byte scalar ({what})"
            )),
            (Some(r), None) => wrong.push(format!(
                "member {i}: `{}` in Rust has no WGSL counterpart",
                r.name
            )),
            (None, Some(Ok(w))) => wrong.push(format!(
                "member {i}: `{}` in WGSL has no Rust counterpart",
                w.name
            )),
            (None, None) => {}
        }
    }
    if wrong.is_empty() {
        Ok(())
    } else {
        Err(wrong.join("; "))
    }
}

/// Checks a Rust block against its shader's WGSL struct of the same name.
pub fn check(layout: &Layout) -> Result<(), GpuError> {
    let uniforms = reflect(layout.shader)?;
    let mismatch = |what: String| GpuError::Uniform {
        rust: layout.rust.to_string(),
        wgsl: format!(
            "shaders/{}.wgsl: struct {}",
            layout.shader.name, layout.wgsl
        ),
        what,
    };
    let wgsl = uniforms
        .structs
        .get(layout.wgsl)
        .ok_or_else(|| mismatch("no `var<uniform>` of this struct in the shader".into()))?;
    compare(layout, wgsl).map_err(mismatch)
}
