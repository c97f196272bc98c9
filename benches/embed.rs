//! Per-tick latency of the embedded predictor from Rust, C and Python, in one run
//! (`make bench-embed`; docs/embedding.md "Latency"). One control tick is a push of raw
//! sensor values and a prediction of the window ending there, on the native CPU forward
//! on one thread, at the demo's shape (C 16, T 48, L 2) and the paper's (C 64, T 100,
//! L 5), with freshly initialised weights.
//!
//! Each round times a run of ticks in each language in turn: Rust in this process
//! (`compensate::SensorPredictor`), C through the cdylib this bench was built with
//! (benches/embed/latency.c, compiled here), Python through the installed package
//! (benches/embed/latency.py, in `IASTGCN_PYTHON`, default target/python-venv/bin/python;
//! skipped with a note when it cannot import iastgcn: `make python` builds it). The
//! frames are made before the timing in every language. The table gives the median
//! per-tick time over the rounds, the spread (min–max), and each binding's overhead
//! against Rust in the same round, as a ratio and in µs, with the goal: within 5 % +
//! 10 µs of Rust. `IASTGCN_BENCH_ROUNDS` sets the rounds (default 7). The table is
//! printed and written to target/bench-embed/latency.md.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use iastgcn::compensate::SensorPredictor;
use iastgcn::graph::Graph;
use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters};
use iastgcn::train::RunConfig;

/// The twin's control period, s.
const DT: f64 = 0.02;

fn sensor(node: usize, tick: usize) -> f64 {
    if !tick.is_multiple_of(1 + node % 4) {
        return f64::NAN;
    }
    let phase = (tick * (node + 1) * 7 + node * 13) % 200;
    20.0 + node as f64 + 0.5 * (phase as f64 - 100.0).abs() / 100.0
}

/// Seconds of `ticks` ticks in Rust, after filling the window.
fn time_rust(checkpoint: &Checkpoint, ticks: usize) -> f64 {
    let mut p = SensorPredictor::native(checkpoint, DT).unwrap();
    let (n, t) = (checkpoint.config.nodes, checkpoint.config.window);
    let total = t + 10 + ticks;
    let frames: Vec<Vec<f64>> = (0..total)
        .map(|tick| (0..n).map(|node| sensor(node, tick)).collect())
        .collect();
    for f in &frames[..t + 10] {
        p.push(f).unwrap();
        p.predict_latest().unwrap();
    }
    let mut sum = 0.0;
    let began = Instant::now();
    for f in &frames[t + 10..] {
        p.push(f).unwrap();
        sum += p.predict_latest().unwrap().unwrap()[0];
    }
    let seconds = began.elapsed().as_secs_f64();
    std::hint::black_box(sum);
    seconds
}

/// Runs a timing program; its first output word is the seconds.
fn time_program(command: &mut Command) -> Result<f64, String> {
    let out = command.output().map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    let text = String::from_utf8_lossy(&out.stdout);
    text.split_whitespace()
        .next()
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| format!("unexpected output {text:?}"))
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Compiles the C timing program against the cdylib built with this bench.
fn compile_c(out: &Path) -> Result<PathBuf, String> {
    let deps = std::env::current_exe()
        .map_err(|e| e.to_string())?
        .parent()
        .ok_or("no folder")?
        .to_path_buf();
    if !deps.join("libiastgcn.so").exists() {
        return Err(format!("{} has no libiastgcn.so", deps.display()));
    }
    let exe = out.join("latency");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let done = Command::new(cc)
        .args(["-std=c99", "-O2", "-I"])
        .arg(root().join("include"))
        .arg(root().join("benches/embed/latency.c"))
        .arg(format!("-L{}", deps.display()))
        .arg("-liastgcn")
        .arg(format!("-Wl,-rpath,{}", deps.display()))
        .args(["-lm", "-o"])
        .arg(&exe)
        .output()
        .map_err(|e| e.to_string())?;
    if !done.status.success() {
        return Err(String::from_utf8_lossy(&done.stderr).into_owned());
    }
    Ok(exe)
}

