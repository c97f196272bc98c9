//! The studies on the twin's held-out sessions (issue 73). The morning minute
//! (docs/model.md "The morning minute"): an offset moves the output bias alone and
//! removes the mean miss on the adapting windows; a fine-tune repeats bit for bit with its
//! seed; the judge keeps the trained weights when adapting makes the judging windows
//! worse; a recording too short is refused; and the CLI's `adapt` and `morning` run end
//! to end, refusing a bad method by name. Confidence (docs/results.md "Confidence"), on
//! the same twin session and two seeds: `confidence` calibrates its intervals on the
//! validation session, where they cover at least their level, writes the ensemble file
//! with the radius per quantity that covers it, which a predictor loads and applies, and
//! refuses a model of one seed. The look-ahead floor (docs/results.md "The look-ahead floor"): `floor` writes
//! both oracles for every path.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use iastgcn::compensate::{Ensemble, EnsembleFile};
use iastgcn::data::{DataSources, SplitMode, WindowConfig};
use iastgcn::experiment::confidence;
use iastgcn::gpu::Device;
use iastgcn::model::{Checkpoint, ModelConfig, Parameters, Variant};
use iastgcn::progress::Silent;
use iastgcn::testing::gpu;
use iastgcn::train::{self, AdaptConfig, Adaptation, RunConfig, Stage, Trainer};

fn model() -> ModelConfig {
    ModelConfig {
        variant: Variant::Iastgcn,
        window: 16,
        channels: 6,
        blocks: 2,
        ..ModelConfig::default()
    }
}

/// A twin session (grid: the training, fermat: the morning) and a model trained two
/// epochs on the grid with seed 1 (and one with seed 2), once per test binary.
struct Fixture {
    dir: PathBuf,
    calibration: PathBuf,
    grid: PathBuf,
    fermat: PathBuf,
    trained: Checkpoint,
    seed2: Checkpoint,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("iastgcn-adapt-{}", std::process::id()));
        let (calibration, paths) = common::twin_session(&dir, &["grid", "fermat"], 40.0);
        let sources = DataSources {
            recordings: vec![paths[0].clone()],
            calibration: calibration.clone(),
            graph: None,
            robot: None,
        };
        let window = WindowConfig {
            length: 16,
            stride: 5,
            ..WindowConfig::default()
        };
        let (graph, data) = sources
            .dataset(&window, SplitMode::Contiguous, None)
            .unwrap();
        let device = Device::from(gpu());
        let fit = |seed: u64| {
            let mut config = run_config();
            config.train.seed = seed;
            let stage = Stage {
                max_epochs: 2,
                ..train::core_stage(&config)
            };
            let mut t = Trainer::new(
                &device,
                &data,
                &graph,
                &config.model,
                &config.train,
                stage,
                &Parameters::init(&config.model, seed),
            )
            .unwrap();
            while !t.finished() {
                t.run_epoch().unwrap();
            }
            train::checkpoint(&config.model, &graph, &t.best, &data.normalization)
        };
        let (trained, seed2) = (fit(1), fit(2));
        Fixture {
            dir,
            calibration,
            grid: paths[0].clone(),
            fermat: paths[1].clone(),
            trained,
            seed2,
        }
    })
}

fn run_config() -> RunConfig {
    let mut config = RunConfig {
        model: model(),
        ..RunConfig::default()
    };
    config.train.batch = 32;
    config.train.lr = 3e-3;
    config
}

fn morning(f: &Fixture) -> DataSources {
    DataSources {
        recordings: vec![f.fermat.clone()],
        calibration: f.calibration.clone(),
        graph: None,
        robot: None,
    }
}

fn adapt(method: Adaptation) -> train::Adapted {
    let f = fixture();
    let device = Device::from(gpu());
    let how = AdaptConfig::new(method, &run_config());
    train::adapt(&device, &morning(f), &f.trained, &how, &mut Silent).unwrap()
}

