//! `iastgcn reproduce` end to end at a tiny size: the data once, the jobs split over two
//! shards, a final run that trains nothing and writes the report with the spread over
//! seeds; a job whose outputs are lost resumes from its state file to the same model;
//! another protocol in the same folder and a bad shard are refused; another twin
//! machine's data say which machine they come from.

mod common;

use std::path::{Path, PathBuf};

use common::{cli, cli_fails};

const TINY: &str =
    "[model]\nwindow = 16\nchannels = 4\nblocks = 2\nhidden = 8\n\n[data]\nstride = 5\n\n\
[train]\nbatch = 32\nlr = 3e-3\nmax_epochs = 2\n\n[refine]\nmagnifications = [3]\nmax_epochs = 1\n";

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn reproduce_shards_resumes_and_reports_over_seeds() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("iastgcn-reproduce-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let out = dir.join("out");
    let run = |extra: &[&str]| {
        let mut args = vec![
            "reproduce",
            "--config",
            s(&config),
            "--recipe",
            "paper",
            "--minutes",
            "0.5",
            "--seeds",
            "1,2",
            "--models",
            "iastgcn,mlp",
            "--fractions",
            "0.5",
            "--curve-models",
            "iastgcn",
            "--held-out-minutes",
            "0.1",
            "--warm-up-minutes",
            "0.2",
            "--out",
            s(&out),
        ];
        args.extend(extra);
        cli(&args)
    };

    let text = run(&["--data-only"]);
    assert!(text.contains("0 of 6 jobs done"), "{text}");
    assert!(out.join("data/calibration.toml").exists());
    assert!(out.join("protocol.toml").exists());

    // The jobs: iastgcn and mlp for seed 1, then for seed 2, then the learning curve's
    // iastgcn on half the training windows for seeds 1 and 2. Shard 1 of 2 takes jobs 1,
    // 3 and 5; shard 2 jobs 2, 4 and 6.
    let text = run(&["--shard", "1/2"]);
    assert!(text.contains("3 of 6 jobs done"), "{text}");
    let models = out.join("models");
    assert!(models.join("iastgcn.seed1.job.toml").exists());
    assert!(models.join("iastgcn.seed2.job.toml").exists());
    assert!(models.join("curve/iastgcn.seed1.train50.job.toml").exists());
    assert!(!models.join("mlp.seed1.job.toml").exists());
    assert!(!out.join("report.md").exists());
    let text = run(&["--shard", "2/2"]);
    assert!(text.contains("6 of 6 jobs done"), "{text}");

    // A job whose record and refined model are lost resumes from its core state: the
    // same refined weights, bit for bit.
    let refined = models.join("iastgcn.seed2.safetensors");
    let before = std::fs::read(&refined).unwrap();
    std::fs::remove_file(models.join("iastgcn.seed2.job.toml")).unwrap();
    std::fs::remove_file(&refined).unwrap();

    // The final run: only the lost job trains, then the report.
    let text = run(&[]);
    assert!(text.contains("reproduce finished"), "{text}");
    assert_eq!(std::fs::read(&refined).unwrap(), before);
    for name in [
        "report.md",
        "table_v.csv",
        "table_iii.csv",
        "table_v_seeds.csv",
        "table_iii_seeds.csv",
        "paired.csv",
        "losses.png",
    ] {
        assert!(out.join(name).exists(), "{name}");
    }
    let table_v = std::fs::read_to_string(out.join("table_v.csv")).unwrap();
    for model in ["iastgcn.seed1", "iastgcn.seed2", "mlp.seed1", "mlp.seed2"] {
        assert_eq!(
            table_v
                .lines()
                .filter(|l| l.contains(&format!(",compensated,{model},")))
                .count(),
            12,
            "{model}: one row per held-out path in each of 3 held-out sessions"
        );
    }
    let seeds = std::fs::read_to_string(out.join("table_v_seeds.csv")).unwrap();
    assert_eq!(
        seeds.lines().filter(|l| l.contains(",iastgcn,6,")).count(),
        4
    );
    let paired = std::fs::read_to_string(out.join("paired.csv")).unwrap();
    // mlp against iastgcn: 3 Table III paths × 2 + 4 Table V paths × 2.
    assert_eq!(paired.lines().count(), 1 + 14, "{paired}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Spread over training seeds"));
    assert!(report.contains("## Core training over seeds"));
    assert!(report.contains("| iastgcn | 2 |"), "{report}");
    // The report names the recipe it ran.
    assert!(
        report.contains("recipe: paper (the paper's single session at the training placement, open loop, a prediction every 5 ticks)"),
        "{report}"
    );
    assert!(report.contains("## Learning curve"), "{report}");
    // The learning curve: iastgcn at 50 % and 100 % of the training windows, 2 seeds.
    let curve = std::fs::read_to_string(out.join("learning_curve.csv")).unwrap();
    let rows: Vec<Vec<&str>> = curve
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 2, "{curve}");
    assert_eq!(
        (rows[0][0], rows[0][1], rows[0][3]),
        ("iastgcn", "0.5", "2")
    );
    assert_eq!((rows[1][0], rows[1][1], rows[1][3]), ("iastgcn", "1", "2"));
    let windows = |r: &Vec<&str>| r[2].parse::<f64>().unwrap();
    let ratio = windows(&rows[0]) / windows(&rows[1]);
    assert!((0.45..=0.55).contains(&ratio), "{curve}");
    for r in &rows {
        assert!(
            r[4..].iter().all(|v| v.parse::<f64>().unwrap().is_finite()),
            "{curve}"
        );
    }
    assert!(out.join("learning_curve.png").exists());
    assert!(out.join("losses.csv").exists());

    // Another protocol in the same folder is refused, naming the file.
    let mut args = vec!["reproduce", "--config", s(&config), "--minutes", "0.5"];
    args.extend([
        "--recipe",
        "paper",
        "--seeds",
        "1,3",
        "--models",
        "iastgcn,mlp",
        "--out",
        s(&out),
    ]);
    let err = cli_fails(&args);
    assert!(err.contains("protocol.toml"), "{err}");
    let err = cli_fails(&["reproduce", "--shard", "3/2", "--out", s(&out)]);
    assert!(err.contains("k/n"), "{err}");
    let err = cli_fails(&[
        "reproduce",
        "--fractions",
        "1.5",
        "--out",
        s(&dir.join("x")),
    ]);
    assert!(err.contains("fractions: 1.5"), "{err}");

    // Another twin machine: its own folder, its data recorded on that machine (the
    // sidecars say so, and an evaluation's held-out session follows them); the first
    // folder refuses it, and recordings of two machines do not mix.
    let out2 = dir.join("out2");
    let mut args = vec!["reproduce", "--config", s(&config), "--minutes", "0.5"];
    args.extend(["--recipe", "paper", "--machine-seed", "2"]);
    args.extend(["--data-only", "--out", s(&out2)]);
    let text = cli(&args);
    assert!(text.contains("0 of"), "{text}");
    let data = |o: &Path| {
        iastgcn::experiment::protocol::data_sources(&o.join("data"), &iastgcn::twin::Recipe::SINGLE)
    };
    assert_eq!(data(&out2).machine_seed().unwrap(), 2);
    assert_eq!(data(&out).machine_seed().unwrap(), 1);
    let mut mixed = data(&out);
    mixed.recordings[1] = data(&out2).recordings[1].clone();
    let e = mixed.machine_seed().unwrap_err().to_string();
    assert!(e.contains("recorded on twin machine 2"), "{e}");
    args.pop();
    args.push(s(&out));
    let err = cli_fails(&args);
    assert!(err.contains("protocol.toml"), "{err}");
    let err = cli_fails(&[
        "reproduce",
        "--merge",
        s(&out),
        s(&out2),
        "--out",
        s(&dir.join("m")),
    ]);
    assert!(err.contains("another protocol"), "{err}");

    // Closed-loop data are part of the data stage: a round-0 IASTGCN trained on session
    // 1 records session 2 again with it compensating; a second call finds both done.
    let out3 = dir.join("out3");
    let closed = || {
        let mut args = vec!["reproduce", "--config", s(&config), "--minutes", "1"];
        args.extend([
            "--recipe",
            "paper",
            "--sessions",
            "2",
            "--closed-loop",
            "--every",
            "1",
        ]);
        args.extend(["--data-only", "--out", s(&out3)]);
        cli(&args)
    };
    let text = closed();
    assert!(
        text.contains("closed-loop data: round 0 (iastgcn.seed1.round0) trained on sessions 1-1")
            && text.contains("every job trained on sessions 1-1 open loop and 2-2 closed loop"),
        "{text}"
    );
    let recorded = out3.join("data/closed-loop/hilbert.s02.csv");
    let info = iastgcn::twin::RunInfo::read(&recorded).unwrap();
    assert!(
        info.controller
            .ends_with("with iastgcn.seed1.round0 compensating (every 1 ticks)"),
        "{}",
        info.controller
    );
    let written = std::fs::metadata(&recorded).unwrap().modified().unwrap();
    let again = closed();
    assert!(again.contains("nothing more to train"), "{again}");
    assert_eq!(
        std::fs::metadata(&recorded).unwrap().modified().unwrap(),
        written,
        "the closed-loop recordings were made again"
    );
    let err = cli_fails(&[
        "reproduce",
        "--recipe",
        "paper",
        "--closed-loop",
        "--out",
        s(&dir.join("y")),
    ]);
    assert!(
        err.contains("--sessions: closed-loop data") && err.contains("2 sessions or more"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
