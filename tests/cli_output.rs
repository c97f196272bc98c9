//! What the commands print, in the units and shapes the rest of the program uses: the
//! twin's hidden error in µm and mdeg, a before/after table that is never empty, and
//! `--plot` refused where nothing is plotted. Each run takes well under a second.

mod common;

use std::path::{Path, PathBuf};

use common::{calibration_set, cli, cli_fails};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("iastgcn-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn simulate_prints_the_hidden_error_in_micrometres_and_millidegrees() {
    let dir = folder("out-units");
    let out = cli(&[
        "simulate",
        "--trajectory",
        "grid",
        "--minutes",
        "0.1",
        "--out",
        s(&dir.join("g.csv")),
    ]);
    let line = out
        .lines()
        .find(|l| l.starts_with("twin truth"))
        .unwrap_or_else(|| panic!("no truth line in {out}"));
    assert!(
        line.contains(" µm and ") && line.ends_with(" mdeg on average"),
        "{line}"
    );
    // The hybrid twin's mean error is tens to thousands of µm: a number in mm (below 10)
    // printed with the new unit would fail here.
    let um: f64 = line
        .split(" is off by ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no number in {line}"));
    assert!(um > 10.0, "{line}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn calibrate_without_held_out_poses_scores_the_fitted_ones() {
    let dir = folder("out-hold0");
    let set = dir.join("set.csv");
    calibration_set(&set, 40, 101, &[]);
    let out = cli(&[
        "calibrate",
        "--measurements",
        s(&set),
        "--out",
        s(&dir.join("cal.toml")),
        "--hold-out-every",
        "0",
    ]);
    let rows: Vec<&str> = out
        .lines()
        .skip_while(|l| !l.starts_with("data "))
        .skip(2)
        .filter(|l| !l.trim().is_empty())
        .collect();
    assert_eq!(rows.len(), 2, "{out}");
    assert!(rows[0].starts_with("fitted poses (40)"), "{out}");
    assert!(rows[1].trim_start().starts_with("calibrated"), "{out}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn plot_is_refused_where_nothing_is_plotted() {
    let dir = folder("out-plot");
    let png = dir.join("x.png");
    let arm = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/arms/wam4.toml");
    for args in [
        vec!["simulate", "--trajectory", "calibration", "--poses", "20"],
        vec!["simulate", "--robot", s(&arm), "--poses", "20"],
    ] {
        let mut args = args.clone();
        let out = dir.join("p.csv");
        args.extend(["--out", s(&out), "--plot", s(&png)]);
        let err = cli_fails(&args);
        assert!(
            err.contains("--plot") && err.contains("no plot"),
            "{args:?}: {err}"
        );
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// On a machine without any GPU driver: `info` says there is no adapter and what runs
/// anyway, and the WGSL-only commands fail saying that they need an adapter.
#[test]
fn without_a_gpu_driver_info_says_so_and_wgsl_commands_refuse() {
    let (text, _) = common::cli_without_gpu(&["info"]);
    assert!(
        text.contains("adapter      none: native CPU (no GPU adapter)")
            && text.contains("train, refine, predict, evaluate"),
        "{text}"
    );
    let o = common::run(&["smoke"], &common::NO_DRIVER);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains("`iastgcn smoke` (the WGSL kernels) needs a GPU adapter")
            && err.contains("lavapipe"),
        "{err}"
    );
}
