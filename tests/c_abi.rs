//! The C ABI (src/embed/c_api.rs): the checked-in header is what cbindgen makes of the
//! source; the C controller example compiles against it, links the library this test
//! run built, and prints the Rust example's lines bit for bit; and the functions refuse
//! bad input with a status and a message instead of crashing.

mod common;

use std::ffi::{c_char, CStr, CString};
use std::path::{Path, PathBuf};
use std::process::Command;

use iastgcn::embed::c_api::*;

/// What a program linking `libiastgcn.a` adds (rustc's `--print native-static-libs` on
/// Linux; docs/embedding.md "C").
const STATIC_LIBS: &str = "-lgcc_s -lutil -lrt -lpthread -lm -ldl -lc";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The profile folder this test was built into (`target/debug`): `cargo test` builds the
/// examples into its `examples/`.
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.parent().and_then(Path::parent).unwrap().to_path_buf()
}

/// Runs `command` (`what` it does, for the message), which must succeed.
fn succeeded(command: &mut Command, what: &str) {
    let out = command
        .output()
        .unwrap_or_else(|e| panic!("{what}: {e} (is the program installed?)"));
    assert!(
        out.status.success(),
        "{what} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The folder holding the C ABI's libraries (`libiastgcn.so`, `libiastgcn.a`) of this
/// source, built now in this test's profile as `make c-library` builds them (the crate's
/// own builds make only the Rust library).
fn c_libraries() -> PathBuf {
    let dir = profile_dir();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut build = Command::new(&cargo);
    build.current_dir(root()).args([
        "rustc",
        "--quiet",
        "--lib",
        "--crate-type",
        "cdylib,staticlib",
    ]);
    match dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") => {}
        Some("release") => {
            build.arg("--release");
        }
        Some(other) => {
            build.args(["--profile", other]);
        }
        None => panic!("no profile folder above {}", dir.display()),
    }
    if let Some(target) = dir.parent() {
        build.env("CARGO_TARGET_DIR", target);
    }
    succeeded(
        &mut build,
        "`cargo rustc --lib --crate-type cdylib,staticlib`",
    );
    dir
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("iastgcn-c-abi-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A freshly initialised checkpoint of the demo's shape, with statistics that are not
/// the identity (so that the standardisation of inputs and outputs is exercised); the
/// pytest suite makes the same one (python/tests/conftest.py).
fn checkpoint(dir: &Path) -> PathBuf {
    seeded_checkpoint(dir, "model", 5)
}

/// As [`checkpoint`], initialised with `seed`, in `dir/<name>.safetensors`.
fn seeded_checkpoint(dir: &Path, name: &str, seed: u64) -> PathBuf {
    let out = dir.join(format!("{name}.safetensors"));
    let config = root().join("assets/demo.toml");
    common::cli(&[
        "init",
        "--config",
        config.to_str().unwrap(),
        "--seed",
        &seed.to_string(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let mut ck = iastgcn::model::Checkpoint::load(&out).unwrap();
    let nz = &mut ck.normalization;
    for (n, (mean, std)) in nz
        .feature_mean
        .iter_mut()
        .zip(&mut nz.feature_std)
        .enumerate()
    {
        *mean = vec![20.0 + n as f64, 0.001, 0.5];
        *std = vec![0.3, 0.01, 0.2];
    }
    nz.label_mean = vec![5.0, -3.0, 2.0, 1.0, -1.0, 0.5];
    nz.label_std = vec![30.0, 20.0, 10.0, 5.0, 4.0, 3.0];
    ck.save(&out).unwrap();
    out
}

/// The header cbindgen generates from the source now.
fn generated_header() -> String {
    let config = cbindgen::Config::from_file(root().join("cbindgen.toml")).unwrap();
    let mut bytes = Vec::new();
    cbindgen::Builder::new()
        .with_config(config)
        .with_src(root().join("src/embed/c_api.rs"))
        .generate()
        .expect("cbindgen")
        .write(&mut bytes);
    String::from_utf8(bytes).unwrap()
}

#[test]
fn checked_in_header_is_what_cbindgen_generates() {
    let path = root().join("include/iastgcn.h");
    let fresh = generated_header();
    if std::env::var_os("IASTGCN_WRITE_HEADER").is_some() {
        std::fs::write(&path, &fresh).unwrap();
    }
    let checked_in = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        checked_in == fresh,
        "include/iastgcn.h is stale: src/embed/c_api.rs changed; run `make header` and \
         commit the result"
    );
}

#[test]
fn c_controller_example_prints_the_rust_examples_residuals() {
    let dir = scratch("example");
    let model = checkpoint(&dir);
    let lib_dir = c_libraries();
    for library in ["libiastgcn.so", "libiastgcn.a"] {
        assert!(
            lib_dir.join(library).exists(),
            "{library} is missing from {} after `cargo rustc --crate-type cdylib,staticlib`",
            lib_dir.display()
        );
    }
    let rust_example = profile_dir().join("examples/controller");
    assert!(
        rust_example.exists(),
        "{} is missing: `cargo test` builds the examples (or `cargo build --example controller`)",
        rust_example.display()
    );
    // Linked against the shared library, and against the static one with the system
    // libraries docs/embedding.md lists.
    let exe = dir.join("controller");
    let exe_static = dir.join("controller-static");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let compile = |out: &Path, link: &[String]| {
        let mut compiled = Command::new(&cc);
        compiled
            .args([
                "-std=c99",
                "-Wall",
                "-Wextra",
                "-Werror",
                "-ffp-contract=off",
                "-I",
            ])
            .arg(root().join("include"))
            .arg(root().join("examples/c/controller.c"))
            .args(link)
            .arg("-o")
            .arg(out);
        succeeded(
            &mut compiled,
            &format!("compiling examples/c/controller.c with {cc} and {link:?}"),
        );
    };
    compile(
        &exe,
        &[
            format!("-L{}", lib_dir.display()),
            "-liastgcn".into(),
            format!("-Wl,-rpath,{}", lib_dir.display()),
            "-lm".into(),
        ],
    );
    let mut static_link = vec![lib_dir.join("libiastgcn.a").display().to_string()];
    static_link.extend(STATIC_LIBS.split(' ').map(String::from));
    compile(&exe_static, &static_link);
    let run = |program: &Path| {
        // cargo's LD_LIBRARY_PATH would outrank the rpath: the library must be this run's.
        let o = Command::new(program)
            .env_remove("LD_LIBRARY_PATH")
            .arg(&model)
            .arg("70")
            .output()
            .unwrap_or_else(|e| panic!("{}: {e}", program.display()));
        assert!(
            o.status.success(),
            "{} failed:\n{}",
            program.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8(o.stdout).unwrap()
    };
    let rust = run(&rust_example);
    let c = run(&exe);
    // Demo shape: T = 48, so ticks 47..69 predict.
    assert_eq!(rust.lines().count(), 1 + 23, "{rust}");
    assert_eq!(c, rust, "the C example's residuals differ from Rust's");
    assert_eq!(run(&exe_static), rust, "statically linked, they differ");
    std::fs::remove_dir_all(&dir).ok();
}

fn last_error() -> String {
    // SAFETY: the library returns a NUL-terminated string valid until the next failure.
    unsafe { CStr::from_ptr(iastgcn_last_error()) }
        .to_string_lossy()
        .into_owned()
}

fn load(path: &Path, dt: f64) -> (IastgcnStatus, *mut IastgcnPredictor) {
    let path = CString::new(path.to_str().unwrap()).unwrap();
    let mut p = std::ptr::null_mut();
    // SAFETY: a valid string and out pointer.
    let s = unsafe { iastgcn_predictor_load(path.as_ptr(), dt, IastgcnBackend::Native, &mut p) };
    (s, p)
}

#[test]
fn bad_input_is_refused_with_a_status_and_a_message() {
    let dir = scratch("errors");
    // A missing file: an engine error naming it, and no handle.
    let (s, p) = load(&dir.join("missing.safetensors"), 0.02);
    assert_eq!(s, IastgcnStatus::Error);
    assert!(p.is_null());
    assert!(
        last_error().contains("missing.safetensors"),
        "{}",
        last_error()
    );
    // NULL arguments.
    let mut out = std::ptr::null_mut();
    // SAFETY: NULL is what is being tested; the out pointer is valid.
    let s =
        unsafe { iastgcn_predictor_load(std::ptr::null(), 0.02, IastgcnBackend::Native, &mut out) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(last_error().contains("path is NULL"));
    let model = checkpoint(&dir);
    let (s, _) = load(&model, -1.0);
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(last_error().contains("dt"), "{}", last_error());

    let (s, p) = load(&model, 0.02);
    assert_eq!(s, IastgcnStatus::Ok, "{}", last_error());
    let (mut n, mut f, mut t) = (0usize, 0usize, 0usize);
    // SAFETY: a live handle and writable outputs.
    unsafe { iastgcn_predictor_shape(p, &mut n, &mut f, &mut t) };
    assert_eq!((n, f, t), (17, 3, 48));
    let mut ahead = usize::MAX;
    // SAFETY: a live handle and a writable output.
    let s = unsafe { iastgcn_predictor_look_ahead(p, &mut ahead) };
    assert_eq!((s, ahead), (IastgcnStatus::Ok, 1));
    // SAFETY: a live handle; the NULL output is what is tested.
    let s = unsafe { iastgcn_predictor_look_ahead(p, std::ptr::null_mut()) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    // SAFETY: a live handle.
    let name = unsafe { CStr::from_ptr(iastgcn_predictor_node_name(p, 0)) };
    assert_eq!(name.to_str().unwrap(), "E1");
    // SAFETY: a live handle; an index out of range is what is tested.
    assert!(unsafe { iastgcn_predictor_node_name(p, 17) }.is_null());
    let mut r = [0.0f64; 6];
    // Nothing pushed yet: not ready, and `r` untouched.
    // SAFETY: a live handle and 6 doubles.
    let s = unsafe { iastgcn_predictor_predict_latest(p, r.as_mut_ptr()) };
    assert_eq!(s, IastgcnStatus::NotReady);
    // A frame of the wrong length names both lengths.
    let frame = [1.0f64; 13];
    // SAFETY: a live handle and 13 doubles.
    let s = unsafe { iastgcn_predictor_push(p, frame.as_ptr(), frame.len()) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(
        last_error().contains("17") && last_error().contains("13"),
        "{}",
        last_error()
    );
    // SAFETY: NULL frame is what is tested.
    let s = unsafe { iastgcn_predictor_push(p, std::ptr::null(), 17) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    // A window of the wrong length.
    let window = [0.0f32; 10];
    // SAFETY: a live handle, 10 floats and 6 doubles.
    let s = unsafe { iastgcn_predictor_predict(p, window.as_ptr(), 10, r.as_mut_ptr()) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(last_error().contains("2448"), "{}", last_error());
    // A batch whose output is too short.
    let windows = vec![0.0f32; 2 * 17 * 3 * 48];
    // SAFETY: a live handle, the floats and 6 doubles (fewer than needed: tested).
    let s = unsafe {
        iastgcn_predictor_predict_batch(p, windows.as_ptr(), windows.len(), r.as_mut_ptr(), 6)
    };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(last_error().contains("12 doubles"), "{}", last_error());
    // SAFETY: a live handle, freed once.
    unsafe { iastgcn_predictor_free(p) };

    // Loaded without dt: features only.
    let (s, p) = load(&model, 0.0);
    assert_eq!(s, IastgcnStatus::Ok);
    let frame = [1.0f64; 17];
    // SAFETY: a live handle and 17 doubles.
    let s = unsafe { iastgcn_predictor_push(p, frame.as_ptr(), 17) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(
        last_error().contains("without a control period"),
        "{}",
        last_error()
    );
    // SAFETY: a live handle, freed once; then NULL, which is ignored.
    unsafe {
        iastgcn_predictor_free(p);
        iastgcn_predictor_free(std::ptr::null_mut());
    }
    // SAFETY: NULL handles are refused, not dereferenced.
    unsafe {
        assert_eq!(
            iastgcn_predictor_reset(std::ptr::null_mut()),
            IastgcnStatus::InvalidArgument
        );
        assert_eq!(iastgcn_predictor_is_native(std::ptr::null_mut()), -1);
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Features pushed through the C ABI and whole windows give the Rust predictor's
/// residuals, and batches agree with single windows.
#[test]
fn feature_windows_and_batches_match_the_rust_predictor() {
    use iastgcn::model::{Checkpoint, Features, Predictor};
    let dir = scratch("windows");
    let model = checkpoint(&dir);
    let ck = Checkpoint::load(&model).unwrap();
    let mut rust = Predictor::native(&ck).unwrap();
    let len = rust.window_len();
    let windows: Vec<f32> = (0..3 * len)
        .map(|i| ((i * 37) % 101) as f32 / 50.0 - 1.0)
        .collect();
    let mut expected = Vec::new();
    rust.predict_batch(&windows, Features::Raw, &mut expected)
        .unwrap();

    let (s, p) = load(&model, 0.0);
    assert_eq!(s, IastgcnStatus::Ok);
    let mut out = vec![0.0f64; 18];
    // SAFETY: a live handle, 3 windows and 18 doubles.
    let s = unsafe {
        iastgcn_predictor_predict_batch(p, windows.as_ptr(), windows.len(), out.as_mut_ptr(), 18)
    };
    assert_eq!(s, IastgcnStatus::Ok, "{}", last_error());
    let flat: Vec<f64> = expected.iter().flatten().copied().collect();
    assert_eq!(out, flat);
    let mut one = [0.0f64; 6];
    // SAFETY: a live handle, one window and 6 doubles.
    let s = unsafe { iastgcn_predictor_predict(p, windows[len..].as_ptr(), len, one.as_mut_ptr()) };
    assert_eq!(s, IastgcnStatus::Ok);
    assert_eq!(one, expected[1]);
    // SAFETY: a live handle, freed once.
    unsafe { iastgcn_predictor_free(p) };
    std::fs::remove_dir_all(&dir).ok();
}

/// Sensor frame `k` of 17 values, varied over nodes and ticks.
fn frame(k: usize) -> [f64; 17] {
    std::array::from_fn(|n| 20.0 + n as f64 + 0.3 * ((k * (n + 1)) as f64 * 0.07).sin())
}

/// An ensemble file loaded through the C ABI averages its members as the Rust ensemble
/// does, bit for bit, and carries the calibrated interval: the scale times the members'
/// spread; window calls, a handle without dt and an interval of a plain checkpoint are
/// refused with a message.
#[test]
fn ensemble_files_average_their_members_and_carry_the_interval() {
    use iastgcn::compensate::{ensemble, Ensemble, IntervalCalibration, Radius, SensorPredictor};
    use iastgcn::model::Checkpoint;
    let dir = scratch("ensemble");
    let members: Vec<PathBuf> = [5, 6, 7]
        .iter()
        .map(|&seed| seeded_checkpoint(&dir, &format!("m.seed{seed}"), seed))
        .collect();
    // Position spread-scaled, attitude both.
    let scale = IntervalCalibration {
        level: 0.9,
        position: Radius {
            scale: 2.5,
            constant: 0.0,
        },
        attitude: Radius {
            scale: 4.0,
            constant: 1.5,
        },
    };
    let file = iastgcn::compensate::EnsembleFile {
        members: vec![
            "m.seed5.safetensors".into(),
            "m.seed6.safetensors".into(),
            dir.join("m.seed7.safetensors"),
        ],
        calibrated_on: "a test".into(),
        interval: Some(scale),
    };
    let path = dir.join("m.ensemble.toml");
    file.write(&path).unwrap();
    assert_eq!(
        iastgcn::compensate::EnsembleFile::read(&path).unwrap(),
        file
    );

    let mut rust = Ensemble::new(
        members
            .iter()
            .map(|m| SensorPredictor::native(&Checkpoint::load(m).unwrap(), 0.02).unwrap())
            .collect(),
        Some(scale),
    )
    .unwrap();
    let (s, p) = load(&path, 0.02);
    assert_eq!(s, IastgcnStatus::Ok, "{}", last_error());
    let mut n = 0usize;
    // SAFETY: a live handle and a writable output.
    assert_eq!(
        unsafe { iastgcn_predictor_members(p, &mut n) },
        IastgcnStatus::Ok
    );
    assert_eq!(n, 3);
    let (mut pos, mut att, mut level) = (-1.0f64, -1.0f64, -1.0f64);
    // SAFETY: a live handle and writable outputs.
    let s = unsafe { iastgcn_predictor_interval(p, &mut pos, &mut att, &mut level) };
    assert_eq!(s, IastgcnStatus::NotReady, "no prediction yet");
    assert_eq!((pos, att, level), (-1.0, -1.0, -1.0), "nothing written");
    let mut r = [0.0f64; 6];
    let mut predicted = 0;
    for k in 0..60 {
        let f = frame(k);
        let full = rust.push(&f).unwrap();
        // SAFETY: a live handle and 17 doubles.
        assert_eq!(
            unsafe { iastgcn_predictor_push(p, f.as_ptr(), 17) },
            IastgcnStatus::Ok
        );
        // SAFETY: a live handle and 6 doubles.
        let s = unsafe { iastgcn_predictor_predict_latest(p, r.as_mut_ptr()) };
        if !full {
            assert_eq!(s, IastgcnStatus::NotReady);
            continue;
        }
        assert_eq!(s, IastgcnStatus::Ok);
        let mean = rust.predict_latest().unwrap().unwrap();
        assert_eq!(r, mean, "tick {k}");
        // SAFETY: a live handle and writable outputs.
        let s = unsafe { iastgcn_predictor_interval(p, &mut pos, &mut att, &mut level) };
        assert_eq!(s, IastgcnStatus::Ok);
        let interval = rust.interval().unwrap();
        assert_eq!(
            (pos, att, level),
            (interval.position_um, interval.attitude_mdeg, 0.9)
        );
        predicted += 1;
    }
    assert_eq!(predicted, 60 - 47);
    // The mean and the interval are the members' own: predict each alone.
    let mut alone: Vec<[f64; 6]> = Vec::new();
    for m in &members {
        let mut one = SensorPredictor::native(&Checkpoint::load(m).unwrap(), 0.02).unwrap();
        for k in 0..60 {
            one.push(&frame(k)).unwrap();
        }
        alone.push(one.predict_latest().unwrap().unwrap());
    }
    for (c, v) in r.iter().enumerate() {
        let mean = alone.iter().map(|a| a[c]).sum::<f64>() / 3.0;
        assert!(
            (v - mean).abs() <= 1e-12 * mean.abs().max(1.0),
            "{v} against {mean}"
        );
    }
    let spread = ensemble::spread(&alone);
    assert!(
        spread[0] > 0.0 && spread[1] > 0.0,
        "different seeds disagree"
    );
    assert!(
        (pos - 2.5 * spread[0]).abs() < 1e-9 * pos
            && (att - 4.0 * spread[1] - 1.5).abs() < 1e-9 * att
    );

    // Windows go to one checkpoint; the ensemble refuses them.
    let window = vec![0.0f32; 17 * 3 * 48];
    // SAFETY: a live handle, a window and 6 doubles.
    let s = unsafe { iastgcn_predictor_predict(p, window.as_ptr(), window.len(), r.as_mut_ptr()) };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(last_error().contains("ensemble"), "{}", last_error());
    // SAFETY: a live handle, freed once.
    unsafe { iastgcn_predictor_free(p) };
    // An ensemble file takes sensor values: dt is needed.
    let (s, p) = load(&path, 0.0);
    assert_eq!((s, p.is_null()), (IastgcnStatus::Error, true));
    assert!(last_error().contains("dt"), "{}", last_error());
    // A plain checkpoint has no interval.
    let (s, p) = load(&members[0], 0.02);
    assert_eq!(s, IastgcnStatus::Ok);
    // SAFETY: a live handle; NULL outputs are allowed.
    let s = unsafe {
        iastgcn_predictor_interval(
            p,
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
        )
    };
    assert_eq!(s, IastgcnStatus::InvalidArgument);
    assert!(last_error().contains("ensemble file"), "{}", last_error());
    // SAFETY: a live handle and a writable output; freed once.
    unsafe {
        assert_eq!(iastgcn_predictor_members(p, &mut n), IastgcnStatus::Ok);
        iastgcn_predictor_free(p);
    }
    assert_eq!(n, 1);
    // A member that is not there is named.
    std::fs::remove_file(&members[1]).unwrap();
    let (s, _) = load(&path, 0.02);
    assert_eq!(s, IastgcnStatus::Error);
    assert!(
        last_error().contains("m.seed6.safetensors"),
        "{}",
        last_error()
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn version_is_the_crates() {
    // SAFETY: a static NUL-terminated string.
    let v = unsafe { CStr::from_ptr(iastgcn_version() as *const c_char) };
    assert_eq!(v.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
}
