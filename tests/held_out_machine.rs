//! Which twin machine a held-out evaluation runs on, said where a user reads it: the
//! calibration file records the machine its measurement set came from, `evaluate`'s
//! report names the session's machine and warns when the calibration came from another
//! one, and `compensate` says where each model's predictions ran. Each run here takes
//! well under a second (a 1-block model, a few seconds of twin time).

mod common;

use std::path::{Path, PathBuf};

use common::{calibration_set, cli};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// In a fresh folder: a calibration set on machine 2, its calibration, a short grid
/// recording on machine 1 under it, and an untrained 1-block model.
fn setup(name: &str) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("iastgcn-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (set, cal) = (dir.join("set.csv"), dir.join("cal.toml"));
    calibration_set(&set, 40, 101, &["--machine-seed", "2"]);
    cli(&["calibrate", "--measurements", s(&set), "--out", s(&cal)]);
    let rec = dir.join("grid.csv");
    cli(&[
        "simulate",
        "--trajectory",
        "grid",
        "--minutes",
        "0.3",
        "--seed",
        "201",
        "--calibration",
        s(&cal),
        "--out",
        s(&rec),
    ]);
    let config = dir.join("small.toml");
    std::fs::write(&config, "[model]\nwindow = 16\nchannels = 4\nblocks = 1\n").unwrap();
    let model = dir.join("m.safetensors");
    cli(&["init", "--config", s(&config), "--out", s(&model)]);
    (dir, cal, rec, model)
}

/// `compensate` of a short Hilbert run with `model` under `cal` (and `extra` flags),
/// whatever its exit status.
fn compensate(model: &Path, cal: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["compensate", "--model", s(model), "--calibration", s(cal)];
    args.extend(["--minutes", "0.05", "--warm-up-minutes", "0"]);
    args.extend(extra);
    std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn calibration_records_its_machine_and_evaluate_warns_on_another() {
    let (dir, cal, rec, model) = setup("machine-eval");
    let text = std::fs::read_to_string(&cal).unwrap();
    assert!(text.contains("machine_seed = 2"), "{text}");
    assert_eq!(
        iastgcn::calibrate::file::load(&cal).unwrap().machine_seed,
        Some(2)
    );

    let out = dir.join("report");
    cli(&[
        "evaluate",
        "--config",
        s(&dir.join("small.toml")),
        "--calibration",
        s(&cal),
        "--data",
        s(&rec),
        "--models",
        s(&model),
        "--held-out-minutes",
        "0.05",
        "--warm-up-minutes",
        "0",
        "--out",
        s(&out),
    ]);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("held-out session (Table V): twin machine 1"),
        "{report}"
    );
    assert!(
        report.contains("measured on twin machine 2") && report.contains("warning"),
        "{report}"
    );

    // On the calibration's own machine no warning.
    let same = compensate(&model, &cal, &["--machine-seed", "2"]);
    assert!(same.status.success());
    assert!(!String::from_utf8_lossy(&same.stderr).contains("warning"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn compensate_warns_on_another_machine_and_says_where_it_predicted() {
    let (dir, cal, _, model) = setup("machine-comp");
    let o = compensate(&model, &cal, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(
        stderr.contains("measured on twin machine 2") && stderr.contains("machine 1"),
        "{stderr}"
    );
    // The prediction line names the path that ran it: the native CPU forward on a CPU
    // adapter, the adapter's name otherwise; never the adapter for a native run.
    let line = stdout
        .lines()
        .find(|l| l.contains("per online prediction on"))
        .unwrap_or_else(|| panic!("no timing line in {stdout}"));
    let info = cli(&["info"]);
    let cpu_adapter = info.contains("software rasteriser");
    if cpu_adapter {
        assert!(line.ends_with("on native CPU forward"), "{line}");
    } else {
        assert!(!line.contains("native"), "{line}");
    }
    // The run lies at its held-out placement unless --rotation / --reverse place it: the
    // output names the placement, and the calibrated row (no model in it) moves with it.
    assert!(
        stdout.contains("hilbert turned 53°, walked from its other end"),
        "{stdout}"
    );
    let turned = compensate(&model, &cal, &["--rotation", "450", "--reverse"]);
    let turned_out = String::from_utf8_lossy(&turned.stdout);
    assert!(
        turned_out.contains("hilbert turned 90°, walked from its other end"),
        "{turned_out}"
    );
    let calibrated = |text: &str| {
        text.lines()
            .find(|l| l.contains("calibrated"))
            .map(str::to_string)
            .unwrap_or_else(|| panic!("no calibrated row in {text}"))
    };
    assert_ne!(calibrated(&stdout), calibrated(&turned_out));
    let bad = compensate(&model, &cal, &["--rotation", "NaN"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--rotation"));
    std::fs::remove_dir_all(&dir).unwrap();
}
