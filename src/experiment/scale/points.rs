//! The summary's points: each model at each size on each path, over its seeds.

use super::records::{PathScore, ScaleRecord};
use crate::experiment::report::seeds::Spread;
use crate::twin::PathKind;

/// One point of the summary: a model at a size on a path, over its seeds.
pub(super) struct Point {
    pub(super) model: String,
    pub(super) minutes: f64,
    pub(super) path: String,
    pub(super) train_windows: usize,
    pub(super) seeds: usize,
    pub(super) sessions: usize,
    pub(super) pos_removed: Spread,
    pub(super) att_removed: Spread,
    pub(super) test_pos: Spread,
    pub(super) test_att: Spread,
    pub(super) oracle_removed: [f64; 2],
    /// Mean true error left by compensation, position µm and attitude mdeg.
    pub(super) compensated: [Spread; 2],
    /// Open-loop prediction error along the uncompensated runs (NaN where unmeasured).
    pub(super) open_loop: [Spread; 2],
    /// Mean true error with the open-loop predictions fed forward (NaN where unmeasured).
    pub(super) replayed: [Spread; 2],
    /// Mean true error under the calibrated controller and the oracle.
    pub(super) calibrated: [f64; 2],
    pub(super) oracle: [f64; 2],
}

/// The summary's points, model by model (those of `order` first, in its order), each by
/// size.
pub(super) fn points(records: &[ScaleRecord], order: &[String]) -> Vec<Point> {
    let mut keys: Vec<(String, f64)> = Vec::new();
    for r in records {
        if !keys.iter().any(|k| k.0 == r.model && k.1 == r.minutes) {
            keys.push((r.model.clone(), r.minutes));
        }
    }
    let first = |m: &str| order.iter().position(|o| o == m).unwrap_or(order.len());
    keys.sort_by(|a, b| {
        (first(&a.0), &a.0, a.1)
            .partial_cmp(&(first(&b.0), &b.0, b.1))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut out = Vec::new();
    for (model, minutes) in keys {
        let group: Vec<&ScaleRecord> = records
            .iter()
            .filter(|r| r.model == model && r.minutes == minutes)
            .collect();
        for path in PathKind::ALL.map(PathKind::name) {
            // Every held-out session of every seed; the test block once per seed.
            let scores: Vec<&PathScore> = group
                .iter()
                .flat_map(|r| r.paths.iter().filter(|p| p.path == path))
                .collect();
            let tests: Vec<&PathScore> = group
                .iter()
                .filter_map(|r| r.paths.iter().find(|p| p.path == path))
                .collect();
            let each = |of: &[&PathScore], f: &dyn Fn(&PathScore) -> f64| {
                Spread::of(&of.iter().map(|s| f(s)).collect::<Vec<_>>())
            };
            let sessions = {
                let mut k: Vec<usize> = scores.iter().map(|s| s.session).collect();
                k.sort_unstable();
                k.dedup();
                k.len()
            };
            out.push(Point {
                model: model.clone(),
                minutes,
                path: path.into(),
                train_windows: group[0].train_windows,
                seeds: group.len(),
                sessions,
                pos_removed: each(&scores, &|s| s.removed(s.compensated)[0]),
                att_removed: each(&scores, &|s| s.removed(s.compensated)[1]),
                test_pos: each(&tests, &|s| s.test_mae[0]),
                test_att: each(&tests, &|s| s.test_mae[1]),
                oracle_removed: [0, 1].map(|i| each(&scores, &|s| s.removed(s.oracle)[i]).mean),
                compensated: [0, 1].map(|i| each(&scores, &|s| s.compensated[i])),
                open_loop: [0, 1].map(|i| each(&scores, &|s| s.open_loop[i])),
                replayed: [0, 1].map(|i| each(&scores, &|s| s.replayed[i])),
                calibrated: [0, 1].map(|i| each(&scores, &|s| s.calibrated[i]).mean),
                oracle: [0, 1].map(|i| each(&scores, &|s| s.oracle[i]).mean),
            });
        }
    }
    out
}
