//! Dataset building on a twin recording: tensor layout, labels (eq. 19), statistics from
//! the training split only, and clear errors for bad recordings.

use std::path::PathBuf;
use std::sync::OnceLock;

use iastgcn::calibrate::residual;
use iastgcn::data::features::{hold, node_features};
use iastgcn::data::{Dataset, FeatureConfig, Recording, SplitMode, WindowConfig, FEATURES};
use iastgcn::graph::Graph;
use iastgcn::robot::{Geometry, Joints, Robot};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// One minute of the Fermat path from the CLI (3000 rows), simulated once per test binary.
fn recording() -> &'static Recording {
    static REC: OnceLock<Recording> = OnceLock::new();
    REC.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("iastgcn-ds-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out: PathBuf = dir.join("f.csv");
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
            .args([
                "simulate",
                "--trajectory",
                "fermat",
                "--minutes",
                "1",
                "--seed",
                "4",
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let graph = Graph::default_asset();
        let mut channels: Vec<&str> = graph.nodes.iter().map(String::as_str).collect();
        channels.push("F");
        let rec = Recording::read(&out, &channels, 100).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        rec
    })
}

fn build(rec: &Recording, graph: &Graph) -> Result<Dataset, iastgcn::data::DatasetError> {
    let model = Robot::nominal(Geometry::default_asset());
    Dataset::build(
        &[("fermat.csv".to_string(), rec.clone())],
        graph,
        &model,
        &FeatureConfig::default(),
        &WindowConfig::default(),
        SplitMode::Contiguous,
    )
}

#[test]
fn tensors_hold_the_z_scored_features_and_labels() {
    let rec = recording();
    let graph = Graph::default_asset();
    let ds = build(rec, &graph).unwrap();
    println!("{}", ds.summary());
    let (nw, nn, t) = (ds.windows.len(), graph.len(), 100);
    assert_eq!(ds.x.len(), nw * nn * FEATURES * t);
    assert_eq!(ds.y.len(), nw * 6);
    // 3000 rows, T = 100, S = 20, tracker every 5th row: ends 100, 120, ..., 2980 (145);
    // blocks end at rows 2100 and 2700, and the windows straddling them are dropped.
    assert_eq!(nw, 135);
    assert_eq!(
        (
            ds.splits.train.len(),
            ds.splits.validation.len(),
            ds.splits.test.len()
        ),
        (100, 25, 10)
    );
    // Recompute one test window by hand.
    let wi = ds.splits.train.len() + ds.splits.validation.len() + 3;
    let w = ds.windows[wi];
    let node = 7; // Q2
    let col = rec
        .channels
        .iter()
        .position(|c| c == &graph.nodes[node])
        .unwrap();
    let held = hold(&rec.rows.iter().map(|r| r.values[col]).collect::<Vec<_>>()).unwrap();
    let feats = node_features(&held, 0.02, &FeatureConfig::default());
    for (f, feat) in feats.iter().enumerate() {
        for s in [0, 50, 99] {
            let row = w.end + 1 - t + s;
            let (m, sd) = (
                ds.normalization.feature_mean[node][f],
                ds.normalization.feature_std[node][f],
            );
            let want = ((feat[row] - m) / sd) as f32;
            let got = ds.x[((wi * nn + node) * FEATURES + f) * t + s];
            assert!(
                (got - want).abs() <= 1e-6 * want.abs().max(1.0),
                "feature {f} step {s}: {got} vs {want}"
            );
        }
    }
    // The label is eq. 19 at the window's last row.
    let r = &rec.rows[w.end];
    let q = |c: &str| r.values[rec.channels.iter().position(|x| x == c).unwrap()].unwrap();
    let p = r.tracker.unwrap();
    let measured = Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(p[3], p[4], p[5])),
    );
    let joints = Joints {
        limbs: [q("Q1"), q("Q2"), q("Q3")],
        head: [q("Q4").to_radians(), q("Q5").to_radians()],
    };
    let (label, _) = residual(
        &Robot::nominal(Geometry::default_asset()),
        &joints,
        &measured,
        None,
    )
    .unwrap();
    for k in 0..6 {
        assert!(
            (ds.labels[wi][k] - label[k]).abs() < 1e-6,
            "{:?} vs {label:?}",
            ds.labels[wi]
        );
        let z = (label[k] - ds.normalization.label_mean[k]) / ds.normalization.label_std[k];
        assert!((ds.y[wi * 6 + k] as f64 - z).abs() < 1e-5);
    }
}

#[test]
fn statistics_ignore_validation_and_test_data() {
    let rec = recording();
    let graph = Graph::default_asset();
    let base = build(rec, &graph).unwrap();
    // Rewrite everything after the training block: error sensors, tilt, force and the
    // tracker (the joint inputs stay, so the poses stay reachable).
    let mut changed = rec.clone();
    let from = (0.7 * changed.rows.len() as f64) as usize;
    let touched: Vec<usize> = (0..changed.channels.len())
        .filter(|&c| !changed.channels[c].starts_with('Q'))
        .collect();
    for r in &mut changed.rows[from..] {
        for &c in &touched {
            if let Some(v) = &mut r.values[c] {
                *v = *v * 1.5 + 3.0;
            }
        }
        if let Some(p) = &mut r.tracker {
            p[0] += 0.5;
        }
    }
    let other = build(&changed, &graph).unwrap();
    assert_eq!(base.normalization, other.normalization);
    assert_ne!(base.x, other.x, "the held-out windows did change");
}

