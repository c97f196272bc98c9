//! End to end at a small size, scored against the twin's hidden truth: a model trained on
//! one session of recordings (made under the calibrated controller) compensates a
//! held-out run of a path it never saw, on a warm machine, better than calibration alone.

mod common;

use common::cli;

/// The `truth` position mean (µm) of a stage of `iastgcn compensate`'s table.
fn truth_position(table: &str, stage: &str) -> f64 {
    table
        .lines()
        .find_map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            let at = w.iter().position(|x| *x == "truth")?;
            (w.get(1) == Some(&stage)).then(|| w.get(at + 1)?.parse().ok())?
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
        truth_position(&table, "calibrated"),
        truth_position(&table, "compensated"),
        truth_position(&table, "oracle"),
    );
    println!("{table}");
    assert!(oracle < compensated, "{table}");
    assert!(
        compensated < 0.95 * calibrated,
        "compensation {compensated} µm vs calibration alone {calibrated} µm:\n{table}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
