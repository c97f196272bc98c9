//! Shared fixture of the training tests: a short twin session written by the CLI (a
//! calibration measurement set, its EKF calibration and short polishing recordings).

// Each test binary uses only some of these helpers.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// Runs the `iastgcn` binary with `args`; panics with its stderr on failure; returns stdout.
pub fn cli(args: &[&str]) -> String {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "iastgcn {args:?} failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// In `dir` (created if missing): `set.csv`, 60 calibration poses measured with `seed`,
/// and `cal.toml`, their EKF calibration. Returns the calibration's path.
pub fn calibration(dir: &Path, seed: u64) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let (set, cal) = (p("set.csv"), p("cal.toml"));
    let seed = seed.to_string();
    cli(&[
        "simulate",
        "--trajectory",
        "calibration",
        "--poses",
        "60",
        "--seed",
        &seed,
        "--out",
        &set,
    ]);
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