#[test]
fn an_offset_moves_the_output_bias_alone_and_removes_the_mean_miss() {
    let f = fixture();
    let a = adapt(Adaptation::Offset);
    eprintln!("{}", a.verdict());
    let specs = &f.trained.parameters.specs;
    let bias = f.trained.parameters.index("head.bias").unwrap();
    let shifted = a.candidate.clone();
    for (i, spec) in specs.iter().enumerate() {
        let (before, after) = (&f.trained.parameters.values[i], &shifted.values[i]);
        if i == bias {
            assert_ne!(before, after, "the offset moves head.bias");
        } else {
            assert_eq!(before, after, "{} is left as trained", spec.name);
        }
    }
    // The shift in physical units is the mean miss on the adapting windows: after it,
    // the shifted model's mean miss there is zero (to f32 rounding).
    let miss = train::adapt::mean_miss(
        &Device::from(gpu()),
        &morning(f),
        &Checkpoint {
            parameters: shifted,
            ..f.trained.clone()
        },
        &AdaptConfig::new(Adaptation::Offset, &run_config()),
    )
    .unwrap();
    for (k, m) in miss.iter().enumerate() {
        assert!(m.abs() < 1e-3, "output {k}: mean miss {m} after the offset");
    }
    let before = train::adapt::mean_miss(
        &Device::from(gpu()),
        &morning(f),
        &f.trained,
        &AdaptConfig::new(Adaptation::Offset, &run_config()),
    )
    .unwrap();
    assert_eq!(
        before, a.offset,
        "the offset is the trained model's mean miss"
    );
    assert!(a.offset.iter().any(|o| o.abs() > 0.1), "{:?}", a.offset);
    assert_eq!(
        a.kept_trained,
        a.loss_after >= a.loss_before,
        "the judge keeps the adapted weights only when they lower its loss"
    );
}

#[test]
fn a_fine_tune_repeats_with_its_seed_and_the_judge_refuses_a_harmful_one() {
    let f = fixture();
    let method = Adaptation::FineTune {
        epochs: 3,
        lr: 1e-3,
    };
    let (a, b) = (adapt(method), adapt(method));
    eprintln!("{}", a.verdict());
    assert_eq!(a.params, b.params, "the same seed gives the same weights");
    assert_eq!(a.loss_after.to_bits(), b.loss_after.to_bits());
    assert!(!a.kept_trained, "{}", a.verdict());
    assert!(a.loss_after < a.loss_before);
    assert_ne!(a.params, f.trained.parameters);
    // Steps of size 1 throw the weights far: no epoch is better on the judging windows,
    // so the trained weights are kept.
    let wild = adapt(Adaptation::FineTune { epochs: 2, lr: 1.0 });
    eprintln!("{}", wild.verdict());
    assert!(wild.kept_trained, "{}", wild.verdict());
    assert!(wild.loss_after >= wild.loss_before);
    assert_eq!(wild.params, f.trained.parameters);
}

