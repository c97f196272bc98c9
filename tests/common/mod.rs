//! Shared fixture of the training tests: a short twin session written by the CLI (a
//! calibration measurement set, its EKF calibration and short polishing recordings).

// Each test binary uses only some of these helpers.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// Runs the `iastgcn` binary with `args` and the environment variables `env` added.
pub fn run(args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(args)
        .envs(env.iter().copied())
        .output()
        .unwrap()
}

/// Runs the `iastgcn` binary with `args`; panics with its stderr on failure; returns stdout.
pub fn cli(args: &[&str]) -> String {
    let o = run(args, &[]);
    assert!(
        o.status.success(),
        "iastgcn {args:?} failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Environment that hides every Vulkan driver from the loader (a machine with no GPU
/// driver: no adapter at all, not even lavapipe): the loader reads its drivers from these
/// files only, and they do not exist.
pub const NO_DRIVER: [(&str, &str); 2] = [
    ("VK_DRIVER_FILES", "/nonexistent/no-driver.json"),
    ("VK_ICD_FILENAMES", "/nonexistent/no-driver.json"),
];

/// Runs the binary with no GPU driver ([`NO_DRIVER`]), expecting success; returns stdout
/// and stderr.
pub fn cli_without_gpu(args: &[&str]) -> (String, String) {
    let o = run(args, &NO_DRIVER);
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(
        o.status.success(),
        "iastgcn {args:?} without a GPU driver failed:\n{stderr}"
    );
    (String::from_utf8_lossy(&o.stdout).into_owned(), stderr)
}

/// The line a command with a native path prints once when there is no adapter.
pub const NATIVE_NOTE: &str =
    "no GPU adapter found (Vulkan, Metal or DX12): running on the native CPU path";

/// Runs the binary expecting failure; returns stderr.
pub fn cli_fails(args: &[&str]) -> String {
    let o = run(args, &[]);
    assert!(!o.status.success(), "iastgcn {args:?} succeeded");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A calibration measurement set of the twin at `out`: `poses` static poses measured
/// with `seed`, and any further `simulate` flags (`--machine-seed`, …).
pub fn calibration_set(out: &Path, poses: usize, seed: u64, extra: &[&str]) {
    let (poses, seed) = (poses.to_string(), seed.to_string());
    let mut args = vec!["simulate", "--trajectory", "calibration"];
    args.extend(["--poses", &poses, "--seed", &seed]);
    args.extend(extra);
    args.extend(["--out", out.to_str().unwrap()]);
    cli(&args);
}

/// In `dir` (created if missing): `set.csv`, 60 calibration poses measured with `seed`,
/// and `cal.toml`, their EKF calibration. Returns the calibration's path.
pub fn calibration(dir: &Path, seed: u64) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let (set, cal) = (p("set.csv"), p("cal.toml"));
    calibration_set(Path::new(&set), 60, seed, &[]);
    cli(&["calibrate", "--measurements", &set, "--out", &cal]);
    PathBuf::from(cal)
}

/// In `dir`: `cal.toml` (EKF on 60 simulated poses) and `<path>.csv` recordings of
/// `seconds` each (seeds 5, 6, …). Returns (calibration, recordings).
pub fn twin_session(dir: &Path, paths: &[&str], seconds: f64) -> (PathBuf, Vec<PathBuf>) {
    let cal = calibration(dir, 7);
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let minutes = format!("{}", seconds / 60.0);
    let recordings = paths
        .iter()
        .enumerate()
        .map(|(i, path)| {
            let out = p(&format!("{path}.csv"));
            let seed = format!("{}", 5 + i);
            cli(&[
                "simulate",
                "--trajectory",
                path,
                "--minutes",
                &minutes,
                "--seed",
                &seed,
                "--out",
                &out,
            ]);
            PathBuf::from(out)
        })
        .collect();
    (cal, recordings)
}

/// The f64 reference of a recurrent baseline, as its tests check it: the gradients it
/// computed by hand (every parameter tensor, in spec order, and x) against central
/// differences (step 1e-6) of `eval(params, x)`, the loss. Each tensor must matter, and
/// so must every one of the `window` steps of x `[…, T]`.
pub fn check_reference_gradients(
    specs: &[iastgcn::model::ParamSpec],
    (params, x): (&[Vec<f64>], &[f64]),
    (grads, dx): (&[Vec<f64>], &[f64]),
    window: usize,
    eval: impl Fn(&[Vec<f64>], &[f64]) -> f64,
) {
    use iastgcn::testing::{check_gradient, Tolerance};
    const H: f64 = 1e-6;
    let tol = Tolerance::new(1e-7, 1e-5);
    for (t, spec) in specs.iter().enumerate() {
        let of_tensor = |v: &[f64]| {
            let mut q = params.to_vec();
            q[t] = v.to_vec();
            eval(&q, x)
        };
        check_gradient(
            &format!("d{}", spec.name),
            &grads[t],
            of_tensor,
            &params[t],
            H,
            tol,
        )
        .unwrap();
        assert!(
            grads[t].iter().any(|v| v.abs() > 1e-9),
            "{} has no effect",
            spec.name
        );
    }
    check_gradient("dx", dx, |v| eval(params, v), x, H, tol).unwrap();
    for t in 0..window {
        let rows = dx.len() / window;
        assert!(
            (0..rows).any(|r| dx[r * window + t] != 0.0),
            "step {t} of x has no effect"
        );
    }
}

/// What the f64 reference computed for one batch: ŷ, the loss (without weight decay), the
/// parameter gradients and ∂ℒ/∂x.
pub struct Reference<'a> {
    pub output: &'a [f64],
    pub loss: f64,
    pub grads: &'a [Vec<f64>],
    pub dx: &'a [f64],
}

/// Compares the network's last `gradients` pass (ŷ, loss, every parameter gradient, ∂ℒ/∂x)
/// and its inference on `x` with the reference, each to a tolerance relative to the
/// largest reference value.
pub fn compare_network(
    g: &iastgcn::gpu::Gpu,
    net: &iastgcn::model::Network,
    x: &[f64],
    want: Reference,
) {
    use iastgcn::testing::{compare, to_f32, Tolerance};
    let f64s = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
    let scaled = |v: &[f64], rel: f64| {
        Tolerance::new(rel * v.iter().fold(1e-30f64, |m, x| m.max(x.abs())), rel)
    };
    let n = want.output.len();
    let out = f64s(&g.read_f32(&net.output).unwrap()[..n]);
    compare("y_hat", &out, want.output, scaled(want.output, 1e-5)).unwrap();
    let loss = g.read_f32(&net.loss).unwrap()[0] as f64;
    compare("loss", &[loss], &[want.loss], Tolerance::new(0.0, 1e-5)).unwrap();
    let grads = net.read_gradients(g).unwrap();
    for ((spec, got), w) in net.specs.iter().zip(&grads).zip(want.grads) {
        compare(&format!("d{}", spec.name), &f64s(got), w, scaled(w, 1e-4)).unwrap();
    }
    let dx = f64s(&g.read_f32(&net.input_grad).unwrap()[..want.dx.len()]);
    compare("dx", &dx, want.dx, scaled(want.dx, 1e-4)).unwrap();
    let inferred = f64s(&net.predict(g, &to_f32(x)).unwrap());
    compare(
        "inference",
        &inferred,
        want.output,
        scaled(want.output, 1e-5),
    )
    .unwrap();
}

/// He-initialised parameters with biases, be/bs, θ and ln.* moved off their initial
/// values (so their gradients are generic), rounded to f32.
pub fn parameters(config: &iastgcn::model::ModelConfig, seed: u64) -> iastgcn::model::Parameters {
    use iastgcn::model::{Init, Parameters};
    use iastgcn::testing::{rng, to_f32, uniform};
    let mut p = Parameters::init(config, seed);
    let mut r = rng(seed + 1);
    for (s, v) in p.specs.iter().zip(p.values.iter_mut()) {
        let (lo, hi) = match s.init {
            Init::HeUniform { .. } => continue,
            Init::Zeros => (-0.3, 0.3),
            Init::Ones => (0.7, 1.3),
        };
        *v = to_f32(&uniform(&mut r, v.len(), lo, hi));
    }
    p
}

/// The UR5 of `assets/arms/ur5.toml`.
pub fn ur5() -> iastgcn::robot::arm::Arm {
    iastgcn::robot::arm::Arm::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/arms/ur5.toml"),
    )
    .unwrap()
}

/// A serial twin with geometric errors only (no compliance, backlash or expansion) and a
/// 6-D tracker of 15 µm and 0.002° noise: what a placement fit should recover to the noise.
pub fn geometric_twin_config() -> iastgcn::twin::arm::ArmTwinConfig {
    iastgcn::twin::arm::ArmTwinConfig {
        compliance_rad_per_nm: 0.0,
        backlash: 0.0,
        expansion_per_k: 0.0,
        tracker_sd_mm: 0.015,
        orientation_sd_deg: Some(0.002),
        thermometer_sd_k: 0.0,
        ..iastgcn::twin::arm::ArmTwinConfig::default()
    }
}
