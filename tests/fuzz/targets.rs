//! Coverage-guided fuzz targets for every reader of user files and the C ABI (issue 54;
//! `make fuzz`, docs/robustness.md "Fuzzing"). Built with afl.rs on stable Rust
//! (`cargo afl build --release --features fuzz --bin fuzz-targets`), run by `afl-fuzz`:
//!
//! ```text
//! fuzz-targets seeds DIR     # writes valid inputs for every target, DIR/<target>/…
//! fuzz-targets <target>      # one AFL run: the input on stdin
//! fuzz-targets list          # the targets' names
//! ```
//!
//! A crash is a panic (afl.rs aborts on one), a hang, or a broken promise the target
//! checks: a reader that accepts its input returns finite numbers, and the C ABI never
//! answers `IASTGCN_STATUS_PANIC`. Each crash found becomes a regression test in
//! tests/fuzz_readers.rs or tests/c_abi.rs.

use std::ffi::CString;
use std::path::{Path, PathBuf};

use iastgcn::calibrate::{calibrate, file as calibration_file, EkfConfig};
use iastgcn::data::arm_import::{parse_export, Difference, PoseColumns};
use iastgcn::data::arm_poses::{parse_arm_poses, parse_arm_targets};
use iastgcn::data::recording::parse_calibration_set;
use iastgcn::data::{read_measurements, record_calibration_set, record_run, Recording};
use iastgcn::embed::c_api::*;
use iastgcn::graph::Graph;
use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters};
use iastgcn::progress::Silent;
use iastgcn::robot::arm::Arm;
use iastgcn::robot::{Description, Geometry, Robot};
use iastgcn::train::{RunConfig, TrainState};
use iastgcn::twin::{draw_machine, PathKind, PathParams, RunInfo};

/// One target: the input's bytes in, a panic out when a promise breaks.
type Target = fn(&[u8]);

/// The targets, by name.
const TARGETS: &[(&str, Target)] = &[
    ("recording", recording),
    ("calibration_set", calibration_set),
    ("measurements", measurements),
    ("arm_poses", arm_poses),
    ("arm_targets", arm_targets),
    ("import", import),
    ("run_config", run_config),
    ("description", description),
    ("arm", arm),
    ("geometry", geometry),
    ("graph", graph),
    ("calibration", calibration),
    ("sidecar", sidecar),
    ("checkpoint", checkpoint),
    ("state", state),
    ("tensor", tensor),
    ("c_api", c_api),
];

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let usage = || -> ! {
        eprintln!("usage: fuzz-targets seeds DIR | list | <target>");
        std::process::exit(2)
    };
    match args.get(1).map(String::as_str) {
        Some("seeds") => write_seeds(Path::new(args.get(2).unwrap_or_else(|| usage()))),
        Some("list") => TARGETS.iter().for_each(|(name, _)| println!("{name}")),
        Some(name) => {
            let Some(&(_, run)) = TARGETS.iter().find(|(n, _)| *n == name) else {
                usage()
            };
            afl::fuzz!(|data: &[u8]| run(data));
        }
        None => usage(),
    }
}

/// The input as text, or `None` (the text readers take `&str`; a file that is not UTF-8
/// is refused before them, which the property tests cover).
fn text(data: &[u8]) -> Option<&str> {
    std::str::from_utf8(data).ok()
}