#[test]
fn a_recording_too_short_or_a_bad_setting_is_refused() {
    let f = fixture();
    let device = Device::from(gpu());
    let mut how = AdaptConfig::new(Adaptation::Offset, &run_config());
    how.stride = 400;
    let e = train::adapt(&device, &morning(f), &f.trained, &how, &mut Silent)
        .unwrap_err()
        .to_string();
    assert!(e.contains("record longer"), "{e}");
    how.stride = 5;
    how.judge = 0.9;
    let e = train::adapt(&device, &morning(f), &f.trained, &how, &mut Silent)
        .unwrap_err()
        .to_string();
    assert!(e.contains("adapt.judge"), "{e}");
    for bad in [
        "sideways",
        "fine-tune:0:1e-3",
        "fine-tune:3:-1",
        "fine-tune:3",
    ] {
        let e = bad.parse::<Adaptation>().unwrap_err();
        assert!(e.contains(bad), "{e}");
    }
    for good in [Adaptation::Offset, Adaptation::FINE_TUNE] {
        assert_eq!(good.to_string().parse::<Adaptation>().unwrap(), good);
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `command` on the fixture's machine and calibration, over one short held-out session
/// (and its validation session) that starts cold.
fn study<'a>(command: &'a str, f: &'a Fixture) -> Vec<&'a str> {
    vec![
        command,
        "--data",
        s(&f.grid),
        "--calibration",
        s(&f.calibration),
        "--held-out-sessions",
        "1",
        "--held-out-minutes",
        "0.1",
        "--warm-up-minutes",
        "0",
    ]
}

#[test]
fn the_cli_adapts_a_checkpoint_and_measures_the_morning_minute() {
    let f = fixture();
    let dir = f.dir.join("cli");
    std::fs::create_dir_all(&dir).unwrap();
    let trained = dir.join("tiny.seed1.safetensors");
    f.trained.save(&trained).unwrap();
    let adapted = dir.join("adapted.safetensors");
    let args = |method: &'static str| {
        [
            "adapt",
            "--data",
            s(&f.fermat),
            "--calibration",
            s(&f.calibration),
            "--model",
            s(&trained),
            "--method",
            method,
            "--out",
            s(&adapted),
        ]
    };
    let text = common::cli(&args("offset"));
    assert!(text.contains("offset") && text.contains("judged"), "{text}");
    Checkpoint::load(&adapted).unwrap();
    let e = common::cli_fails(&args("sideways"));
    assert!(e.contains("sideways"), "{e}");

    // The study on one scored session and its validation session, short runs.
    let out = dir.join("morning");
    let mut args = study("morning", f);
    args.extend([
        "--models",
        s(&trained),
        "--minutes",
        "0.25",
        "--methods",
        "offset,fine-tune:2:1e-3",
        "--out",
        s(&out),
    ]);
    let text = common::cli(&args);
    assert!(text.contains("The validation session favours"), "{text}");
    let md = std::fs::read_to_string(out.join("morning.md")).unwrap();
    for row in [
        "| tiny | none (as trained) |",
        "| tiny | offset |",
        "| tiny | fine-tune:2:1e-3 |",
    ] {
        assert!(md.contains(row), "{row} in\n{md}");
    }
    let adaptations = std::fs::read_to_string(out.join("adaptations.csv")).unwrap();
    // Two sessions (the scored one and the validation one) × two methods.
    assert_eq!(adaptations.lines().count(), 1 + 4, "{adaptations}");
    for k in [1, 2] {
        assert!(out.join(format!("morning.s{k}.csv")).exists());
    }
    let rows = std::fs::read_to_string(out.join("morning_table_v.csv")).unwrap();
    // Per session and path: initial, calibrated, oracle and three models.
    assert_eq!(rows.lines().count(), 1 + 2 * 4 * 6, "{rows}");
    // The same study again gives the same rows (the twin and the adaptation are seeded).
    let again = dir.join("again");
    let mut args2 = args.to_vec();
    let at = args2.len() - 1;
    args2[at] = s(&again);
    common::cli(&args2);
    assert_eq!(
        rows,
        std::fs::read_to_string(again.join("morning_table_v.csv")).unwrap()
    );
}

#[test]
fn confidence_calibrates_on_the_validation_session_and_needs_two_seeds() {
    let f = fixture();
    let dir = f.dir.join("confidence");
    std::fs::create_dir_all(&dir).unwrap();
    let (one, two) = (
        dir.join("tiny.seed1.safetensors"),
        dir.join("tiny.seed2.safetensors"),
    );
    f.trained.save(&one).unwrap();
    f.seed2.save(&two).unwrap();
    let out = dir.join("out");
    let mut args = study("confidence", f);
    args.extend(["--out", s(&out), "--models", s(&one)]);
    let e = common::cli_fails(&args);
    assert!(e.contains("one seed"), "{e}");
    args.push(s(&two));
    let text = common::cli(&args);
    assert!(text.contains("## tiny"), "{text}");
    let md = std::fs::read_to_string(out.join("confidence.md")).unwrap();
    for path in ["grid", "fermat", "hilbert", "rosette"] {
        assert!(md.contains(&format!("| {path} |")), "{md}");
    }
    // The gates in the loop: the model in full and at three limits.
    for gate in ["none", "q50", "q75", "q90"] {
        assert!(md.contains(&format!("| tiny | {gate} |")), "{md}");
    }
    // Every prediction of both sessions, with its miss and spread; on the validation
    // session (the second), each calibrated interval covers at least 90 % by construction.
    let csv = std::fs::read_to_string(out.join("ticks.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        // miss_um, miss_mdeg, spread_um, spread_mdeg, size_um, size_mdeg (after model,
        // session, path, tick).
        .map(|l| l.split(',').skip(4).map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() > 4 * 2 * 100, "{} predictions", rows.len());
    let validation: Vec<&Vec<f64>> = csv
        .lines()
        .skip(1)
        .zip(&rows)
        .filter(|(l, _)| l.split(',').nth(1) == Some("2"))
        .map(|(_, r)| r)
        .collect();
    assert!(validation.iter().all(|r| r[2] >= 0.0 && r[3] >= 0.0));
    // Every prediction corrects something: the twin's residuals are never zero.
    assert!(rows
        .iter()
        .all(|r| r.len() == 6 && r[4] > 0.0 && r[5] > 0.0));
    assert!(validation.iter().any(|r| r[2] > 0.0), "two seeds spread");
    for q in 0..2 {
        let pairs: Vec<(f64, f64)> = validation.iter().map(|r| (r[q], r[2 + q])).collect();
        for radius in [
            confidence::spread_scaled(&pairs, 0.9).unwrap(),
            confidence::constant(&pairs, 0.9).unwrap(),
        ] {
            let c = confidence::coverage(&radius, &pairs);
            // The CSV rounds to 3 decimals: a tie at the quantile may fall either side.
            assert!(c >= 0.89, "quantity {q}: {radius:?} covers {c}");
        }
    }
    // The ensemble file: both seeds, relative to it, and the radius per quantity that
    // covers the validation session; a predictor loads it and gives each prediction
    // that interval.
    let path = out.join("tiny.ensemble.toml");
    let file = EnsembleFile::read(&path).unwrap();
    assert_eq!(
        file.members,
        vec![
            PathBuf::from("../tiny.seed1.safetensors"),
            PathBuf::from("../tiny.seed2.safetensors")
        ]
    );
    let calibration = file.interval.expect("an interval");
    assert_eq!(calibration.level, 0.9);
    for (q, radius) in [calibration.position, calibration.attitude]
        .iter()
        .enumerate()
    {
        let pairs: Vec<(f64, f64)> = validation.iter().map(|r| (r[q], r[2 + q])).collect();
        assert!(
            radius.scale == 0.0 || radius.constant == 0.0,
            "one kind: {radius:?}"
        );
        let c = confidence::coverage(radius, &pairs);
        assert!(
            (0.89..0.95).contains(&c),
            "quantity {q}: {radius:?} covers {c}"
        );
    }
    let (mut ensemble, _) = Ensemble::load(&path, 0.02, None).unwrap();
    let n = ensemble.first().config().nodes;
    let frame: Vec<f64> = (0..n).map(|k| 20.0 + k as f64).collect();
    assert!(ensemble.interval().is_none());
    while !ensemble.push(&frame).unwrap() {}
    ensemble.predict_latest().unwrap().unwrap();
    let spread = ensemble.spread().unwrap();
    let interval = ensemble.interval().unwrap();
    assert_eq!(interval.level, 0.9);
    assert_eq!(interval.position_um, calibration.position.of(spread[0]));
    assert_eq!(interval.attitude_mdeg, calibration.attitude.of(spread[1]));
}

#[test]
fn the_floor_writes_both_oracles_for_every_path() {
    let f = fixture();
    let out = f.dir.join("floor");
    let mut args = study("floor", f);
    args.extend(["--out", s(&out)]);
    let text = common::cli(&args);
    assert!(text.contains("# The look-ahead floor"), "{text}");
    let csv = std::fs::read_to_string(out.join("floor.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 4, "{csv}");
    for r in &rows {
        let v: Vec<f64> = r[2..].iter().map(|x| x.parse().unwrap()).collect();
        // Calibrated, oracle, look-ahead: both oracles remove most of the error.
        assert!(v[2] < 0.3 * v[0] && v[4] < 0.3 * v[0], "{r:?}");
    }
    let e = common::cli_fails(&[
        "floor",
        "--data",
        s(&f.grid),
        "--calibration",
        s(&f.calibration),
        "--window",
        "0",
        "--out",
        s(&out),
    ]);
    assert!(e.contains("--window"), "{e}");
}

/// The demo's "Confidence" section: the seeds as one ensemble, recorded session by
/// session on every core, give the same section twice, and its ensemble file loads.
#[test]
fn the_reports_confidence_section_repeats_and_writes_the_ensemble_file() {
    use iastgcn::experiment::evaluate::HeldOutConfig;
    let f = fixture();
    let dir = f.dir.join("section");
    std::fs::create_dir_all(&dir).unwrap();
    let members: Vec<(PathBuf, Checkpoint)> = [&f.trained, &f.seed2]
        .iter()
        .enumerate()
        .map(|(i, ck)| {
            let path = dir.join(format!("tiny.seed{}.safetensors", i + 1));
            ck.save(&path).unwrap();
            (path, (*ck).clone())
        })
        .collect();
    let sources = DataSources {
        recordings: vec![f.grid.clone()],
        calibration: f.calibration.clone(),
        graph: None,
        robot: None,
    };
    let held = HeldOutConfig {
        minutes: 0.1,
        warm_up_minutes: 0.0,
        sessions: 2,
        ..HeldOutConfig::default()
    };
    let device = Device::from(gpu());
    let section = || {
        confidence::ensemble_section(
            &device,
            "tiny",
            &members,
            &sources,
            &held,
            confidence::LEVEL,
            &dir,
            &mut Silent,
        )
        .unwrap()
    };
    let first = section();
    for path in ["grid", "fermat", "hilbert", "rosette"] {
        assert!(first.contains(&format!("| {path} |")), "{first}");
    }
    assert!(first.contains("tiny.ensemble.toml"), "{first}");
    assert_eq!(
        section(),
        first,
        "the same runs, whichever core ran which session"
    );
    let file = EnsembleFile::read(&dir.join("tiny.ensemble.toml")).unwrap();
    assert_eq!(
        file.members,
        vec![
            PathBuf::from("tiny.seed1.safetensors"),
            PathBuf::from("tiny.seed2.safetensors")
        ]
    );
    assert!(
        file.calibrated_on.contains("session 3"),
        "{}",
        file.calibrated_on
    );
    let (ensemble, _) = Ensemble::load(&dir.join("tiny.ensemble.toml"), 0.02, None).unwrap();
    assert_eq!(ensemble.members().len(), 2);
}
