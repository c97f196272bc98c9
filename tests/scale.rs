//! `iastgcn scale` end to end at a tiny size: the data once at the largest size, the jobs
//! split over two shards, the summary after them; every size is scored on the same test
//! windows and the same held-out session (the calibrated and oracle rows do not depend
//! on the model); a validation session is scored beside it, kept out of the tables, and
//! names the recommended model at each size by the rule recomputed here; a job whose
//! record is lost is redone from its state to the same scores;
//! a study grows by seeds; another setup in the same folder and bad sizes are refused.
//! A closed-loop study records its second half of sessions again with a round-0 model
//! compensating, on the same days, placements and seeds.

mod common;

use std::path::{Path, PathBuf};

use common::{cli, cli_fails};
use iastgcn::experiment::scale::ScaleRecord;

const TINY: &str = "[model]\nwindow = 16\nchannels = 4\nblocks = 2\nhidden = 8\n\n\
[data]\nstride = 5\n\n[train]\nbatch = 32\nlr = 3e-3\nmax_epochs = 2\n";

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn record(path: &Path) -> ScaleRecord {
    toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn scale_shards_scores_every_size_alike_and_resumes() {
    let dir: PathBuf = std::env::temp_dir().join(format!("iastgcn-scale-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let out = dir.join("out");
    let run = |extra: &[&str]| {
        let mut args = vec!["scale", "--config", s(&config), "--sizes", "0.25,0.5"];
        args.extend(["--recipe", "paper"]);
        args.extend(["--seeds", "1,2", "--models", "tgcn,mlp"]);
        args.extend(["--held-out-minutes", "0.1", "--warm-up-minutes", "0.2"]);
        args.extend(["--held-out-sessions", "1", "--validation-session"]);
        args.extend(["--out", s(&out)]);
        args.extend(extra);
        cli(&args)
    };
    let text = run(&["--data-only"]);
    assert!(text.contains("0 of 8 jobs done"), "{text}");
    assert!(out.join("study.toml").exists());
    // Jobs: seed 1 (tgcn, mlp on 0.25, then on 0.5), then seed 2; shard 1 has the tgcn.
    let text = run(&["--shard", "1/2"]);
    assert!(text.contains("4 of 8 jobs done"), "{text}");
    let models = out.join("models");
    assert!(models.join("tgcn.min0.25.seed1.job.toml").exists());
    assert!(!models.join("mlp.min0.25.seed1.job.toml").exists());
    let text = run(&["--shard", "2/2"]);
    assert!(text.contains("8 of 8 jobs done"), "{text}");

    let records: Vec<ScaleRecord> = ["tgcn", "mlp"]
        .iter()
        .flat_map(|m| {
            ["0.25", "0.5"]
                .iter()
                .flat_map(move |min| [1, 2].map(|k| format!("{m}.min{min}.seed{k}.job.toml")))
        })
        .map(|name| record(&models.join(name)))
        .collect();
    let first = &records[0];
    for r in &records {
        // Four paths in the held-out session and in the validation session after it,
        // on another day: its calibrated error differs on every path.
        assert_eq!(r.paths.len(), 8, "{}", r.name);
        for (a, b) in r.paths[..4].iter().zip(&r.paths[4..]) {
            assert_eq!(
                (a.path.as_str(), a.session, b.session),
                (b.path.as_str(), 0, 1)
            );
            assert_ne!(a.calibrated, b.calibrated, "{} {}", r.name, a.path);
            assert_eq!(a.test_mae.map(f64::to_bits), b.test_mae.map(f64::to_bits));
        }
        // About half the training windows at half the size (a window's length less).
        let full = records[2].train_windows as f64;
        let want = if r.minutes == 0.5 {
            1.0..=1.0
        } else {
            0.35..=0.55
        };
        assert!(
            want.contains(&(r.train_windows as f64 / full)),
            "{}: {} training windows against {full}",
            r.name,
            r.train_windows
        );
        for (p, q) in r.paths.iter().zip(&first.paths) {
            // The same test block and held-out session for every size and model.
            assert_eq!(p.test_windows, q.test_windows, "{} {}", r.name, p.path);
            assert_eq!(p.calibrated, q.calibrated, "{} {}", r.name, p.path);
            assert_eq!(p.oracle, q.oracle, "{} {}", r.name, p.path);
            assert_eq!(p.initial, q.initial, "{} {}", r.name, p.path);
            assert!(p.compensated.iter().all(|v| v.is_finite()), "{}", r.name);
            // The open-loop miss along the uncompensated run is measured for every path.
            assert!(
                p.open_loop.iter().all(|v| v.is_finite() && *v > 0.0),
                "{}",
                r.name
            );
            assert!(p.calibrated[0] < p.initial[0], "{}", p.path);
            if p.path == "rosette" {
                assert_eq!(p.test_windows, 0);
            } else {
                assert!(
                    p.test_windows > 0 && p.test_mae[0].is_finite(),
                    "{}",
                    p.path
                );
            }
        }
    }

    let md = std::fs::read_to_string(out.join("scale.md")).unwrap();
    assert!(
        md.contains("- recipe: paper (the paper's single session"),
        "{md}"
    );
    let summary = std::fs::read_to_string(out.join("scale_summary.csv")).unwrap();
    // 2 models × 2 sizes × 4 paths, each over 2 seeds and the one test session: the
    // validation session is in no table.
    let rows: Vec<Vec<&str>> = summary
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 16, "{summary}");
    assert!(rows.iter().all(|r| r[3] == "2" && r[4] == "1"), "{summary}");
    assert_eq!(
        (rows[0][0], rows[0][1], rows[0][5]),
        ("tgcn", "0.25", "grid")
    );
    // Every job's row per path and session, each session's role named.
    let jobs_csv = std::fs::read_to_string(out.join("scale.csv")).unwrap();
    assert_eq!(jobs_csv.lines().count(), 1 + 64);
    for (role, n) in [(",test", 32), (",validation", 32)] {
        assert_eq!(jobs_csv.lines().filter(|l| l.ends_with(role)).count(), n);
    }
    // The recommendation at each size: the rule over the validation session's scores,
    // computed here again from the records (mean over paths, then over seeds; the
    // highest mean of position and attitude, if it removes anything).
    let chosen = std::fs::read_to_string(out.join("scale_validation.csv")).unwrap();
    for min in ["0.25", "0.5"] {
        let mut best: Option<(f64, &str)> = None;
        for m in ["tgcn", "mlp"] {
            let score: Vec<[f64; 2]> = [1, 2]
                .map(|k| record(&models.join(format!("{m}.min{min}.seed{k}.job.toml"))))
                .iter()
                .map(|r| {
                    let v: Vec<[f64; 2]> = r.paths[4..]
                        .iter()
                        .map(|p| {
                            assert_eq!(p.session, 1);
                            p.removed(p.compensated)
                        })
                        .collect();
                    [0, 1].map(|i| v.iter().map(|s| s[i]).sum::<f64>() / 4.0)
                })
                .collect();
            let [pos, att] = [0, 1].map(|i| (score[0][i] + score[1][i]) / 2.0);
            let line = format!("{min},{m},2,{pos:.3},{att:.3},{:.3},", (pos + att) / 2.0);
            assert!(chosen.contains(&line), "{line}\n{chosen}");
            if (pos + att) / 2.0 > best.map_or(0.0, |b| b.0) {
                best = Some(((pos + att) / 2.0, m));
            }
        }
        let recommended: Vec<&str> = chosen
            .lines()
            .filter(|l| l.starts_with(&format!("{min},")) && l.contains(",true,"))
            .collect();
        match best {
            Some((_, m)) => assert!(
                recommended.len() == 1 && recommended[0].starts_with(&format!("{min},{m},")),
                "{min}: {m}\n{chosen}"
            ),
            None => assert!(recommended.is_empty(), "{chosen}"),
        }
    }
    let md = std::fs::read_to_string(out.join("scale.md")).unwrap();
    assert!(md.contains("Jobs finished in this folder: 8 "), "{md}");
    assert!(
        md.contains("## hilbert") && md.contains("| oracle (true residual) |"),
        "{md}"
    );
    assert!(
        md.contains("  - session 2 (**validation**")
            && md.contains("| session 2 (validation) |")
            && md.contains("## Recommended model")
            && md.contains("### 0.5 min per path")
            && md.contains("## By held-out session")
            && md.contains("## Where the error goes"),
        "{md}"
    );
    assert!(out.join("scale.png").exists());

    // A lost record: the job resumes from its state (training is over) to the same scores.
    let lost = models.join("tgcn.min0.5.seed2.job.toml");
    let before = record(&lost);
    std::fs::remove_file(&lost).unwrap();
    let text = run(&[]);
    assert!(text.contains("8 of 8 jobs done"), "{text}");
    let after = record(&lost);
    // (As text: the rosette's test MAE is NaN.)
    assert_eq!(format!("{:?}", after.paths), format!("{:?}", before.paths));
    assert_eq!(after.best_val, before.best_val);

    // Seed ensembles: each model and size whose seeds have finished, scored on the same
    // held-out sessions with the seeds' mean prediction in the loop, once.
    let text = run(&["--ensemble"]);
    assert!(text.contains("8 of 8 jobs done"), "{text}");
    for m in ["tgcn", "mlp"] {
        for min in ["0.25", "0.5"] {
            let r = record(&models.join(format!("{m}.min{min}.ensemble.job.toml")));
            assert_eq!((r.model.as_str(), r.seed), (&*format!("{m}-ensemble"), 0));
            assert_eq!(r.trained_on, "the mean of seeds 1, 2");
            assert_eq!(r.paths.len(), 8);
            for (p, q) in r.paths.iter().zip(&first.paths) {
                assert_eq!((p.calibrated, p.oracle), (q.calibrated, q.oracle));
                assert!(p.compensated.iter().all(|v| v.is_finite()), "{}", r.name);
                assert!(p.open_loop.iter().all(|v| v.is_finite()), "{}", r.name);
                assert!(p.test_mae[0].is_nan() && p.test_windows == 0);
            }
        }
    }
    let summary = std::fs::read_to_string(out.join("scale_summary.csv")).unwrap();
    assert!(
        summary.lines().any(|l| l.starts_with("tgcn-ensemble,0.5,")),
        "{summary}"
    );

    // The study may grow by seeds (or sizes, models): seed 1's jobs are done already.
    let mut args = vec!["scale", "--config", s(&config), "--sizes", "0.25,0.5"];
    args.extend(["--recipe", "paper"]);
    args.extend(["--seeds", "1,3", "--models", "tgcn,mlp", "--data-only"]);
    args.extend(["--held-out-minutes", "0.1", "--warm-up-minutes", "0.2"]);
    args.extend(["--held-out-sessions", "1", "--validation-session"]);
    args.extend(["--out", s(&out)]);
    let text = cli(&args);
    assert!(text.contains("4 of 8 jobs done"), "{text}");
    // Another setup in the same folder (here: recordings of another length), and sizes
    // out of order, are refused.
    let mut args = vec!["scale", "--config", s(&config), "--sizes", "0.25,0.75"];
    args.extend(["--recipe", "paper", "--out", s(&out)]);
    let err = cli_fails(&args);
    assert!(
        err.contains("study.toml") && err.contains("another study"),
        "{err}"
    );
    let err = cli_fails(&["scale", "--sizes", "8,2", "--out", s(&dir.join("x"))]);
    assert!(err.contains("ascending"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn closed_loop_data_are_recorded_with_a_round_zero_model_compensating() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("iastgcn-closed-loop-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let out = dir.join("out");
    let mut args = vec![
        "scale",
        "--config",
        s(&config),
        "--recipe",
        "paper",
        "--sizes",
        "0.5",
        "--seeds",
        "1",
    ];
    args.extend(["--models", "mlp", "--held-out-minutes", "0.1"]);
    args.extend(["--warm-up-minutes", "0.2", "--held-out-sessions", "1"]);
    args.extend(["--sessions", "2", "--placement", "varied", "--out", s(&out)]);
    // One session has no second half to record closed loop.
    let mut one = args.clone();
    let n = one.len();
    one[n - 5] = "1";
    one.push("--closed-loop");
    let err = cli_fails(&one);
    assert!(
        err.contains("--sessions: closed-loop data") && err.contains("2 sessions or more"),
        "{err}"
    );
    args.push("--closed-loop");
    let text = cli(&args);
    assert!(text.contains("1 of 1 jobs done"), "{text}");
    let models = out.join("models");
    assert!(models
        .join("mlp.min0.5.seed1.round0.core.safetensors")
        .exists());
    let r = record(&models.join("mlp.min0.5.seed1.job.toml"));
    assert!(
        r.closed_loop.contains("trained on sessions 1-1")
            && r.closed_loop.contains("compensated sessions 2-2")
            && r.closed_loop
                .contains("mean true error against the path target of"),
        "{}",
        r.closed_loop
    );
    assert!(r.paths.iter().all(|p| p.compensated[0].is_finite()));
    for path in ["grid", "fermat", "hilbert"] {
        let open = out.join("data").join(format!("{path}.s02.csv"));
        let closed = models
            .join("mlp.min0.5.seed1.closed")
            .join(format!("{path}.s02.csv"));
        let sidecar = |p: &Path| iastgcn::twin::RunInfo::read(p).unwrap();
        let (a, b) = (sidecar(&open), sidecar(&closed));
        // The same session: day, placement, seed, feed and force; another controller.
        assert_eq!(
            (
                a.session,
                a.seed,
                a.rotation_deg,
                a.reverse,
                a.feed_mm_s,
                a.force_n
            ),
            (
                b.session,
                b.seed,
                b.rotation_deg,
                b.reverse,
                b.feed_mm_s,
                b.force_n
            )
        );
        assert_eq!(a.ambient_offset_k, b.ambient_offset_k);
        assert!(
            b.controller
                .contains("mlp.min0.5.seed1.round0 compensating"),
            "{}",
            b.controller
        );
        // The corrections moved the joints: the recordings differ.
        assert_ne!(
            std::fs::read(&open).unwrap(),
            std::fs::read(&closed).unwrap()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
