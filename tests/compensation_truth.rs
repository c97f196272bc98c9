//! End to end at a small size, scored against the twin's hidden truth: a model trained on
//! one session of recordings (made under the calibrated controller) compensates a
//! held-out run of a path it never saw, on a warm machine, better than calibration alone
//! by the margin measured (2026-11-27: 40 % of the position and 17 % of the attitude error
//! removed after one minute of data per path; the test asks 30 % and 8 %).

mod common;

use common::cli;

/// The `truth` position (µm) and attitude (mdeg) means of a stage of `iastgcn
/// compensate`'s table.
fn truth_means(table: &str, stage: &str) -> (f64, f64) {
    table
        .lines()
        .find_map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            let at = w.iter().position(|x| *x == "truth")?;
            let value = |k: usize| w.get(at + k)?.parse::<f64>().ok();
            (w.get(1) == Some(&stage)).then(|| Some((value(1)?, value(4)?)))?
        })
        .unwrap_or_else(|| panic!("no {stage} truth row in\n{table}"))
}

#[test]
fn a_trained_model_beats_calibration_on_the_hidden_truth() {
    let dir = std::env::temp_dir().join(format!("iastgcn-truth-{}", std::process::id()));
    let cal = common::calibration(&dir, 101);
    let cal = cal.to_str().unwrap();
    let f = |name: &str| dir.join(name).to_str().unwrap().to_string();
    // One cold session per recording here (the CLI starts each run cold); each has its
    // own seed and the calibrated controller.
    let mut data = Vec::new();
    for (i, path) in ["grid", "fermat", "hilbert"].iter().enumerate() {
        let seed = format!("{}", 201 + i);
        cli(&[
            "simulate",
            "--trajectory",
            path,
            "--minutes",
            "1",
            "--seed",
            &seed,
            "--calibration",
            cal,
            "--out",
            &f(&format!("{path}.csv")),
        ]);
        data.push(f(&format!("{path}.csv")));
    }
    // The demo's model and schedule (T = 48, C = 16, L = 2).
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/demo.toml");
    let model = f("m.safetensors");
    let mut args = vec![
        "train",
        "--config",
        config,
        "--calibration",
        cal,
        "--out",
        &model,
    ];
    args.push("--data");
    args.extend(data.iter().map(String::as_str));
    cli(&args);
    // The rosette: a pattern no recording has, after a warm-up.
    let table = cli(&[
        "compensate",
        "--model",
        &model,
        "--calibration",
        cal,
        "--trajectory",
        "rosette",
        "--minutes",
        "0.5",
        "--warm-up-minutes",
        "1",
        "--every",
        "5",
        "--seed",
        "301",
    ]);
    let (calibrated, compensated, oracle) = (
        truth_means(&table, "calibrated"),
        truth_means(&table, "compensated"),
        truth_means(&table, "oracle"),
    );
    println!("{table}");
    assert!(
        oracle.0 < compensated.0 && oracle.1 < compensated.1,
        "{table}"
    );
    let removed = |of: f64, by: f64| 100.0 * (of - by) / of;
    let (pos, att) = (
        removed(calibrated.0, compensated.0),
        removed(calibrated.1, compensated.1),
    );
    assert!(
        pos >= 30.0 && att >= 8.0,
        "compensation removed {pos:.1} % / {att:.1} % of calibration's error (measured: 40 % / \
         17 %; asked: 30 % / 8 %):\n{table}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Two models that read different sensors (the demo's 17 nodes, Table II's and the planned
/// motion, looking ahead; and Table II's 14 plus the polishing force F:
/// assets/graph-force.toml) compensate side by side, each reading its own checkpoint's
/// channels: each one's row is what it gives alone.
#[test]
fn models_with_different_sensor_graphs_each_read_their_own_channels() {
    let dir = std::env::temp_dir().join(format!("iastgcn-graphs-{}", std::process::id()));
    let cal = common::calibration(&dir, 101);
    let cal = cal.to_str().unwrap();
    let f = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let root = env!("CARGO_MANIFEST_DIR");
    let demo = std::fs::read_to_string(format!("{root}/assets/demo.toml")).unwrap();
    let (ahead, force) = (
        "nodes = 17\nlook_ahead = 1\n",
        "nodes = 15\nlook_ahead = 0\n",
    );
    assert!(
        demo.contains(ahead),
        "assets/demo.toml no longer looks ahead on 17 nodes"
    );
    std::fs::write(f("f.toml"), demo.replacen(ahead, force, 1)).unwrap();
    cli(&[
        "init",
        "--config",
        &format!("{root}/assets/demo.toml"),
        "--out",
        &f("paper.safetensors"),
    ]);
    cli(&[
        "init",
        "--config",
        &f("f.toml"),
        "--graph",
        &format!("{root}/assets/graph-force.toml"),
        "--out",
        &f("force.safetensors"),
    ]);
    let run = |models: &[&str]| {
        let mut args = vec!["compensate", "--calibration", cal, "--trajectory", "grid"];
        args.extend([
            "--minutes",
            "0.2",
            "--warm-up-minutes",
            "0",
            "--seed",
            "301",
        ]);
        for m in models {
            args.extend(["--model", m]);
        }
        cli(&args)
    };
    // The row's fields: the columns' widths follow the longest name in the table (the
    // oracle's, which stands in for the first model, says whether it looks ahead).
    let row = |table: &str, model: &str| -> Vec<String> {
        table
            .lines()
            .find(|l| l.contains(model) && l.contains("truth"))
            .unwrap_or_else(|| panic!("no {model} row in\n{table}"))
            .split_whitespace()
            .map(str::to_string)
            .collect()
    };
    let (paper, force) = (f("paper.safetensors"), f("force.safetensors"));
    let both = run(&[&paper, &force]);
    assert_eq!(row(&both, "force"), row(&run(&[&force]), "force"));
    assert_eq!(row(&both, "paper"), row(&run(&[&paper]), "paper"));
    // Table III windows the recordings with one graph: a model reading other sensors is
    // refused by name rather than scored on the wrong channels.
    let rec = f("grid.csv");
    cli(&[
        "simulate",
        "--trajectory",
        "grid",
        "--minutes",
        "0.5",
        "--calibration",
        cal,
        "--out",
        &rec,
    ]);
    let err = common::cli_fails(&[
        "evaluate",
        "--data",
        &rec,
        "--calibration",
        cal,
        "--models",
        &paper,
        &force,
        "--config",
        &format!("{root}/assets/demo.toml"),
        "--out",
        &f("report"),
    ]);
    assert!(
        err.contains("force: the model reads the sensors") && err.contains("F"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
