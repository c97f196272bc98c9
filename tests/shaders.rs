//! Every WGSL file parses and validates with naga (with the common prelude), and a broken
//! shader is reported with its own file and line.

use std::path::Path;

use iastgcn::gpu::{validate_wgsl, Shader};
use iastgcn::ops;

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
    let failures: Vec<String> = ops::shaders()
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
    let registered = ops::shaders();
    for (name, src) in files.iter().filter(|(n, _)| n != "common") {
        let s = registered
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("shaders/{name}.wgsl is not registered in ops::shaders()"));
        assert_eq!(&s.source, src, "ops registry holds a stale copy of {name}");
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