/// The Python with the package installed, or why there is none.
fn python() -> Result<PathBuf, String> {
    let python = std::env::var_os("IASTGCN_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("target/python-venv/bin/python"));
    let ok = Command::new(&python)
        .args(["-c", "import iastgcn"])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        Ok(python)
    } else {
        Err(format!(
            "{} cannot import iastgcn (run `make python`)",
            python.display()
        ))
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn main() {
    let out = root().join("target/bench-embed");
    std::fs::create_dir_all(&out).unwrap();
    let rounds: usize = std::env::var("IASTGCN_BENCH_ROUNDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(7);
    // A C program that does not compile is a defect, not a skip.
    let c = compile_c(&out).unwrap_or_else(|e| panic!("{e}"));
    let py = python();
    let mut notes = Vec::new();
    if let Err(e) = &py {
        notes.push(format!("Python skipped: {e}"));
    }
    let shapes = [
        ("demo (C 16, T 48, L 2)", RunConfig::demo().model, 2000),
        ("paper (C 64, T 100, L 5)", ModelConfig::default(), 200),
    ];
    let mut rows = Vec::new();
    for (label, config, ticks) in shapes {
        let checkpoint = Checkpoint {
            parameters: Parameters::init(&config, 1),
            normalization: Normalization::identity(&config),
            graph: Graph::default_asset(),
            config,
        };
        let path = out.join(format!("{}.safetensors", label.split(' ').next().unwrap()));
        checkpoint.save(&path).unwrap();
        // Per language: per-tick µs of each round, and the overhead against this round's Rust.
        let mut times: [Vec<f64>; 3] = Default::default();
        let mut over: [Vec<f64>; 3] = Default::default();
        for round in 0..rounds {
            eprintln!("{label}: round {} of {rounds}", round + 1);
            let rust = 1e6 * time_rust(&checkpoint, ticks) / ticks as f64;
            times[0].push(rust);
            let ticks_arg = ticks.to_string();
            let others = [
                {
                    // cargo's LD_LIBRARY_PATH would outrank the rpath to this run's library.
                    let mut cmd = Command::new(&c);
                    cmd.env_remove("LD_LIBRARY_PATH").arg(&path).arg(&ticks_arg);
                    Some(cmd)
                },
                py.as_ref().ok().map(|python| {
                    let mut cmd = Command::new(python);
                    cmd.arg(root().join("benches/embed/latency.py"))
                        .arg(&path)
                        .arg(&ticks_arg);
                    cmd
                }),
            ];
            for (k, cmd) in others.into_iter().enumerate() {
                let Some(mut cmd) = cmd else { continue };
                match time_program(&mut cmd) {
                    Ok(s) => {
                        let us = 1e6 * s / ticks as f64;
                        times[k + 1].push(us);
                        over[k + 1].push(us - rust);
                    }
                    Err(e) => panic!("{label}: {e}"),
                }
            }
        }
        let rust = median(&mut times[0].clone());
        for (k, language) in ["Rust", "C", "Python"].iter().enumerate() {
            if times[k].is_empty() {
                continue;
            }
            let t = median(&mut times[k].clone());
            let (lo, hi) = times[k]
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let (overhead, verdict) = if k == 0 {
                ("–".to_string(), "baseline".to_string())
            } else {
                let o = median(&mut over[k].clone());
                let goal = 0.05 * rust + 10.0;
                (
                    format!("{:+.1} µs ({:.3}×)", o, t / rust),
                    format!(
                        "{} (≤ {goal:.1} µs)",
                        if o <= goal { "met" } else { "not met" }
                    ),
                )
            };
            rows.push(format!(
                "| {label} | {language} | {t:.1} | {lo:.1}–{hi:.1} | {overhead} | {verdict} |"
            ));
        }
    }
    let mut md = format!(
        "Per control tick (push of raw sensor values + predict_latest), native CPU forward \
         on one thread, median over {rounds} rounds (2000 ticks per round at the demo \
         shape, 200 at the paper's); overhead = the language's time minus Rust's in the \
         same round, median over rounds; goal: within 5 % + 10 µs of Rust.\n\n\
         | shape | language | µs per tick | min–max | overhead vs Rust | goal |\n\
         |---|---|---|---|---|---|\n"
    );
    for r in &rows {
        md.push_str(r);
        md.push('\n');
    }
    for n in &notes {
        md.push_str(&format!("\n{n}\n"));
    }
    println!("{md}");
    let file = out.join("latency.md");
    std::fs::write(&file, &md).unwrap();
    eprintln!("wrote {}", file.display());
}
