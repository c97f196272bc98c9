//! The recommended model (docs/usage.md "Recommended model"): chosen on a validation
//! session's Table V rows by the mean share of the calibrated error removed, position and
//! attitude over the paths and the model's seeds; none when no model removes any.

use iastgcn::experiment::evaluate::HeldOutConfig;
use iastgcn::experiment::recommend::{recommend, validation_session};
use iastgcn::experiment::report::{ErrorStats, TableVRow};
use iastgcn::stats::Summary;
use iastgcn::twin::PathKind;

fn row(path: &str, stage: &str, model: &str, pos: f64, att: f64) -> TableVRow {
    let s = |mean: f64| Summary {
        mean,
        sd: 1.0,
        max: 2.0 * mean,
        count: 100,
    };
    let stats = ErrorStats {
        position: s(pos),
        attitude: s(att),
    };
    TableVRow {
        trajectory: path.into(),
        session: 0,
        stage: stage.into(),
        model: model.into(),
        truth: stats,
        tracker: stats,
    }
}

/// Two paths, calibrated 100 µm / 50 mdeg on both, the oracle, and each (model, left
/// error on grid, on hilbert) as given (attitude left: half the position's).
fn session(models: &[(&str, f64, f64)]) -> Vec<TableVRow> {
    let mut rows = Vec::new();
    for (i, path) in ["grid", "hilbert"].into_iter().enumerate() {
        rows.push(row(path, "initial", "-", 900.0, 300.0));
        rows.push(row(path, "calibrated", "-", 100.0, 50.0));
        rows.push(row(path, "oracle", "true residual", 5.0, 2.0));
        for (m, g, h) in models {
            let left = if i == 0 { *g } else { *h };
            rows.push(row(path, "compensated", m, left, left / 2.0));
        }
    }
    rows
}

#[test]
fn the_model_removing_most_over_paths_and_seeds_is_recommended() {
    // a: seeds remove (70+50)/2 = 60 % and (80+60)/2 = 70 %: mean 65 %.
    // b: one seed removes 90 % on grid but the other only 10 %: mean over seeds 55 %.
    let rows = session(&[
        ("a.seed1", 30.0, 50.0),
        ("a.seed2", 20.0, 40.0),
        ("b.seed1", 10.0, 10.0),
        ("b.seed2", 90.0, 90.0),
    ]);
    let r = recommend(&rows);
    let names: Vec<&str> = r.scores.iter().map(|s| s.model.as_str()).collect();
    assert_eq!(names, ["a", "b"]);
    let a = &r.scores[0];
    assert_eq!(a.seeds, 2);
    assert!((a.position - 65.0).abs() < 1e-9, "{a:?}");
    // Attitude left is half the position's of a calibrated 50: the same shares.
    assert!((a.attitude - 65.0).abs() < 1e-9 && (a.score() - 65.0).abs() < 1e-9);
    assert!((r.scores[1].position - 50.0).abs() < 1e-9);
    assert_eq!(r.model().unwrap().model, "a");
    assert_eq!(a.best_seed, "a.seed2");
    let text = r.sentence();
    assert!(
        text.contains("**a**") && text.contains("`a.seed2`"),
        "{text}"
    );
    let session = HeldOutConfig::default()
        .session(validation_session(3))
        .describe();
    let md = r.markdown((validation_session(3) + 1, &session), 0.5);
    assert!(md.contains("| **a** | 2 | 65.0 | 65.0 | 65.0 |"), "{md}");
    assert!(md.contains("| b | 2 | 50.0 | 50.0 | 50.0 |"), "{md}");
}

#[test]
fn no_model_is_recommended_when_none_beats_calibration() {
    let rows = session(&[("mlp", 120.0, 100.0), ("erc", 150.0, 140.0)]);
    let r = recommend(&rows);
    assert_eq!(r.scores.len(), 2);
    assert!(r.model().is_none());
    assert!(
        r.sentence().contains("no residual model"),
        "{}",
        r.sentence()
    );
}

#[test]
fn the_validation_session_is_none_of_the_test_sessions() {
    let held = HeldOutConfig::default();
    let v = held.session(validation_session(3));
    for k in 0..validation_session(3) {
        let t = held.session(k);
        assert_ne!(v.seed, t.seed);
        assert_ne!(v.conditions, t.conditions);
    }
    // Placements differ too, but for the spiral: its only placement clear of every
    // training placement is the half turn, which every held-out session walks (one way
    // or the other); the validation session shares it with test session 2.
    for kind in [PathKind::Grid, PathKind::Hilbert, PathKind::Rosette] {
        let p = iastgcn::twin::PathParams::held_out_in(kind, validation_session(3));
        for k in 0..validation_session(3) {
            assert_ne!(
                p,
                iastgcn::twin::PathParams::held_out_in(kind, k),
                "{kind:?}"
            );
        }
    }
}

#[test]
fn the_headline_is_the_recommended_model_on_the_test_sessions_hilbert_runs() {
    let validation = session(&[("a.seed1", 30.0, 50.0), ("b.seed1", 60.0, 60.0)]);
    let r = recommend(&validation);
    assert_eq!(r.model().unwrap().model, "a");
    // Table V: two test sessions; a leaves 40 and 60 µm of session 0's 100 µm (60 and
    // 40 % removed) and 100 µm of session 1's 200 µm (50 %); b's rows do not count.
    let mut table_v = session(&[("a.seed1", 0.0, 40.0), ("b.seed1", 0.0, 10.0)]);
    let mut second = session(&[("a.seed1", 0.0, 100.0), ("b.seed1", 0.0, 10.0)]);
    for row in second.iter_mut() {
        row.session = 1;
        if row.stage == "calibrated" {
            row.truth.position.mean = 200.0;
            row.truth.attitude.mean = 100.0;
        }
    }
    table_v.append(&mut second);
    let text = r.headline(&table_v).unwrap();
    // Position: 60 % and 50 % → 55.0 ± 7.1; attitude likewise (left half of position).
    assert!(
        text.starts_with("a, the recommended model, removes 55.0 ± 7.1 % of the position")
            && text.contains("and 55.0 ± 7.1 % of the attitude")
            && text.contains("1 seed(s) × 2 held-out session(s)"),
        "{text}"
    );
    // No recommended model, no headline.
    let none = recommend(&session(&[("mlp", 120.0, 100.0)]));
    assert!(none.headline(&table_v).is_none());
}
