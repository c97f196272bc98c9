//! Per-tick latency of the embedded predictor from Rust, C and Python, in one run
//! (`make bench-embed`; docs/embedding.md "Latency"). One control tick is a push of raw
//! sensor values and a prediction of the window ending there, on the native CPU forward
//! on one thread, at the demo's shape (C 16, T 48, L 2) and the paper's (C 64, T 100,
//! L 5), with freshly initialised weights.
//!
//! Each round times a run of ticks in each language in turn: Rust in this process
//! (`compensate::SensorPredictor`), C through the shared library `make c-library` built beside this bench's profile
//! (benches/embed/latency.c, compiled here), Python through the installed package
//! (benches/embed/latency.py, in `IASTGCN_PYTHON`, default target/python-venv/bin/python;
//! skipped with a note when it cannot import iastgcn: `make python` builds it). The
//! frames are made before the timing in every language. The table gives the median
//! per-tick time over the rounds, the spread (min–max), and each binding's overhead
//! against Rust in the same round, as a ratio and in µs, with the goal: within 5 % +
//! 10 µs of Rust. `IASTGCN_BENCH_ROUNDS` sets the rounds (default 7).
//!
//! Then the worst ticks, what a control loop is judged by: one long run per language
//! (`IASTGCN_BENCH_TAIL_TICKS`, default 10⁶ at the demo shape, a hundredth of it at the
//! paper's) with every tick timed on its own (a monotonic clock read before and after
//! it), frames cycled from 1 200 made beforehand; p50, p99, p99.9, the maximum and the
//! mean per tick, the ticks over twice the median, the process's resident memory (VmRSS)
//! after the warm-up and after the run, and its minor page faults during the run. Each
//! program writes its tick times (u64 ns, native byte order) to a file and the
//! percentiles are computed here, one way for all three. Both tables are printed and
//! written to target/bench-embed/latency.md.

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

/// Frames made before a long run and cycled through it (a multiple of the sensors'
/// sampling periods and of `sensor`'s 200-tick phase).
const CYCLE: usize = 1200;

/// The resident memory of this process, KiB (VmRSS of /proc/self/status; 0 where there
/// is none).
fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// Minor page faults of this process so far (field 10 of /proc/self/stat; 0 where there
/// is none).
fn minor_faults() -> u64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            // After the command's name, in parentheses: state, ppid, pgrp, session,
            // tty_nr, tpgid, flags, minflt.
            let rest = &s[s.rfind(')')? + 1..];
            rest.split_whitespace().nth(7)?.parse().ok()
        })
        .unwrap_or(0)
}

/// One long run's tick times, ns, the resident memory (KiB) after the warm-up and after
/// the run, and the minor page faults during the run.
struct Tail {
    ns: Vec<u64>,
    rss: (u64, u64),
    faults: u64,
}

/// `ticks` ticks in Rust, each timed on its own.
fn tail_rust(checkpoint: &Checkpoint, ticks: usize) -> Tail {
    let mut p = SensorPredictor::native(checkpoint, DT).unwrap();
    let (n, t) = (checkpoint.config.nodes, checkpoint.config.window);
    let frames: Vec<Vec<f64>> = (0..CYCLE)
        .map(|tick| (0..n).map(|node| sensor(node, tick)).collect())
        .collect();
    // Written before the run, so that the run touches no new page of it.
    let mut ns = vec![1u64; ticks];
    for f in frames.iter().cycle().take(t + 10) {
        p.push(f).unwrap();
        p.predict_latest().unwrap();
    }
    let before = rss_kib();
    let faults = minor_faults();
    let mut sum = 0.0;
    for (tick, slot) in ns.iter_mut().enumerate() {
        let began = Instant::now();
        p.push(&frames[(t + 10 + tick) % CYCLE]).unwrap();
        sum += p.predict_latest().unwrap().unwrap()[0];
        *slot = began.elapsed().as_nanos() as u64;
    }
    let faults = minor_faults() - faults;
    std::hint::black_box(sum);
    Tail {
        ns,
        rss: (before, rss_kib()),
        faults,
    }
}