#[test]
fn bad_recordings_are_named() {
    let rec = recording();
    let graph = Graph::default_asset();
    let mut gap = rec.clone();
    gap.rows.remove(1234);
    let e = build(&gap, &graph).unwrap_err().to_string();
    assert!(e.starts_with("fermat.csv: line 1236: a gap in time"), "{e}");
    let mut short = rec.clone();
    short.rows.truncate(60);
    let e = build(&short, &graph).unwrap_err().to_string();
    assert!(
        e.contains("60 rows give no labelled window of 100 steps"),
        "{e}"
    );
    let other = Graph::parse(
        "nodes = [\"E1\", \"E9\"]\nedges = [[\"E1\", \"E9\"]]",
        "g.toml",
    )
    .unwrap();
    let e = build(rec, &other).unwrap_err().to_string();
    assert!(e.contains("no column for \"E9\""), "{e}");
}

#[test]
fn batches_are_seeded_shuffles_of_a_split() {
    let ds = build(recording(), &Graph::default_asset()).unwrap();
    let [train, _, test] = ds.split_ranges();
    let a = ds.batches(train.clone(), 64, 9);
    assert_eq!(a, ds.batches(train.clone(), 64, 9));
    assert_ne!(a, ds.batches(train.clone(), 64, 10));
    assert_eq!(a.iter().map(Vec::len).collect::<Vec<_>>(), [64, 36]);
    let mut all: Vec<usize> = a.concat();
    all.sort();
    assert_eq!(all, train.collect::<Vec<_>>());
    let (x, y) = ds.gather(&[test.start, 0]);
    let len = ds.window_len();
    assert_eq!(x.len(), 2 * len);
    assert_eq!(&x[..len], &ds.x[test.start * len..(test.start + 1) * len]);
    assert_eq!(&y[6..], &ds.y[..6]);
}

/// The dataset of one recording (as `fermat.csv`) under `window` and `mode`.
fn one_recording(rec: &Recording, window: WindowConfig, mode: SplitMode) -> Dataset {
    Dataset::build(
        &[("fermat.csv".to_string(), rec.clone())],
        &Graph::default_asset(),
        &Robot::nominal(Geometry::default_asset()),
        &FeatureConfig::default(),
        &window,
        mode,
    )
    .unwrap()
}

/// A share of the training windows keeps the first windows of the training block,
/// leaves validation and test alone, and takes the statistics from the kept windows only.
#[test]
fn a_training_share_keeps_the_start_of_the_training_block() {
    let rec = recording();
    let with = |kept: f64, mode: SplitMode| {
        one_recording(
            rec,
            WindowConfig {
                train_kept: kept,
                ..WindowConfig::default()
            },
            mode,
        )
    };
    let full = with(1.0, SplitMode::Contiguous);
    let half = with(0.5, SplitMode::Contiguous);
    // The windows of the block's first half: those that end before its middle.
    let limit = (0.7 * 0.5 * rec.rows.len() as f64).round() as usize;
    let before = full.splits.train.iter().filter(|w| w.end < limit).count();
    assert!(before > 10 && before < full.splits.train.len());
    assert_eq!(half.splits.train, full.splits.train[..before]);
    assert_eq!(half.splits.validation, full.splits.validation);
    assert_eq!(half.splits.test, full.splits.test);
    assert_ne!(
        half.normalization, full.normalization,
        "statistics of the kept windows"
    );
    // The random split keeps the first share of its shuffled training windows.
    let random = SplitMode::Random { seed: 5 };
    let (all, quarter) = (with(1.0, random), with(0.25, random));
    let k = (0.25 * all.splits.train.len() as f64).round() as usize;
    assert_eq!(quarter.splits.train, all.splits.train[..k]);
    assert_eq!(quarter.splits.validation, all.splits.validation);
}

/// A share of the validation windows keeps the first windows of each validation block and
/// leaves training and test alone (the scaling study's shorter sessions).
#[test]
fn a_validation_share_keeps_the_start_of_the_validation_block() {
    let rec = recording();
    let with = |kept: f64, mode: SplitMode| {
        one_recording(
            rec,
            WindowConfig {
                validation_kept: kept,
                ..WindowConfig::default()
            },
            mode,
        )
    };
    let full = with(1.0, SplitMode::Contiguous);
    let half = with(0.5, SplitMode::Contiguous);
    let n = rec.rows.len() as f64;
    let limit = (0.7 * n).round() as usize + (0.2 * 0.5 * n).round() as usize;
    let before = full
        .splits
        .validation
        .iter()
        .filter(|w| w.end < limit)
        .count();
    assert!(before > 2 && before < full.splits.validation.len());
    assert_eq!(half.splits.validation, full.splits.validation[..before]);
    assert_eq!(half.splits.train, full.splits.train);
    assert_eq!(half.splits.test, full.splits.test);
    assert_eq!(
        half.normalization, full.normalization,
        "training statistics"
    );
    let random = SplitMode::Random { seed: 5 };
    let (all, quarter) = (with(1.0, random), with(0.25, random));
    let k = (0.25 * all.splits.validation.len() as f64).round() as usize;
    assert_eq!(quarter.splits.validation, all.splits.validation[..k]);
    assert_eq!(quarter.splits.train, all.splits.train);
    assert_eq!(quarter.splits.test, all.splits.test);
}
