//! The training CLI end to end on a short twin session: `train` writes the checkpoint,
//! state, CSV log and loss plot; `--resume` continues to the same losses as an
//! uninterrupted run; `predict` writes residuals with metrics; `refine` writes the
//! refined model and the accumulated-error table; configs are checked field by field.

mod common;

use std::path::{Path, PathBuf};

use common::cli;
use iastgcn::train::RunConfig;

const TINY: &str =
    "[model]\nwindow = 16\nchannels = 4\nblocks = 2\nhidden = 8\n\n[data]\nstride = 5\n\n\
[train]\nbatch = 32\nlr = 3e-3\nmax_epochs = 2\n\n[refine]\nmagnifications = [5]\nmax_epochs = 1\n";

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The `train_loss,val_loss` columns of a log.
fn losses(log: &Path) -> Vec<String> {
    std::fs::read_to_string(log)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').skip(3).take(2).collect::<Vec<_>>().join(","))
        .collect()
}

#[test]
fn train_resume_predict_refine() {
    let dir: PathBuf = std::env::temp_dir().join(format!("iastgcn-cli-{}", std::process::id()));
    let (cal, recs) = common::twin_session(&dir, &["grid", "hilbert"], 40.0);
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let f = |name: &str| dir.join(name);
    let data: Vec<&str> = recs.iter().map(|p| s(p)).collect();
    let train = |out: &Path, extra: &[&str]| {
        let mut args = vec!["train", "--config", s(&config), "--calibration", s(&cal)];
        args.extend(["--out", s(out), "--data"]);
        args.extend(&data);
        args.extend(extra);
        cli(&args)
    };

    // Uninterrupted: two epochs, on a machine without any GPU driver (the native path,
    // said once); the runs below on the adapter (lavapipe: the native path as well) must
    // repeat its losses and its checkpoint bit for bit.
    let straight = f("straight.safetensors");
    let mut args = vec!["train", "--config", s(&config), "--calibration", s(&cal)];
    args.extend(["--out", s(&straight), "--data"]);
    args.extend(&data);
    let (text, stderr) = common::cli_without_gpu(&args);
    assert!(text.contains("test split"), "{text}");
    assert_eq!(stderr.matches(common::NATIVE_NOTE).count(), 1, "{stderr}");
    for suffix in [
        ".safetensors",
        ".state.safetensors",
        ".log.csv",
        ".loss.png",
    ] {
        assert!(f(&format!("straight{suffix}")).exists(), "straight{suffix}");
    }
    let want = losses(&f("straight.log.csv"));
    assert_eq!(want.len(), 2);

    // Interrupted after one epoch, then resumed to two.
    let m = f("m.safetensors");
    train(&m, &["--max-epochs", "1"]);
    assert_eq!(losses(&f("m.log.csv")), want[..1]);
    let text = train(
        &m,
        &[
            "--max-epochs",
            "2",
            "--resume",
            s(&f("m.state.safetensors")),
        ],
    );
    assert!(text.contains("resumed"), "{text}");
    assert_eq!(
        losses(&f("m.log.csv")),
        want,
        "the resumed run repeats the uninterrupted one"
    );

    // Killed (SIGKILL) in the middle of its second epoch, after the first epoch's
    // files were written: what it left loads, and --resume finishes the run exactly
    // as the uninterrupted one did.
    let k = f("k.safetensors");
    let mut args: Vec<String> = ["train", "--config", s(&config), "--calibration", s(&cal)]
        .iter()
        .map(|a| a.to_string())
        .collect();
    args.extend(["--out".into(), s(&k).into(), "--data".into()]);
    args.extend(data.iter().map(|d| d.to_string()));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(&args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let state = f("k.state.safetensors");
    let began = std::time::Instant::now();
    // The plot is the last of an epoch's files to be put in place.
    while !f("k.loss.png").exists() {
        assert!(began.elapsed().as_secs() < 300, "no state after 5 minutes");
        assert!(
            child.try_wait().unwrap().is_none(),
            "finished before the kill"
        );
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    iastgcn::model::Checkpoint::load(&k).expect("the checkpoint left behind loads");
    iastgcn::train::TrainState::load(&state).expect("the state left behind loads");
    assert_eq!(losses(&f("k.log.csv")), want[..1]);
    let text = train(&k, &["--resume", s(&state)]);
    assert!(text.contains("resumed"), "{text}");
    assert_eq!(
        losses(&f("k.log.csv")),
        want,
        "killed and resumed = uninterrupted"
    );
    assert_eq!(
        std::fs::read(&k).unwrap(),
        std::fs::read(f("straight.safetensors")).unwrap(),
        "the same best checkpoint, bit for bit"
    );

    // A state from another config is refused, naming the file.
    std::fs::write(&config, TINY.replace("channels = 4", "channels = 5")).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args([
            "train",
            "--config",
            s(&config),
            "--calibration",
            s(&cal),
            "--out",
        ])
        .arg(f("other.safetensors"))
        .args(["--resume", s(&f("m.state.safetensors")), "--data"])
        .args(&data)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains("m.state.safetensors")
            && err.contains("another config"),
        "{err}"
    );
    std::fs::write(&config, TINY).unwrap();

    // Predict on the test split: one row per window end, labels where the tracker measured.
    let res = f("res.csv");
    let mut args = vec![
        "predict",
        "--model",
        s(&m),
        "--calibration",
        s(&cal),
        "--out",
        s(&res),
    ];
    args.extend(["--split", "test", "--stride", "7", "--data"]);
    args.extend(&data);
    let (text, _) = common::cli_without_gpu(&args);
    assert!(text.contains("all") && text.contains('%'), "{text}");
    let csv = std::fs::read_to_string(&res).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header.len(), 15);
    assert_eq!(&header[..4], ["recording", "row", "t", "pred_dx_um"]);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(rows.len() > 10);
    assert!(rows
        .iter()
        .all(|r| r.len() == 15 && r[3].parse::<f64>().is_ok()));

    // All or nothing: when the plot cannot be written (its path is a folder), the
    // CSV is not replaced either, and no temporary file stays behind.
    let blocked = f("blocked.csv");
    std::fs::write(&blocked, "old").unwrap();
    std::fs::create_dir_all(f("blocked.png")).unwrap();
    args[6] = s(&blocked);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(&args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("blocked.png"), "{err}");
    assert_eq!(std::fs::read_to_string(&blocked).unwrap(), "old");
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    // A baseline trains from the CLI the same way; ann-bfpa runs its seeded search first,
    // and the same seed on the same data gives the same weights bit for bit.
    let bfpa = f("bfpa.safetensors");
    let text = train(&bfpa, &["--variant", "ann-bfpa"]);
    assert!(
        text.contains("flower-pollination search") && text.contains("test split"),
        "{text}"
    );
    // "… loss A at the He initialisation, B at the pick": the pick is never worse.
    let line = text.lines().find(|l| l.contains("at the pick")).unwrap();
    let number = |before: &str| -> f64 {
        let head = &line[..line.find(before).unwrap()];
        head.rsplit(' ').nth(1).unwrap().parse().unwrap()
    };
    let (start, pick) = (number("at the He"), number("at the pick"));
    assert!(pick <= start && pick.is_finite(), "{line}");
    let ck = iastgcn::model::Checkpoint::load(&bfpa).unwrap();
    assert_eq!(ck.config.variant, iastgcn::model::Variant::AnnBfpa);
    let again = f("bfpa2.safetensors");
    train(&again, &["--variant", "ann-bfpa"]);
    let ck2 = iastgcn::model::Checkpoint::load(&again).unwrap();
    assert!(
        ck2.parameters == ck.parameters,
        "the search is reproducible"
    );
    assert!(
        rows.iter().any(|r| r[9].parse::<f64>().is_ok()),
        "some windows are labelled"
    );
    // The spatio-temporal baselines too (the recurrent time loops and ST-GAT's graph
    // attention), and the checkpoint says which.
    for variant in ["convlstm", "tgcn", "eat-gcn", "st-gat"] {
        let out = f(&format!("{variant}.safetensors"));
        let text = train(&out, &["--variant", variant]);
        assert!(text.contains("test split"), "{variant}: {text}");
        let ck = iastgcn::model::Checkpoint::load(&out).unwrap();
        assert_eq!(ck.config.variant.name(), variant);
        assert!(ck
            .parameters
            .get("head.weight")
            .iter()
            .all(|v| v.is_finite()));
    }

    // Refine: one stage of ensembles of 5.
    let refined = f("refined.safetensors");
    let mut args = vec![
        "refine",
        "--model",
        s(&m),
        "--config",
        s(&config),
        "--calibration",
        s(&cal),
    ];
    args.extend(["--out", s(&refined), "--data"]);
    args.extend(&data);
    let text = cli(&args);
    assert!(text.contains("accumulated error"), "{text}");
    let acc = std::fs::read_to_string(f("refined.accumulated.csv")).unwrap();
    assert!(acc.starts_with("horizon,pos_before_um"));
    assert!(acc.lines().count() > 5);
    assert!(f("refined.accumulated.png").exists());
    iastgcn::model::Checkpoint::load(&refined).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A run that early stopping ended: resuming it says why nothing more trains and which
/// flag to raise; `--patience` continues it; `--max-epochs` counts every epoch of the run.
#[test]
fn resume_says_why_nothing_trains_and_patience_continues() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("iastgcn-cli-patience-{}", std::process::id()));
    let (cal, recs) = common::twin_session(&dir, &["grid", "hilbert"], 40.0);
    let config = dir.join("patience.toml");
    // Patience 1: the first epoch without a better validation loss ends the run, long
    // before the epoch limit.
    std::fs::write(
        &config,
        TINY.replace("max_epochs = 2\n\n", "max_epochs = 200\npatience = 1\n\n"),
    )
    .unwrap();
    let out = dir.join("m.safetensors");
    let (state, log) = (dir.join("m.state.safetensors"), dir.join("m.log.csv"));
    let train = |extra: &[&str]| {
        let mut args = vec!["train", "--config", s(&config), "--calibration", s(&cal)];
        args.extend(["--out", s(&out), "--data"]);
        args.extend(recs.iter().map(|p| s(p)));
        args.extend(extra);
        cli(&args)
    };

    let text = train(&[]);
    let n = losses(&log).len();
    assert!(n < 200, "patience 1 did not stop the run: {text}");
    let why = format!("patience ran out at epoch {n} (1 epoch without a better validation loss");
    assert!(text.contains(&format!("stopped: {why}")), "{text}");

    // A larger epoch limit alone trains nothing, and says so.
    let before = std::fs::read_to_string(&log).unwrap();
    let text = train(&["--max-epochs", "300", "--resume", s(&state)]);
    assert!(
        text.contains(&format!("nothing more to train: {why}"))
            && text.contains("set --patience above 1")
            && !text.contains("training iastgcn on"),
        "{text}"
    );
    assert_eq!(std::fs::read_to_string(&log).unwrap(), before);

    // --patience continues it: two more epochs, up to the total of n + 2.
    let total = (n + 2).to_string();
    let text = train(&[
        "--patience",
        "3",
        "--max-epochs",
        &total,
        "--resume",
        s(&state),
    ]);
    assert!(text.contains("resumed"), "{text}");
    let after = std::fs::read_to_string(&log).unwrap();
    assert_eq!(losses(&log).len(), n + 2, "{text}");
    assert!(
        after.starts_with(&before),
        "the resumed epochs follow the first ones"
    );
    let limit = format!(
        "the epoch limit is reached (epoch {total} of max_epochs = {total}, a total count)"
    );
    assert!(text.contains(&format!("stopped: {limit}")), "{text}");

    // The epoch limit is a total count: the same limit again trains nothing.
    let text = train(&[
        "--patience",
        "100",
        "--max-epochs",
        &total,
        "--resume",
        s(&state),
    ]);
    assert!(
        text.contains(&format!(
            "nothing more to train: {limit}; to continue, set --max-epochs above {total}"
        )),
        "{text}"
    );
    assert_eq!(std::fs::read_to_string(&log).unwrap(), after);

    // Zero patience is refused by the flag's name.
    let mut args = vec!["train", "--patience", "0", "--calibration", s(&cal)];
    args.extend(["--out", s(&out), "--data", s(&recs[0])]);
    let err = common::cli_fails(&args);
    assert!(err.contains("--patience"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn run_configs_have_defaults_and_checks() {
    let demo = RunConfig::demo();
    assert_eq!(demo.model.window, 48);
    let paper = RunConfig::parse(include_str!("../assets/paper.toml"), "paper.toml").unwrap();
    assert_eq!(
        paper,
        RunConfig::default(),
        "paper.toml spells out the defaults"
    );
    // Equal values are not enough: docs/usage.md says every field is written out there,
    // so a field left to its default (as `heads` and `joint_inputs` once were) fails.
    let spelled: toml::Table = include_str!("../assets/paper.toml").parse().unwrap();
    let defaults = toml::Table::try_from(RunConfig::default()).unwrap();
    for (table, fields) in &defaults {
        let fields = fields.as_table().expect("a run config's tables");
        let written = spelled.get(table).and_then(|t| t.as_table());
        for field in fields.keys() {
            assert!(
                written.is_some_and(|t| t.contains_key(field)),
                "assets/paper.toml does not spell out [{table}] {field}"
            );
        }
    }
    let empty = RunConfig::parse("", "empty.toml").unwrap();
    assert_eq!(empty, RunConfig::default());
    for (text, needle) in [
        ("[train]\nlr = -1.0\n", "train.lr"),
        ("[train]\nbatch = 0\n", "train.batch"),
        ("[data]\nsplit = \"shuffled\"\n", "data.split"),
        ("[refine]\nmagnifications = [1]\n", "refine.magnifications"),
        ("[model]\nchannels = 0\n", "channels"),
        ("[model]\nwindow = 1000000000\n", "window = 1000000000"),
        ("[model]\nchannels = 1000000000\n", "channels = 1000000000"),
        // Within each size's bound, but a C×C mix per block: 10^10 parameters.
        (
            "[model]\nchannels = 100000\n",
            "parameters (window = 100, channels = 100000",
        ),
        ("[model]\nwindow = 100000\n", "parameters (window = 100000"),
        ("[data]\ntrain_fraction = 0\n", "data.train_fraction"),
        (
            "[data]\nvalidation_fraction = 1.5\n",
            "data.validation_fraction",
        ),
        ("[train]\nlearning_rate = 1e-3\n", "learning_rate"),
        ("[training]\n", "training"),
    ] {
        let e = RunConfig::parse(text, "bad.toml").unwrap_err().to_string();
        assert!(
            e.starts_with("bad.toml") && e.contains(needle),
            "{text:?}: {e}"
        );
    }
}

/// A fresh folder `<prefix>-<pid>` in the temporary directory with `tiny.toml`, the tiny
/// config at one epoch and one short refinement stage: the demo tests' budget.
fn tiny_demo_config(prefix: &str) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("{prefix}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("tiny.toml");
    std::fs::write(
        &config,
        TINY.replace("max_epochs = 2\n", "max_epochs = 1\n")
            .replace("magnifications = [5]", "magnifications = [3]"),
    )
    .unwrap();
    (dir, config)
}

/// `iastgcn demo --all-models` end to end at a tiny size with one training seed: every
/// stage runs, every model is trained, and the report folder has the two tables with the
/// promised columns and rows.
#[test]
fn demo_writes_the_report() {
    let (dir, config) = tiny_demo_config("iastgcn-demo");
    let out = dir.join("report");
    // One training session, as the paper records it, open loop (the demo's default recipe
    // is `demo_over_seeds_reports_the_spread`'s), on a machine without any GPU driver:
    // every model trains and predicts on the native path.
    let args = |open_loop: bool| {
        let mut a = vec![
            "demo",
            "--config",
            s(&config),
            "--minutes",
            "0.5",
            "--sessions",
            "1",
            "--placement",
            "fixed",
            "--held-out-minutes",
            "0.1",
            "--all-models",
            "--seeds",
            "1",
            "--mirror-iterations",
            "0",
            "--out",
            s(&out),
        ];
        if open_loop {
            a.push("--open-loop");
        }
        a
    };
    // Closed-loop data (the default) need a second half of the sessions to record again:
    // refused before any work, the flags named.
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(args(false))
        .output()
        .unwrap();
    let why = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success()
            && why.contains("--sessions: closed-loop data")
            && why.contains("got 1")
            && why.contains("--open-loop")
            && !out.exists(),
        "{why}"
    );
    let (text, stderr) = common::cli_without_gpu(&args(true));
    assert!(text.contains("demo finished"), "{text}");
    assert_eq!(stderr.matches(common::NATIVE_NOTE).count(), 1, "{stderr}");
    assert!(
        !out.join("polish").exists(),
        "the mirror was asked to stay out"
    );
    let table_v = std::fs::read_to_string(out.join("table_v.csv")).unwrap();
    let mut lines = table_v.lines();
    assert_eq!(
        lines.next().unwrap(),
        "trajectory,held_out_session,stage,model,\
         true_pos_mean_um,true_pos_sd_um,true_pos_max_um,true_att_mean_mdeg,true_att_sd_mdeg,true_att_max_mdeg,\
         trk_pos_mean_um,trk_pos_sd_um,trk_pos_max_um,trk_att_mean_mdeg,trk_att_sd_mdeg,trk_att_max_mdeg"
    );
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    // Per held-out session (3) and path (the three trained ones placed anew, and the
    // rosette): initial, calibrated, the oracle, and the 12 models (each refined or kept):
    // IASTGCN, its three ablations, the four dense baselines and the four spatio-temporal
    // ones.
    assert_eq!(rows.len(), 3 * 4 * 15);
    let value = |r: &Vec<String>, i: usize| r[i].parse::<f64>().unwrap();
    for (session, path) in ["0", "1", "2"]
        .into_iter()
        .flat_map(|k| ["grid", "fermat", "hilbert", "rosette"].map(|p| (k, p)))
    {
        let of = |stage: &str| {
            rows.iter()
                .filter(|r| r[0] == path && r[1] == session && r[2] == stage)
                .collect::<Vec<_>>()
        };
        assert_eq!(
            [
                of("initial").len(),
                of("calibrated").len(),
                of("oracle").len(),
                of("compensated").len()
            ],
            [1, 1, 1, 12],
            "{path}"
        );
        // On the hidden truth, the true residual fed back at a model's rate and latency
        // beats calibration alone in position and attitude.
        let (cal, oracle) = (of("calibrated")[0], of("oracle")[0]);
        // The tiny models do not look ahead, nor does the oracle that stands in for them
        // (a look-ahead one: tests/open_loop.rs).
        assert_eq!(oracle[3], "true residual");
        assert!(
            value(oracle, 4) < value(cal, 4),
            "{path}: {oracle:?} vs {cal:?}"
        );
        assert!(
            value(oracle, 7) < value(cal, 7),
            "{path}: {oracle:?} vs {cal:?}"
        );
    }
    assert!(rows
        .iter()
        .all(|r| r[4..].iter().all(|v| v.parse::<f64>().unwrap().is_finite())));
    // Refinement keeps the refined weights only where they lower the per-window
    // validation loss, and the model the tables use is then the refined file; where it
    // keeps the core weights, that file holds the core weights exactly.
    let mut kept = [0, 0];
    for line in text
        .lines()
        .filter(|l| l.contains(": refinement per-window"))
    {
        let name = line.split(": refinement").next().unwrap().trim();
        let nums: Vec<f64> = line
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .filter_map(|w| w.parse().ok())
            .collect();
        let (before, after) = (nums[0], nums[1]);
        let weights = |file: String| {
            iastgcn::model::Checkpoint::load(&out.join("models").join(file))
                .unwrap()
                .parameters
                .values
        };
        let same =
            weights(format!("{name}.safetensors")) == weights(format!("{name}.core.safetensors"));
        if line.ends_with("kept the core model") {
            assert!(same && after == before, "{line}");
            kept[0] += 1;
        } else {
            assert!(
                line.ends_with("kept the refined model") && !same && after < before,
                "{line}"
            );
            kept[1] += 1;
        }
    }
    assert_eq!(kept[0] + kept[1], 12, "{text}");
    // Every recording has its own seed, written beside it.
    let seeds: Vec<u64> = ["calibration_set", "grid", "fermat", "hilbert"]
        .iter()
        .map(|n| {
            iastgcn::twin::RunInfo::read(&out.join(format!("data/{n}.csv")))
                .unwrap()
                .seed
        })
        .collect();
    let mut distinct = seeds.clone();
    distinct.sort_unstable();
    distinct.dedup();
    assert_eq!(distinct.len(), seeds.len(), "{seeds:?}");
    let hilbert = iastgcn::twin::RunInfo::read(&out.join("data/hilbert.csv")).unwrap();
    assert_eq!(hilbert.start, "warm");
    assert!(hilbert.controller.ends_with("calibration.toml"));
    let table_iii = std::fs::read_to_string(out.join("table_iii.csv")).unwrap();
    assert!(table_iii.starts_with(
        "trajectory,model,pos_mae_um,pos_rmse_um,pos_mape_pct,att_mae_mdeg,att_rmse_mdeg,att_mape_pct\n"
    ));
    assert!(table_iii.contains("hilbert,iastgcn-s,") && table_iii.contains("training mean"));
    for baseline in iastgcn::model::Variant::ALL.map(|v| v.name()) {
        assert!(
            table_iii.contains(&format!("hilbert,{baseline},")),
            "{baseline} in Table III"
        );
    }
    for f in [
        "compensated.png",
        "report.md",
        "fig11_hilbert.png",
        "fig10_timings.png",
        "losses.png",
        "accumulated.png",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    // docs/usage.md "Checkpoint names": the refined model under the model's name, the
    // core stage beside it.
    for f in [
        "iastgcn.safetensors",
        "iastgcn.core.safetensors",
        "iastgcn.core.state.safetensors",
    ] {
        assert!(out.join("models").join(f).exists(), "{f}");
    }
    assert!(!out.join("models/iastgcn-refined.safetensors").exists());
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("and every baseline, all at the same budget"));
    assert!(
        report.contains(
            "open-loop data: every training session recorded under the calibrated controller alone"
        ) && !out.join("data/closed-loop").exists(),
        "{report}"
    );
    // The model to use, chosen on a validation session of its own (not in Table V).
    assert!(
        report.contains("## Recommended model") && report.contains("Recommended: **"),
        "{report}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The demo over two training seeds at a tiny size: every model trained with each seed
/// under its seeded name, the seeds giving different weights, the tables over seeds and
/// the paired comparisons written, the core stage summarised over seeds; a seed listed
/// twice is refused.
#[test]
fn demo_over_seeds_reports_the_spread() {
    let (dir, config) = tiny_demo_config("iastgcn-demo-seeds");
    let out = dir.join("report");
    let args = |seeds: &'static str| {
        vec![
            "demo".to_string(),
            "--config".into(),
            s(&config).into(),
            // The default recipe: 4 sessions of 0.25 min per path.
            "--minutes".into(),
            "1".into(),
            "--held-out-minutes".into(),
            "0.1".into(),
            "--warm-up-minutes".into(),
            "0".into(),
            "--seeds".into(),
            seeds.into(),
            "--mirror-iterations".into(),
            "1".into(),
            "--out".into(),
            s(&out).into(),
        ]
    };
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(args("1,2,1"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && stderr.contains("training seed 1 is listed twice"));

    let a = args("1,2");
    let text = cli(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(text.contains("demo finished"), "{text}");
    // Before any work, the plan and its forecast; after the first seed, its result, while
    // the second trains.
    let at = |needle: &str| {
        text.find(needle)
            .unwrap_or_else(|| panic!("{needle}: {text}"))
    };
    assert!(at("== the plan") < at("== 1/6"));
    // Its own config: no forecast (that is for the default demo), and it says so.
    assert!(at("time: no forecast for these settings") < at("== 1/6"));
    assert!(at("== training seed 1") < at("first result, after"));
    assert!(at("first result, after") < at("== training seed 2"));
    let models: Vec<&str> = iastgcn::model::Variant::IASTGCN
        .into_iter()
        .chain(iastgcn::model::Variant::DENSE)
        .map(|v| v.name())
        .collect();
    let table_v = std::fs::read_to_string(out.join("table_v.csv")).unwrap();
    for model in &models {
        for seed in [1, 2] {
            let name = format!("{model}.seed{seed}");
            for f in [
                format!("{name}.safetensors"),
                format!("{name}.core.safetensors"),
            ] {
                assert!(out.join("models").join(&f).exists(), "{f}");
            }
            for session in 0..3 {
                assert!(
                    table_v.contains(&format!("hilbert,{session},compensated,{name},")),
                    "{name}"
                );
            }
        }
    }
    let weights = |seed: u64| {
        iastgcn::model::Checkpoint::load(
            &out.join(format!("models/iastgcn.seed{seed}.safetensors")),
        )
        .unwrap()
        .parameters
        .values
    };
    assert_ne!(weights(1), weights(2), "the seeds trained the same weights");
    for f in ["table_v_seeds.csv", "table_iii_seeds.csv", "paired.csv"] {
        assert!(out.join(f).exists(), "{f}");
    }
    let paired = std::fs::read_to_string(out.join("paired.csv")).unwrap();
    assert!(
        paired.contains("iastgcn-s") && paired.contains("mlp"),
        "{paired}"
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Core training over seeds"), "{report}");
    for model in &models {
        assert!(
            report.contains(&format!("| {model} | 2 | ")),
            "{model} over 2 seeds"
        );
    }
    assert!(report.contains("training seeds 1, 2"));
    assert!(
        report.contains("recipe: use-like, the default (4 cold sessions at spread placements"),
        "{report}"
    );
    // The mirror: one surface polished under each controller (the tiny models remove no
    // error on validation, so none is recommended and none compensates).
    assert!(
        report.contains("## The mirror (Table VI)") && report.contains("No model was recommended"),
        "{report}"
    );
    let polish = std::fs::read_to_string(out.join("polish/polish.csv")).unwrap();
    assert!(!polish.contains(",compensated ("), "{polish}");
    // No recommended model, so no ensemble to calibrate an interval for (the section
    // itself: tests/held_out_studies.rs).
    assert!(!report.contains("## Confidence"), "{report}");
    assert!(std::fs::read_dir(out.join("models")).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(".ensemble.toml")));
    for controller in ["nominal", "calibrated", "oracle", "perfect machine"] {
        assert!(
            polish.contains(&format!(",{controller}")),
            "{controller}: {polish}"
        );
    }
    for f in [
        "polish/convergence.png",
        "polish/maps.png",
        "polish/sweep/map.png",
        "polish/sweep/sweep.csv",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    // When compensation pays on the demo's pad: every kind under both floats, this run's
    // calibrated controller marked (the nominal's too; no model compensated).
    assert!(
        report.contains("### When compensation pays on this pad")
            && report.contains("| slow, ideal float |")
            && report.contains("| white, float 4 N/mm, seal 3 N |")
            && report.contains("This run's controllers showed the glass: nominal (")
            && report.contains(", calibrated ("),
        "{report}"
    );
    // Closed-loop data (the default): a round-0 IASTGCN trained on sessions 1-2 recorded
    // sessions 3-4 again at every tick, and those recordings, not the open-loop ones of
    // the same sessions, trained every model.
    assert!(
        report.contains("closed-loop data: round 0 (iastgcn.seed1.round0) trained on sessions 1-2")
            && report.contains("prediction every 1 ticks"),
        "{report}"
    );
    assert!(out
        .join("models/iastgcn.seed1.round0.core.safetensors")
        .exists());
    for session in [3, 4] {
        let recorded = out.join(format!("data/closed-loop/hilbert.s0{session}.csv"));
        let info = iastgcn::twin::RunInfo::read(&recorded).unwrap();
        assert!(
            info.controller
                .ends_with("with iastgcn.seed1.round0 compensating (every 1 ticks)"),
            "{}",
            info.controller
        );
        let open = iastgcn::twin::RunInfo::read(&out.join(format!("data/hilbert.s0{session}.csv")))
            .unwrap();
        assert_eq!(info.seed, open.seed, "the same run recorded again");
    }
    // The default recipe and the three held-out sessions of Table V, named in the setup.
    assert!(
        report.contains("1 min per path in 4 session(s)")
            && report.contains("3 held-out session(s) (1: cold, ambient +0.00 K")
            && report.contains("| hilbert, session 3 | calibrated |"),
        "{report}"
    );
    let mixing = report
        .split("## Graph convolution after training")
        .nth(1)
        .expect("the graph convolution's table");
    let mixing = mixing.split("\n## ").next().unwrap();
    assert!(mixing.contains("| iastgcn.seed1 | 0.") && mixing.contains("| iastgcn-s.seed2 | 0."));
    assert!(!mixing.contains("mlp"), "{mixing}");

    // A demo folder written before the one naming scheme: its refined models,
    // `<model>.seed<k>-refined`, are the seeded models for `evaluate`'s tables over seeds.
    let old = dir.join("old");
    std::fs::create_dir_all(&old).unwrap();
    let mut refined = Vec::new();
    for model in ["iastgcn", "mlp"] {
        for seed in [1, 2] {
            let to = old.join(format!("{model}.seed{seed}-refined.safetensors"));
            std::fs::copy(
                out.join(format!("models/{model}.seed{seed}.safetensors")),
                &to,
            )
            .unwrap();
            refined.push(s(&to).to_string());
        }
    }
    let evaluated = dir.join("evaluated");
    let data = out.join("data");
    let evaluate = |models: &[String]| {
        let mut a: Vec<String> = ["evaluate", "--config", s(&config), "--calibration"]
            .map(String::from)
            .into();
        a.push(s(&data.join("calibration.toml")).into());
        a.extend(
            [
                "--held-out-minutes",
                "0.1",
                "--warm-up-minutes",
                "0",
                "--every",
                "1",
                "--out",
            ]
            .map(String::from),
        );
        a.push(s(&evaluated).into());
        a.push("--data".into());
        for k in 1..=4 {
            for p in ["grid", "fermat", "hilbert"] {
                a.push(s(&data.join(format!("{p}.s0{k}.csv"))).into());
            }
        }
        a.push("--models".into());
        a.extend(models.iter().cloned());
        // With no GPU driver: evaluation runs on the native path.
        common::run(
            &a.iter().map(String::as_str).collect::<Vec<_>>(),
            &common::NO_DRIVER,
        )
    };
    // The old core file beside its refined one is the same model twice: refused at once.
    let core = old.join("iastgcn.seed1.safetensors");
    std::fs::copy(out.join("models/iastgcn.seed1.core.safetensors"), &core).unwrap();
    let began = std::time::Instant::now();
    let o = evaluate(&[refined[0].clone(), s(&core).to_string()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains("--models")
            && err.contains("iastgcn.seed1-refined.safetensors")
            && err.contains("are both the model iastgcn.seed1"),
        "{err}"
    );
    assert!(
        began.elapsed().as_secs_f64() < 2.0,
        "refused only after {:?}",
        began.elapsed()
    );
    let o = evaluate(&refined);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert_eq!(stderr.matches(common::NATIVE_NOTE).count(), 1, "{stderr}");
    // The demo evaluated each seed's models as they were trained (the second seed's on
    // the first seed's runs, [`more_models`]); `evaluate` runs these four together on
    // the same held-out sessions: every row the same, bit for bit.
    let evaluated_v = std::fs::read_to_string(evaluated.join("table_v.csv")).unwrap();
    let rows: Vec<&str> = evaluated_v.lines().skip(1).collect();
    assert_eq!(rows.len(), 3 * 4 * (3 + 4), "{evaluated_v}");
    for row in rows {
        assert!(table_v.lines().any(|l| l == row), "{row} is not the demo's");
    }
    assert!(evaluated_v.contains("hilbert,2,compensated,mlp.seed2,"));
    for f in ["table_v_seeds.csv", "table_iii_seeds.csv", "paired.csv"] {
        assert!(evaluated.join(f).exists(), "{f}");
    }

    // An interrupted demo continues: as if it had stopped while seed 2's MLP trained (no
    // job record, no state file, no weights), the same command trains that model alone
    // and keeps every other one; the tables, the loss curves and Fig. 9b come out the same
    // byte for byte.
    let tables = [
        "table_v.csv",
        "table_iii.csv",
        "losses.csv",
        "accumulated.csv",
        "paired.csv",
    ];
    let before: Vec<String> = tables
        .iter()
        .map(|f| std::fs::read_to_string(out.join(f)).unwrap())
        .collect();
    let pinned = out.join("demo.toml");
    let setup = std::fs::read_to_string(&pinned).unwrap();
    assert!(setup.contains("finished = true"), "{setup}");
    std::fs::write(
        &pinned,
        setup.replace("finished = true", "finished = false"),
    )
    .unwrap();
    for f in [
        "mlp.seed2.job.toml",
        "mlp.seed2.core.state.safetensors",
        "mlp.seed2.safetensors",
    ] {
        std::fs::remove_file(out.join("models").join(f)).unwrap();
    }
    let text = cli(&a.iter().map(String::as_str).collect::<Vec<_>>());
    for needle in [
        "continuing the unfinished demo",
        "15 of 16 models already trained",
        "8 of seed 1's 8 models trained by the unfinished run",
        "7 of seed 2's 8 models trained by the unfinished run",
        "mlp.seed2: best validation loss",
        "demo finished",
    ] {
        assert!(text.contains(needle), "{needle}: {text}");
    }
    assert!(
        !text.contains("iastgcn.seed2: best validation loss"),
        "{text}"
    );
    for (f, was) in tables.iter().zip(&before) {
        assert_eq!(&std::fs::read_to_string(out.join(f)).unwrap(), was, "{f}");
    }
    assert!(std::fs::read_to_string(&pinned)
        .unwrap()
        .contains("finished = true"));
    std::fs::remove_dir_all(&dir).unwrap();
}