/// Runs a long-run program that writes its tick times to `file` and prints
/// `tail RSS_BEFORE RSS_AFTER FAULTS`.
fn tail_program(command: &mut Command, file: &Path) -> Result<Tail, String> {
    let out = command.output().map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let words: Vec<&str> = text.split_whitespace().collect();
    let number = |w: &str| -> Result<u64, String> {
        w.parse().map_err(|_| format!("unexpected output {text:?}"))
    };
    let (rss, faults) = match words.as_slice() {
        ["tail", before, after, faults, ..] => ((number(before)?, number(after)?), number(faults)?),
        _ => return Err(format!("unexpected output {text:?}")),
    };
    let bytes = std::fs::read(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let ns = bytes
        .chunks_exact(8)
        .map(|b| u64::from_ne_bytes(b.try_into().unwrap()))
        .collect();
    std::fs::remove_file(file).map_err(|e| e.to_string())?;
    Ok(Tail { ns, rss, faults })
}

/// The table row of one long run: p50, p99, p99.9, max and mean in µs (nearest-rank
/// percentiles), the resident memory before and after in MiB, the minor page faults, and
/// the ticks over twice the median.
fn tail_row(label: &str, language: &str, tail: &Tail) -> String {
    let mut ns = tail.ns.clone();
    ns.sort_unstable();
    let at = |p: f64| ns[((p * ns.len() as f64).ceil() as usize).clamp(1, ns.len()) - 1] as f64;
    let mean = ns.iter().map(|&v| v as f64).sum::<f64>() / ns.len() as f64;
    let mib = |kib: u64| kib as f64 / 1024.0;
    format!(
        "| {label} | {language} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} → {:.1} | {} | {} |",
        ns.len(),
        at(0.5) / 1e3,
        at(0.99) / 1e3,
        at(0.999) / 1e3,
        *ns.last().unwrap() as f64 / 1e3,
        mean / 1e3,
        mib(tail.rss.0),
        mib(tail.rss.1),
        tail.faults,
        ns.iter().filter(|&&v| v > 2 * ns[(ns.len() - 1) / 2]).count()
    )
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

/// Compiles the C timing program against the shared library in this bench's profile
/// folder (`target/release`, where `make c-library` builds it).
fn compile_c(out: &Path) -> Result<PathBuf, String> {
    let deps = std::env::current_exe()
        .map_err(|e| e.to_string())?
        .parent()
        .and_then(Path::parent)
        .ok_or("no profile folder")?
        .to_path_buf();
    if !deps.join("libiastgcn.so").exists() {
        return Err(format!(
            "{} has no libiastgcn.so: `make c-library` builds it",
            deps.display()
        ));
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
    let tail_ticks: usize = std::env::var("IASTGCN_BENCH_TAIL_TICKS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let shapes = [
        (
            "demo (C 16, T 48, L 2)",
            RunConfig::demo().model,
            2000,
            tail_ticks,
        ),
        (
            "paper (C 64, T 100, L 5)",
            ModelConfig::default(),
            200,
            (tail_ticks / 100).max(1),
        ),
    ];
    let mut rows = Vec::new();
    let mut tail_rows = Vec::new();
    for (label, config, ticks, long) in shapes {
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
        eprintln!("{label}: {long} ticks timed one by one, in Rust, C and Python");
        tail_rows.push(tail_row(label, "Rust", &tail_rust(&checkpoint, long)));
        let file = out.join("ticks.bin");
        let long_arg = long.to_string();
        let mut c_cmd = Command::new(&c);
        c_cmd
            .env_remove("LD_LIBRARY_PATH")
            .arg(&path)
            .arg(&long_arg)
            .arg(&file);
        let c_tail = tail_program(&mut c_cmd, &file).unwrap_or_else(|e| panic!("{label}: {e}"));
        tail_rows.push(tail_row(label, "C", &c_tail));
        if let Ok(python) = &py {
            let mut cmd = Command::new(python);
            cmd.arg(root().join("benches/embed/latency.py"))
                .arg(&path)
                .arg(&long_arg)
                .arg(&file);
            let tail = tail_program(&mut cmd, &file).unwrap_or_else(|e| panic!("{label}: {e}"));
            tail_rows.push(tail_row(label, "Python", &tail));
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
    md.push_str(&format!(
        "\nEvery tick of one long run per language timed on its own ({tail_ticks} ticks at \
         the demo shape, {} at the paper's), µs per tick; resident memory after the \
         warm-up → after the run; minor page faults during the run; ticks over twice the median.\n\n\
         | shape | language | ticks | p50 | p99 | p99.9 | max | mean | RSS MiB | faults | > 2 × p50 |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
        (tail_ticks / 100).max(1)
    ));
    for r in &tail_rows {
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
