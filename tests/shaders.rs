//! Every WGSL file parses and validates with naga (with the common prelude), and a broken
//! shader is reported with its own file and line; every kernel's uniform block in Rust
//! matches its WGSL struct (size, every member's name, offset and type), read through
//! naga's reflection, and a planted mismatch is caught, here and at dispatch.

use std::path::Path;

use bytemuck::Zeroable;
use iastgcn::gpu::{
    check_uniform, reflect_uniforms, validate_wgsl, Binding, DType, GpuError, Kernel, Scalar,
    Shader, Uniform, UniformLayout,
};
use iastgcn::testing::gpu;
use iastgcn::{model, ops};

fn shader_files() -> Vec<(String, String)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("shaders/ exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            (stem, std::fs::read_to_string(&p).unwrap())
        })
        .collect();
    files.sort();
    files
}

/// Every shader: the shared ops' and the steps' own kernels'.
fn all_shaders() -> Vec<&'static Shader> {
    ops::shaders()
        .into_iter()
        .chain(model::block::shaders())
        .collect()
}

/// Every uniform block on the Rust side, the shared ops' and the steps' kernels'.
fn all_uniforms() -> Vec<UniformLayout> {
    let mut all = ops::uniforms();
    all.extend(model::block::uniforms());
    all
}

#[test]
fn every_shader_file_validates() {
    let files = shader_files();
    assert!(
        files.len() >= 3,
        "expected common, elementwise and matmul shaders"
    );
    // Through the registry, so that a shader compiled after a base one (the subgroup
    // matmul after matmul.wgsl) is validated with it; the next test ties the registry to
    // the files.
    let failures: Vec<String> = all_shaders()
        .iter()
        .filter_map(|s| s.validate().err().map(|e| e.to_string()))
        .collect();
    assert!(
        failures.is_empty(),
        "invalid shaders:\n{}",
        failures.join("\n")
    );
}

#[test]
fn every_op_shader_is_registered_and_matches_its_file() {
    let files = shader_files();
    let registered = all_shaders();
    for (name, src) in files.iter().filter(|(n, _)| n != "common") {
        let s = registered
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("shaders/{name}.wgsl is not registered in ops::shaders() or model::block::shaders()"));
        assert_eq!(&s.source, src, "the registry holds a stale copy of {name}");
    }
    assert_eq!(registered.len(), files.len() - 1);
}

#[test]
fn syntax_error_names_file_and_line() {
    let src = "fn ok() -> f32 {\n    return 1.0;\n}\nfn broken( -> f32 { return 2.0; }\n";
    let err = validate_wgsl("broken", src).unwrap_err().to_string();
    assert!(err.starts_with("shaders/broken.wgsl:4:"), "{err}");
}

#[test]
fn validation_error_names_file_and_line() {
    // Parses, but returns an f32 from a u32 function: a validation (not parse) error.
    let src = "\n\nfn wrong() -> u32 {\n    return relu(1.0);\n}\n";
    let err = validate_wgsl("typed", src).unwrap_err().to_string();
    assert!(err.starts_with("shaders/typed.wgsl:"), "{err}");
    let line: usize = err.split(':').nth(1).unwrap().parse().unwrap();
    assert!((3..=4).contains(&line), "{err}");
}

#[test]
fn error_after_a_base_shader_names_its_own_file_and_line() {
    // Uses the base's parameters (`p`), then breaks on line 4 of its own text.
    let derived = Shader {
        name: "derived",
        source: "fn ok() -> u32 {\n    return p.m;\n}\nfn broken( -> u32 { return 2u; }\n",
        base: Some(&ops::matmul::SHADER),
    };
    let err = derived.validate().unwrap_err().to_string();
    assert!(err.starts_with("shaders/derived.wgsl:4:"), "{err}");
    let fixed = Shader {
        source: "fn ok() -> u32 {\n    return p.m;\n}\n",
        ..derived
    };
    fixed.validate().unwrap();
}

#[test]
fn helpers_from_common_are_visible() {
    let src = "@compute @workgroup_size(1) fn main() { let s = sigmoid(0.5) + tanh_stable(0.1) + relu(-1.0); }";
    validate_wgsl("uses_common", src).unwrap();
}

