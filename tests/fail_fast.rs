//! A command whose output cannot be written refuses before any long work, naming the flag
//! (issue 42): before, `simulate --minutes 30` ran its 30 minutes of twin and `evaluate`
//! its Tables III and V, and only then failed to write. The output is checked first, so
//! these fail even before their inputs are read (the input files here do not exist).

mod common;

use common::cli_fails;

#[test]
fn unwritable_outputs_are_refused_before_any_work() {
    let dir = std::env::temp_dir().join(format!("iastgcn-fail-fast-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let blocker = dir.join("a-file");
    std::fs::write(&blocker, "not a folder").unwrap();
    let missing = dir.join("no-such-folder");
    let p = |name: &str| missing.join(name).to_str().unwrap().to_string();
    let (data, cal) = (p("grid.csv"), p("cal.toml"));
    let cases: Vec<Vec<String>> = [
        vec![
            "simulate",
            "--trajectory",
            "hilbert",
            "--minutes",
            "30",
            "--out",
            &p("h.csv"),
        ],
        vec!["calibrate", "--data", &data, "--out", &p("c.toml")],
        vec![
            "train",
            "--data",
            &data,
            "--calibration",
            &cal,
            "--out",
            &p("m.safetensors"),
        ],
        vec![
            "refine",
            "--data",
            &data,
            "--calibration",
            &cal,
            "--model",
            &p("m.safetensors"),
            "--out",
            &p("r.safetensors"),
        ],
        vec![
            "predict",
            "--data",
            &data,
            "--calibration",
            &cal,
            "--model",
            &p("m.safetensors"),
            "--out",
            &p("p.csv"),
        ],
        vec![
            "evaluate",
            "--data",
            &data,
            "--calibration",
            &cal,
            "--models",
            &p("m.safetensors"),
            "--out",
            blocker.join("report").to_str().unwrap(),
        ],
    ]
    .into_iter()
    .map(|v| v.into_iter().map(String::from).collect())
    .collect();
    for args in &cases {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let err = cli_fails(&a);
        assert!(
            err.contains("--out") && err.contains("nothing was run"),
            "{}: {err}",
            args[0]
        );
    }
    assert!(!missing.exists(), "a refused command made its folder");
    let _ = std::fs::remove_dir_all(&dir);
}