/// A scratch file of this process holding `data` (the readers that take a path).
fn scratch(name: &str, data: &[u8]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("iastgcn-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("the temporary folder");
    let path = dir.join(name);
    std::fs::write(&path, data).expect("the scratch file");
    path
}

fn finite(values: impl IntoIterator<Item = f64>) -> bool {
    values.into_iter().all(f64::is_finite)
}

fn recording(data: &[u8]) {
    let Some(text) = text(data) else { return };
    let graph = Graph::default_asset();
    let channels: Vec<&str> = graph.nodes.iter().map(String::as_str).collect();
    if let Ok(r) = Recording::parse(text, "run.csv", &channels, 1) {
        let csv = r.to_csv();
        assert!(
            !csv.contains("NaN") && !csv.contains("inf"),
            "accepted: {csv}"
        );
    }
}

fn calibration_set(data: &[u8]) {
    let Some(text) = text(data) else { return };
    if let Ok(rows) = parse_calibration_set(text, "set.csv") {
        assert!(rows
            .iter()
            .all(|r| finite(r.joints.iter().chain(&r.pose).copied())));
    }
}

fn measurements(data: &[u8]) {
    let path = scratch("measurements.csv", data);
    if let Ok(m) = read_measurements(&path) {
        assert!(m.iter().all(|m| finite(
            m.joints
                .limbs
                .iter()
                .chain(&m.joints.head)
                .copied()
                .chain(m.pose.translation.vector.iter().copied())
                .chain(m.pose.rotation.coords.iter().copied())
        )));
    }
}

fn arm_poses(data: &[u8]) {
    let Some(text) = text(data) else { return };
    if let Ok(p) = parse_arm_poses(text, "poses.csv", 6) {
        assert!(p
            .poses
            .iter()
            .all(|q| finite(q.joints.iter().chain(q.position.coords.iter()).copied())));
    }
}

/// A serial arm's target list (`evaluate --robot arm.toml --targets`), for models
/// trained with one channel.
fn arm_targets(data: &[u8]) {
    let Some(text) = text(data) else { return };
    if let Ok(t) = parse_arm_targets(text, "targets.csv", &["temp_c".into()]) {
        assert!(t.targets.iter().all(|(stamp, p, ch)| finite(
            std::iter::once(*stamp)
                .chain(p.coords.iter().copied())
                .chain(ch.iter().copied())
        )));
    }
}

/// The columns of the real UR5 export (assets/real-arms).
fn ur5_columns() -> PoseColumns {
    PoseColumns {
        stamp: Some("step_order".into()),
        joints: (1..=6).map(|j| format!("joint_{j}")).collect(),
        position: ["x_t", "y_t", "z_t"].map(String::from),
        difference: Some(["x_dif", "y_dif", "z_dif"].map(String::from)),
        sign: Difference::Minus,
        joint_scale: 1.0,
        length_scale: 1.0,
        channels: Vec::new(),
        ..PoseColumns::default()
    }
}

fn import(data: &[u8]) {
    let Some(text) = text(data) else { return };
    if let Ok(p) = parse_export(text, "export.csv", &ur5_columns()) {
        assert!(p
            .poses
            .iter()
            .all(|q| finite(q.joints.iter().chain(q.position.coords.iter()).copied())));
    }
}

fn run_config(data: &[u8]) {
    let Some(text) = text(data) else { return };
    if let Ok(c) = RunConfig::parse(text, "run.toml") {
        c.validate().ok();
    }
}

fn description(data: &[u8]) {
    let Some(text) = text(data) else { return };
    Description::parse(text, "robot.toml").ok();
}

fn arm(data: &[u8]) {
    let Some(text) = text(data) else { return };
    Arm::parse(text, "arm.toml").ok();
}

fn geometry(data: &[u8]) {
    let Some(text) = text(data) else { return };
    Geometry::parse(text, "robot.toml").ok();
}

fn graph(data: &[u8]) {
    let Some(text) = text(data) else { return };
    Graph::parse(text, "graph.toml").ok();
}

fn calibration(data: &[u8]) {
    let path = scratch("calibration.toml", data);
    calibration_file::load(&path).ok();
}

/// A simulated recording's `.run.toml` sidecar, read through the recording's path.
fn sidecar(data: &[u8]) {
    let toml = scratch("run.run.toml", data);
    if let Ok(i) = RunInfo::read(&toml.with_file_name("run.csv")) {
        let [a, b, c] = i.screw_rise_k;
        assert!(finite([
            i.rotation_deg,
            i.seconds,
            i.session_clock_s,
            a,
            b,
            c,
            i.feed_mm_s,
            i.force_n,
            i.ambient_offset_k,
            i.ambient_phase_shift
        ]));
        assert!(i.seconds >= 0.0 && i.session_clock_s >= 0.0);
    }
}

fn checkpoint(data: &[u8]) {
    if let Ok(ck) = Checkpoint::from_bytes(data, "model.safetensors") {
        assert!(ck.parameters.values.iter().flatten().all(|v| v.is_finite()));
    }
}

fn state(data: &[u8]) {
    let path = scratch("state.safetensors", data);
    TrainState::load(&path).ok();
}

fn tensor(data: &[u8]) {
    let path = scratch("x.safetensors", data);
    if let Ok((shape, values)) = iastgcn::interop::read_tensor(&path, "x") {
        assert_eq!(shape.iter().product::<usize>(), values.len());
    }
}

/// A native predictor of the demo's shape, loaded once per process.
fn predictor() -> *mut IastgcnPredictor {
    static HANDLE: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *HANDLE.get_or_init(|| {
        let path = std::env::temp_dir().join(format!("iastgcn-fuzz-{}.ck", std::process::id()));
        demo_checkpoint()
            .save(&path)
            .expect("the predictor's checkpoint");
        let c = CString::new(path.to_str().expect("a UTF-8 path")).expect("no NUL");
        let mut p = std::ptr::null_mut();
        // SAFETY: a NUL-terminated path and a writable handle pointer.
        let status =
            unsafe { iastgcn_predictor_load(c.as_ptr(), 0.02, IastgcnBackend::Native, &mut p) };
        assert_eq!(status, IastgcnStatus::Ok);
        p as usize
    }) as *mut IastgcnPredictor
}

fn demo_checkpoint() -> Checkpoint {
    let config = ModelConfig {
        window: 16,
        ..RunConfig::demo().model
    };
    Checkpoint {
        parameters: Parameters::init(&config, 3),
        graph: Graph::default_asset(),
        normalization: Normalization::identity(&config),
        config,
    }
}

/// The C ABI driven by the input: each byte picks a call, and the bytes after it its
/// arguments (lengths that differ from the model's, NaN and infinite values, NULL
/// buffers, paths that are not files). Every call keeps the ABI's own safety contract
/// (a buffer is as long as the length passed); the promise checked is that no call
/// answers `IASTGCN_STATUS_PANIC` or leaves a non-finite residual.
fn c_api(data: &[u8]) {
    let p = predictor();
    let mut at = 0;
    let mut next = |n: usize| {
        let s = &data[at.min(data.len())..(at + n).min(data.len())];
        at += n;
        s
    };
    let number = |b: &[u8]| -> f64 {
        let mut x = [0u8; 8];
        x[..b.len()].copy_from_slice(b);
        f64::from_le_bytes(x)
    };
    let mut out = [0f64; 6];
    let check = |status: IastgcnStatus| assert_ne!(status, IastgcnStatus::Panic);
    loop {
        let op = next(1);
        let Some(&op) = op.first() else { break };
        let len = next(1).first().map_or(0, |&b| b as usize);
        // SAFETY: every buffer below holds at least the length passed with it.
        unsafe {
            match op % 9 {
                0 => {
                    let frame: Vec<f64> = (0..len).map(|_| number(next(8))).collect();
                    check(iastgcn_predictor_push(p, frame.as_ptr(), frame.len()));
                }
                1 => {
                    let step: Vec<f32> = (0..len * 3).map(|_| number(next(8)) as f32).collect();
                    check(iastgcn_predictor_push_features(
                        p,
                        step.as_ptr(),
                        step.len(),
                    ));
                }
                2 => {
                    let s = iastgcn_predictor_predict_latest(p, out.as_mut_ptr());
                    check(s);
                    if s == IastgcnStatus::Ok {
                        assert!(finite(out), "{out:?}");
                    }
                }
                3 => {
                    let w: Vec<f32> = (0..len * 16).map(|i| (i as f32 * 0.1).sin()).collect();
                    check(iastgcn_predictor_predict(
                        p,
                        w.as_ptr(),
                        w.len(),
                        out.as_mut_ptr(),
                    ));
                }
                4 => {
                    let w: Vec<f32> = (0..len * 64).map(|i| (i as f32 * 0.3).cos()).collect();
                    let mut o = vec![0f64; next(1).first().map_or(0, |&b| b as usize)];
                    check(iastgcn_predictor_predict_batch(
                        p,
                        w.as_ptr(),
                        w.len(),
                        o.as_mut_ptr(),
                        o.len(),
                    ));
                }
                5 => check(iastgcn_predictor_reset(p)),
                6 => check(iastgcn_predictor_set_threads(p, len % 5)),
                7 => {
                    iastgcn_predictor_node_name(p, len);
                    check(iastgcn_predictor_shape(
                        p,
                        std::ptr::null_mut(),
                        std::ptr::null_mut(),
                        std::ptr::null_mut(),
                    ));
                    check(iastgcn_predictor_predict_latest(p, std::ptr::null_mut()));
                    check(iastgcn_predictor_push(
                        std::ptr::null_mut(),
                        std::ptr::null(),
                        0,
                    ));
                }
                _ => {
                    let bytes: Vec<u8> = next(len).iter().copied().filter(|&b| b != 0).collect();
                    let path = CString::new(bytes).expect("no NUL left");
                    let mut q = std::ptr::null_mut();
                    let dt = number(next(8));
                    let s =
                        iastgcn_predictor_load(path.as_ptr(), dt, IastgcnBackend::Native, &mut q);
                    check(s);
                    iastgcn_predictor_free(q);
                }
            }
        }
    }
}

/// Valid inputs for every target under `dir/<target>/`: the embedded assets, files the
/// engine's own writers write (a short twin run, a calibration set and its calibration, a
/// checkpoint, a training state's tensors, a tensor file), the head of the real UR5 export,
/// and a few call sequences for the C ABI.
fn write_seeds(dir: &Path) {
    let put = |target: &str, name: &str, bytes: &[u8]| {
        let d = dir.join(target);
        std::fs::create_dir_all(&d).expect("the seed folder");
        std::fs::write(d.join(name), bytes).expect("a seed");
    };
    let work = dir.join(".work");
    std::fs::create_dir_all(&work).expect("the work folder");
    let machine = draw_machine(Geometry::default_asset(), 1);
    let nominal = Robot::nominal(Geometry::default_asset());
    let set = work.join("set.csv");
    let info = RunInfo::calibration(101);
    record_calibration_set(&machine, &nominal, 20, &info, &set, &mut Silent).expect("a set");
    let set_bytes = std::fs::read(&set).expect("the set");
    put("calibration_set", "set.csv", &set_bytes);
    put("measurements", "set.csv", &set_bytes);
    let measured = read_measurements(&set).expect("the set reads back");
    let cal = calibrate(&nominal, &measured, &EkfConfig::default()).expect("a calibration");
    let cal_path = work.join("cal.toml");
    calibration_file::save(&cal_path, &cal, measured.len()).expect("the calibration");
    put(
        "calibration",
        "cal.toml",
        &std::fs::read(&cal_path).expect("it"),
    );
    let run = work.join("grid.csv");
    let info = RunInfo::polishing(PathKind::Grid, &PathParams::default(), 0.4, 201);
    record_run(
        &machine,
        &nominal,
        info,
        machine.cold(),
        &run,
        None,
        &mut Silent,
    )
    .expect("a run");
    put(
        "recording",
        "grid.csv",
        &std::fs::read(&run).expect("the run"),
    );
    put(
        "sidecar",
        "grid.run.toml",
        &std::fs::read(RunInfo::sidecar(&run)).expect("the run's sidecar"),
    );
    let ck = work.join("model.safetensors");
    demo_checkpoint().save(&ck).expect("a checkpoint");
    let ck_bytes = std::fs::read(&ck).expect("it");
    put("checkpoint", "model.safetensors", &ck_bytes);
    put("state", "model.safetensors", &ck_bytes);
    let x = work.join("x.safetensors");
    iastgcn::interop::write_tensor(&x, "x", &[2, 3], &[0.5, -1.0, 2.0, 0.0, 1e-3, 7.0])
        .expect("a tensor");
    put("tensor", "x.safetensors", &std::fs::read(&x).expect("it"));
    let export = include_str!("../../assets/real-arms/3D_UR5_uncalibrated_grid_cleaned.csv");
    let head: String = export.lines().take(12).map(|l| format!("{l}\n")).collect();
    put("import", "ur5.csv", head.as_bytes());
    if let Ok(poses) = parse_export(&head, "export.csv", &ur5_columns()) {
        put("arm_poses", "ur5.csv", poses.to_csv().as_bytes());
    }
    put(
        "arm_targets",
        "targets.csv",
        b"pose,x,y,z,temp_c\n1,500,0,300,21.5\n2,510.25,-4.5,301,21.75\n3,520,-9,302.5,22\n",
    );
    let assets: [(&str, &str, &[u8]); 8] = [
        (
            "run_config",
            "demo.toml",
            include_bytes!("../../assets/demo.toml"),
        ),
        (
            "run_config",
            "paper.toml",
            include_bytes!("../../assets/paper.toml"),
        ),
        (
            "description",
            "robot.toml",
            include_bytes!("../../assets/robot.toml"),
        ),
        (
            "geometry",
            "robot.toml",
            include_bytes!("../../assets/robot.toml"),
        ),
        (
            "arm",
            "ur5.toml",
            include_bytes!("../../assets/arms/ur5.toml"),
        ),
        (
            "arm",
            "wam4.toml",
            include_bytes!("../../assets/arms/wam4.toml"),
        ),
        (
            "graph",
            "graph.toml",
            include_bytes!("../../assets/graph.toml"),
        ),
        (
            "graph",
            "graph-force.toml",
            include_bytes!("../../assets/graph-force.toml"),
        ),
    ];
    for (target, name, bytes) in assets {
        put(target, name, bytes);
    }
    // Push 16 frames of 14 values, predict, then a batch, a reset and a bad load.
    let mut calls = Vec::new();
    for k in 0..16u8 {
        calls.extend([0, 14]);
        for n in 0..14u8 {
            calls.extend(f64::from(k * n).to_le_bytes());
        }
    }
    calls.extend([2, 0, 4, 3, 12, 5, 0, 8, 4, b'n', b'o', b'n', b'e']);
    put("c_api", "ticks.bin", &calls);
    put("c_api", "short.bin", &[3, 1, 6, 2, 7, 200]);
    std::fs::remove_dir_all(&work).ok();
    println!("seeds for {} targets in {}", TARGETS.len(), dir.display());
}