#[test]
fn every_rust_uniform_block_matches_its_wgsl_struct() {
    let layouts = all_uniforms();
    assert!(layouts.len() >= 19, "{} blocks", layouts.len());
    let failures: Vec<String> = layouts
        .iter()
        .filter_map(|l| check_uniform(l).err().map(|e| e.to_string()))
        .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn every_wgsl_uniform_struct_has_a_rust_block() {
    let layouts = all_uniforms();
    for shader in all_shaders() {
        let uniforms = reflect_uniforms(shader).unwrap();
        assert!(
            !uniforms.structs.is_empty(),
            "shaders/{}.wgsl binds no uniform block",
            shader.name
        );
        for name in uniforms.structs.keys() {
            // A derived shader sees its base's blocks; they belong to the base.
            let owner = if shader.source.contains(&format!("struct {name} ")) {
                shader.name
            } else {
                shader
                    .base
                    .expect("a struct not in the file is its base's")
                    .name
            };
            assert!(
                layouts
                    .iter()
                    .any(|l| l.wgsl == name.as_str() && l.shader.name == owner),
                "struct {name} of shaders/{owner}.wgsl has no Rust block in ops::uniforms() or model::block::uniforms()"
            );
        }
        // Every entry point reads its block (slot 0 is bound for every kernel).
        for entry in naga_entries(shader) {
            assert!(
                uniforms.entries.contains_key(&entry),
                "{}::{entry} reads no uniform block",
                shader.name
            );
        }
    }
}

fn naga_entries(shader: &Shader) -> Vec<String> {
    let module = shader.validate().unwrap();
    module.entry_points.iter().map(|e| e.name.clone()).collect()
}

/// A copy of a real block's layout with one thing changed must fail, naming what.
#[test]
fn a_planted_mismatch_in_a_rust_block_is_caught() {
    let layer_norm = all_uniforms()
        .into_iter()
        .find(|l| l.wgsl == "LnParams")
        .unwrap();
    check_uniform(&layer_norm).unwrap();
    let plant = |change: &dyn Fn(&mut UniformLayout), expect: &str| {
        let mut l = layer_norm.clone();
        change(&mut l);
        let err = check_uniform(&l).unwrap_err().to_string();
        assert!(err.contains("shaders/layer_norm.wgsl: struct"), "{err}");
        assert!(
            err.contains("residual_layer_norm::layer_norm_kernel::Params"),
            "{err}"
        );
        assert!(err.contains(expect), "wanted {expect:?} in: {err}");
    };
    // Two fields declared in the other order: the same size, each at the other's offset.
    plant(
        &|l| {
            let (eps, relu) = (l.members[4].clone(), l.members[5].clone());
            l.members[4] = iastgcn::gpu::UniformMember {
                offset: eps.offset,
                ..relu.clone()
            };
            l.members[5] = iastgcn::gpu::UniformMember {
                offset: relu.offset,
                ..eps
            };
        },
        "member 4: `relu_input: u32` at byte 16 in Rust, `eps: f32` at byte 16 in WGSL",
    );
    // A type changed: eps as u32.
    plant(
        &|l| l.members[4].scalar = Scalar::U32,
        "`eps: u32` at byte 16 in Rust, `eps: f32`",
    );
    // A padding member dropped: size and count differ.
    plant(
        &|l| {
            l.members.pop();
            l.size -= 4;
        },
        "size 60 bytes in Rust, 64 in WGSL",
    );
    plant(
        &|l| l.members.truncate(15),
        "`pad1` in WGSL has no Rust counterpart",
    );
    // A misnamed struct.
    plant(
        &|l| l.wgsl = "LayerNormParams",
        "no `var<uniform>` of this struct",
    );
}

static PLANTED: Shader = Shader {
    name: "planted",
    source:
        "struct PlantedParams {\n    n: u32,\n    scale: f32,\n    pad0: u32,\n    pad1: u32,\n}\n\
        @group(0) @binding(0) var<uniform> p: PlantedParams;\n\
        @group(0) @binding(1) var<storage, read_write> out: array<f32>;\n\
        @compute @workgroup_size(64) fn planted(@builtin(global_invocation_id) id: vec3<u32>) {\n\
        if (id.x < p.n) { out[id.x] = p.scale; }\n}\n",
    base: None,
};

static PLANTED_KERNEL: Kernel = Kernel {
    shader: &PLANTED,
    entry: "planted",
    bindings: &[Binding::read_write(1)],
};

iastgcn::gpu::uniform! {
    /// The block `PlantedParams` as written.
    struct Planted = PlantedParams in PLANTED {
        n: u32,
        scale: f32,
        pad0: u32,
        pad1: u32,
    }
}

iastgcn::gpu::uniform! {
    /// The same block with `n` and `scale` swapped: the same size, a different layout.
    struct Swapped = PlantedParams in PLANTED {
        scale: f32,
        n: u32,
        pad0: u32,
        pad1: u32,
    }
}

iastgcn::gpu::uniform! {
    /// A block that names another struct.
    struct Other = OtherParams in PLANTED {
        n: u32,
        scale: f32,
        pad0: u32,
        pad1: u32,
    }
}

static PLANTED_TWIN: Shader = Shader {
    name: "planted_twin",
    source: PLANTED.source,
    base: None,
};

iastgcn::gpu::uniform! {
    /// The block of another shader that has a struct of the same name and layout.
    struct Foreign = PlantedParams in PLANTED_TWIN {
        n: u32,
        scale: f32,
        pad0: u32,
        pad1: u32,
    }
}

#[test]
fn a_block_declared_with_the_macro_is_checked_through_reflection() {
    check_uniform(&Foreign::layout()).unwrap();
    check_uniform(&Planted::layout()).unwrap();
    let err = check_uniform(&Swapped::layout()).unwrap_err().to_string();
    assert!(
        err.contains("member 0: `scale: f32` at byte 0 in Rust, `n: u32` at byte 0 in WGSL"),
        "{err}"
    );
    assert!(err.contains("shaders/planted.wgsl"), "{err}");
}

/// On a device: the kernel's first dispatch compares the block with the struct its entry
/// point reads, and refuses a drifted or a foreign one before anything runs.
#[test]
fn dispatch_refuses_a_block_that_does_not_match_the_kernel() {
    // The refused blocks' values do not matter: they are refused by their layout.
    let gpu = gpu();
    let out = gpu.zeros("out", &[64], DType::F32).unwrap();
    let swapped = Swapped::zeroed();
    match gpu.dispatch(&PLANTED_KERNEL, &[], &swapped, &[&out], [1, 1, 1]) {
        Err(GpuError::Uniform { what, .. }) => assert!(what.contains("member 0"), "{what}"),
        other => panic!("a swapped block was dispatched: {other:?}"),
    }
    let other = Other::zeroed();
    match gpu.dispatch(&PLANTED_KERNEL, &[], &other, &[&out], [1, 1, 1]) {
        Err(GpuError::Uniform { what, wgsl, .. }) => {
            assert!(
                wgsl.contains("planted::planted: struct PlantedParams"),
                "{wgsl}"
            );
            assert!(what.contains("OtherParams"), "{what}");
        }
        other => panic!("a foreign block was dispatched: {other:?}"),
    }
    // A block of another shader whose struct has the same name.
    let foreign = Foreign::zeroed();
    match gpu.dispatch(&PLANTED_KERNEL, &[], &foreign, &[&out], [1, 1, 1]) {
        Err(GpuError::Uniform { what, .. }) => {
            assert!(
                what.contains("a block of shaders/planted_twin.wgsl"),
                "{what}"
            )
        }
        other => panic!("another shader's block was dispatched: {other:?}"),
    }
    let good = Planted {
        n: 64,
        scale: 2.0,
        pad0: 0,
        pad1: 0,
    };
    let d = gpu
        .dispatch(&PLANTED_KERNEL, &[], &good, &[&out], [1, 1, 1])
        .unwrap();
    // Writing another block's type over a recorded dispatch is refused as well.
    assert!(matches!(
        d.write_params(&gpu, &other),
        Err(GpuError::Uniform { .. })
    ));
    d.write_params(&gpu, &good).unwrap();
}
