//! Spread over training seeds. Models named `<model>.seed<k>` (as `iastgcn reproduce`
//! writes them) are grouped by `<model>`: Tables III and V become mean ± SD over the
//! seeds (Table V also over the held-out sessions), and every other model is compared
//! with the main one (IASTGCN) seed by seed (and session by session),
//! on the same split and the same held-out runs.

use std::fmt::Write as _;

use super::{Report, TableIIIRow, TableVRow};
use crate::train::log::{csv_text, distinct};

/// Splits a model name into its group and training seed: `iastgcn.seed2` →
/// (`iastgcn`, Some(2)); any other name is its own group without a seed.
pub fn split_name(name: &str) -> (&str, Option<u64>) {
    if let Some((group, seed)) = name.rsplit_once(".seed") {
        if let Ok(k) = seed.parse() {
            if !group.is_empty() {
                return (group, Some(k));
            }
        }
    }
    (name, None)
}

/// The model a checkpoint's file stem names: the stem itself, except that the refined
/// checkpoints of demos run before the one naming scheme
/// ([`crate::experiment::protocol::ModelFiles::named`]), `<model>.seed<k>-refined`, are
/// the model `<model>.seed<k>`.
pub fn model_name(stem: &str) -> &str {
    match stem.strip_suffix("-refined") {
        Some(name) if split_name(name).1.is_some() => name,
        _ => stem,
    }
}

/// The name of `group` trained with seed `seed` (the inverse of [`split_name`]).
pub fn seeded_name(group: &str, seed: u64) -> String {
    format!("{group}.seed{seed}")
}

/// Mean and sample standard deviation (divided by n − 1; 0 for one value) of a set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    /// Arithmetic mean.
    pub mean: f64,
    /// Sample standard deviation.
    pub sd: f64,
    /// Number of values.
    pub n: usize,
}

impl Spread {
    /// The spread of `values` (NaN mean for none).
    pub fn of(values: &[f64]) -> Spread {
        let n = values.len();
        let mean = values.iter().sum::<f64>() / n as f64;
        let sd = if n > 1 {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        } else {
            0.0
        };
        Spread { mean, sd, n }
    }

    /// `mean ± sd` with `decimals` decimals (`n/a` for no value).
    pub fn text(&self, decimals: usize) -> String {
        if !self.mean.is_finite() {
            return "n/a".into();
        }
        format!("{:.decimals$} ± {:.decimals$}", self.mean, self.sd)
    }
}

/// Table III of one model on one path over its seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct SeedRowIII {
    /// The training recording whose test block was scored.
    pub trajectory: String,
    /// The model (group) name.
    pub model: String,
    /// Position MAE, µm.
    pub pos_mae: Spread,
    /// Attitude MAE, mdeg.
    pub att_mae: Spread,
    /// Position RMSE, µm.
    pub pos_rmse: Spread,
    /// Attitude RMSE, mdeg.
    pub att_rmse: Spread,
}

/// Table V of one compensating model on one held-out path over its seeds (against the
/// hidden truth, and as the tracker measures it).
#[derive(Clone, Debug, PartialEq)]
pub struct SeedRowV {
    /// The held-out path.
    pub trajectory: String,
    /// The model (group) name.
    pub model: String,
    /// Mean true position error of the run, µm.
    pub truth_pos: Spread,
    /// Mean true attitude error of the run, mdeg.
    pub truth_att: Spread,
    /// Mean position error as the tracker measured it, µm.
    pub tracker_pos: Spread,
    /// Mean attitude error as the tracker measured it, mdeg.
    pub tracker_att: Spread,
    /// Share of the calibrated run's mean true position error that compensation removed, %.
    pub pos_removed: Spread,
    /// The same for attitude, %.
    pub att_removed: Spread,
}

/// One paired comparison: another model against the main one on one path and measure,
/// seed by seed.
#[derive(Clone, Debug, PartialEq)]
pub struct Paired {
    /// The measure: `III pos MAE`, `III att MAE`, `V true pos`, `V true att`.
    pub measure: String,
    /// The path.
    pub trajectory: String,
    /// The other model.
    pub model: String,
    /// Seeds where the main model's error is smaller.
    pub wins: usize,
    /// The other model's error minus the main model's over the shared seeds (positive:
    /// the main model is better).
    pub difference: Spread,
}

impl Paired {
    /// `better` when the mean difference exceeds its spread in the main model's favour,
    /// `worse` when against it, `within spread` otherwise.
    pub fn verdict(&self) -> &'static str {
        let d = &self.difference;
        if d.n < 2 || !d.mean.is_finite() {
            "n/a"
        } else if d.mean > d.sd {
            "better"
        } else if -d.mean > d.sd {
            "worse"
        } else {
            "within spread"
        }
    }
}

/// Tables III and V over seeds and the paired comparisons.
#[derive(Clone, Debug, PartialEq)]
pub struct SeedSummary {
    /// The model the others are compared with (`iastgcn`, or the first group).
    pub main: String,
    /// The seeds each group was trained with, in the report's model order.
    pub groups: Vec<(String, Vec<u64>)>,
    /// Table III over seeds.
    pub table_iii: Vec<SeedRowIII>,
    /// Table V (compensated rows) over seeds.
    pub table_v: Vec<SeedRowV>,
    /// Every other model against the main one.
    pub paired: Vec<Paired>,
}

/// Values of one measure per (path, group) keyed by seed and held-out session (Table
/// III: session 0, the test block).
type BySeed = Vec<((u64, usize), f64)>;

fn spread_of(values: &BySeed) -> Spread {
    Spread::of(&values.iter().map(|v| v.1).collect::<Vec<_>>())
}

/// The summary of `report`'s tables over seeds; `None` unless some model was trained
/// with at least two seeds.
pub fn summarize(report: &Report) -> Option<SeedSummary> {
    let names = distinct(
        report
            .table_iii
            .iter()
            .map(|r| r.model.as_str())
            .chain(report.table_v.iter().map(|r| r.model.as_str())),
    );
    let mut groups: Vec<(String, Vec<u64>)> = Vec::new();
    for name in names {
        let (group, Some(seed)) = split_name(name) else {
            continue;
        };
        match groups.iter_mut().find(|g| g.0 == group) {
            Some(g) if !g.1.contains(&seed) => g.1.push(seed),
            Some(_) => {}
            None => groups.push((group.to_string(), vec![seed])),
        }
    }
    if groups.iter().all(|g| g.1.len() < 2) {
        return None;
    }
    let main = groups
        .iter()
        .find(|g| g.0 == "iastgcn")
        .unwrap_or(&groups[0])
        .0
        .clone();
    let iii = |t: &str, g: &str, pick: fn(&TableIIIRow) -> f64| -> BySeed {
        report
            .table_iii
            .iter()
            .filter(|r| r.trajectory == t)
            .filter_map(|r| match split_name(&r.model) {
                (group, Some(seed)) if group == g => Some(((seed, 0), pick(r))),
                _ => None,
            })
            .collect()
    };
    let compensated = |t: &str, g: &str, pick: fn(&TableVRow) -> f64| -> BySeed {
        report
            .table_v
            .iter()
            .filter(|r| r.trajectory == t && r.stage == "compensated")
            .filter_map(|r| match split_name(&r.model) {
                (group, Some(seed)) if group == g => Some(((seed, r.session), pick(r))),
                _ => None,
            })
            .collect()
    };
    type PickIII = fn(&TableIIIRow) -> f64;
    type PickV = fn(&TableVRow) -> f64;
    let (pos_mae, att_mae): (PickIII, PickIII) = (|r| r.metrics.pos_mae, |r| r.metrics.att_mae);
    let (pos_rmse, att_rmse): (PickIII, PickIII) = (|r| r.metrics.pos_rmse, |r| r.metrics.att_rmse);
    let (true_pos, true_att): (PickV, PickV) =
        (|r| r.truth.position.mean, |r| r.truth.attitude.mean);
    let (trk_pos, trk_att): (PickV, PickV) =
        (|r| r.tracker.position.mean, |r| r.tracker.attitude.mean);

    let mut table_iii = Vec::new();
    for t in distinct(report.table_iii.iter().map(|r| r.trajectory.as_str())) {
        for (g, _) in &groups {
            if iii(t, g, pos_mae).is_empty() {
                continue;
            }
            table_iii.push(SeedRowIII {
                trajectory: t.to_string(),
                model: g.clone(),
                pos_mae: spread_of(&iii(t, g, pos_mae)),
                att_mae: spread_of(&iii(t, g, att_mae)),
                pos_rmse: spread_of(&iii(t, g, pos_rmse)),
                att_rmse: spread_of(&iii(t, g, att_rmse)),
            });
        }
    }
    let mut table_v = Vec::new();
    for t in distinct(report.table_v.iter().map(|r| r.trajectory.as_str())) {
        // Each held-out session's calibrated run: its own day, its own error.
        let calibrated = |session: usize| {
            report
                .table_v
                .iter()
                .find(|r| r.trajectory == t && r.stage == "calibrated" && r.session == session)
        };
        for (g, _) in &groups {
            let pos = compensated(t, g, true_pos);
            if pos.is_empty() {
                continue;
            }
            let removed = |values: &BySeed, pick: PickV| -> Spread {
                Spread::of(
                    &values
                        .iter()
                        .map(|((_, session), v)| match calibrated(*session).map(pick) {
                            Some(before) if before > 0.0 => 100.0 * (before - v) / before,
                            _ => f64::NAN,
                        })
                        .collect::<Vec<_>>(),
                )
            };
            let att = compensated(t, g, true_att);
            table_v.push(SeedRowV {
                trajectory: t.to_string(),
                model: g.clone(),
                truth_pos: spread_of(&pos),
                truth_att: spread_of(&att),
                tracker_pos: spread_of(&compensated(t, g, trk_pos)),
                tracker_att: spread_of(&compensated(t, g, trk_att)),
                pos_removed: removed(&pos, true_pos),
                att_removed: removed(&att, true_att),
            });
        }
    }

    let mut paired = Vec::new();
    let pair = |measure: &str, t: &str, g: &str, main: BySeed, other: BySeed| {
        pair_up(measure, t, g, &main, &other)
    };
    for (g, _) in groups.iter().filter(|g| g.0 != main) {
        for t in distinct(report.table_iii.iter().map(|r| r.trajectory.as_str())) {
            for (measure, pick) in [("III pos MAE", pos_mae), ("III att MAE", att_mae)] {
                paired.extend(pair(measure, t, g, iii(t, &main, pick), iii(t, g, pick)));
            }
        }
        for t in distinct(report.table_v.iter().map(|r| r.trajectory.as_str())) {
            for (measure, pick) in [("V true pos", true_pos), ("V true att", true_att)] {
                paired.extend(pair(
                    measure,
                    t,
                    g,
                    compensated(t, &main, pick),
                    compensated(t, g, pick),
                ));
            }
        }
    }
    Some(SeedSummary {
        main,
        groups,
        table_iii,
        table_v,
        paired,
    })
}

/// Which of `values` to bold: the smallest mean, when its gap to the next smallest
/// exceeds the larger of their two standard deviations.
fn beyond_spread(values: &[Spread]) -> Option<usize> {
    let mut order: Vec<usize> = (0..values.len())
        .filter(|&i| values[i].mean.is_finite())
        .collect();
    order.sort_by(|&a, &b| values[a].mean.total_cmp(&values[b].mean));
    let (&best, &next) = (order.first()?, order.get(1)?);
    let (b, n) = (&values[best], &values[next]);
    (n.mean - b.mean > b.sd.max(n.sd)).then_some(best)
}

/// Each value as text, the one [`beyond_spread`] picks in bold.
pub fn beyond_spread_cells(values: &[Spread], decimals: usize) -> Vec<String> {
    let bold = beyond_spread(values);
    values
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let t = s.text(decimals);
            if Some(i) == bold {
                format!("**{t}**")
            } else {
                t
            }
        })
        .collect()
}

/// The Markdown section of the summary.
pub fn markdown(s: &SeedSummary) -> String {
    let mut out = String::from("## Spread over training seeds\n\n");
    out.push_str(
        "Every model below was trained once per seed on the same data and split and run on \
         the same held-out sessions; a Table V cell is the mean ± sample SD over its seeds \
         and the held-out sessions (the share removed against each session's own calibrated \
         run), a Table III cell over its seeds. A mean is bold only where it is the \
         column's smallest and its gap to the next smallest exceeds the larger of their \
         two SDs.\n\n",
    );
    for (g, seeds) in &s.groups {
        let list: Vec<String> = seeds.iter().map(u64::to_string).collect();
        let _ = writeln!(out, "- {g}: seeds {}", list.join(", "));
    }
    out.push('\n');
    if let Some(goal) = s
        .table_v
        .iter()
        .find(|r| r.trajectory == "hilbert" && r.model == s.main)
    {
        let _ = writeln!(
            out,
            "On the held-out Hilbert runs, {} removes {} % of the calibrated mean true position \
             error (goal: 65 %) and {} % of the attitude error (goal: 60 %).\n",
            s.main,
            goal.pos_removed.text(1),
            goal.att_removed.text(1)
        );
    }

    out.push_str(
        "### Table V over seeds: compensated pose error against the hidden truth\n\n\
         | Trajectory | Model | Pos. mean (µm) | Att. mean (mdeg) | Pos. removed (%) | Att. removed (%) | Tracker pos. (µm) | Tracker att. (mdeg) |\n\
         |---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    for t in distinct(s.table_v.iter().map(|r| r.trajectory.as_str())) {
        let rows: Vec<&SeedRowV> = s.table_v.iter().filter(|r| r.trajectory == t).collect();
        let col = |pick: fn(&SeedRowV) -> Spread| -> Vec<Spread> {
            rows.iter().map(|r| pick(r)).collect()
        };
        let (p, a) = (
            beyond_spread_cells(&col(|r| r.truth_pos), 1),
            beyond_spread_cells(&col(|r| r.truth_att), 2),
        );
        let (tp, ta) = (
            beyond_spread_cells(&col(|r| r.tracker_pos), 1),
            beyond_spread_cells(&col(|r| r.tracker_att), 2),
        );
        for (i, r) in rows.iter().enumerate() {
            let _ = writeln!(
                out,
                "| {t} | {} | {} | {} | {} | {} | {} | {} |",
                r.model,
                p[i],
                a[i],
                r.pos_removed.text(1),
                r.att_removed.text(1),
                tp[i],
                ta[i]
            );
        }
    }
    out.push('\n');

    out.push_str(
        "### Table III over seeds: prediction error on the test split\n\n\
         | Trajectory | Model | Pos. MAE (µm) | Att. MAE (mdeg) | Pos. RMSE (µm) | Att. RMSE (mdeg) |\n\
         |---|---|---:|---:|---:|---:|\n",
    );
    for t in distinct(s.table_iii.iter().map(|r| r.trajectory.as_str())) {
        let rows: Vec<&SeedRowIII> = s.table_iii.iter().filter(|r| r.trajectory == t).collect();
        let col = |pick: fn(&SeedRowIII) -> Spread| -> Vec<String> {
            beyond_spread_cells(&rows.iter().map(|r| pick(r)).collect::<Vec<_>>(), 2)
        };
        let (pm, am) = (col(|r| r.pos_mae), col(|r| r.att_mae));
        let (pr, ar) = (col(|r| r.pos_rmse), col(|r| r.att_rmse));
        for (i, r) in rows.iter().enumerate() {
            let _ = writeln!(
                out,
                "| {t} | {} | {} | {} | {} | {} |",
                r.model, pm[i], am[i], pr[i], ar[i]
            );
        }
    }
    out.push('\n');

    let _ = writeln!(
        out,
        "### Paired comparison with {main}\n\n\
         Seed by seed (same seed, same split, same held-out runs; Table V also session by \
         session): in how many pairs {main}'s error is smaller, and the other model's error \
         minus {main}'s as mean ± SD over the pairs (positive: {main} is better). `better` \
         / `worse` where the mean difference exceeds its SD.\n\n\
         | Measure | Trajectory | Model | {main} wins | Difference | Verdict |\n\
         |---|---|---|---:|---:|---|",
        main = s.main
    );
    out.push_str(&paired_rows(&s.main, &s.paired));
    out.push('\n');
    out
}

/// The rows of a paired-comparison table (after its header) and the tally of verdicts.
pub fn paired_rows(main: &str, paired: &[Paired]) -> String {
    let mut out = String::new();
    for p in paired {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {}/{} | {} | {} |",
            p.measure,
            p.trajectory,
            p.model,
            p.wins,
            p.difference.n,
            p.difference.text(2),
            p.verdict()
        );
    }
    let count = |v: &str| paired.iter().filter(|p| p.verdict() == v).count();
    let _ = writeln!(
        out,
        "\nOf {} comparisons, {main} is better beyond the spread in {}, worse in {}, and \
         within the spread in the rest.",
        paired.len(),
        count("better"),
        count("worse")
    );
    out
}

/// Another model against the main one on the samples both have (`key`: a seed, or a
/// (machine, seed) pair); `None` when they share none.
pub fn pair_up<K: PartialEq>(
    measure: &str,
    trajectory: &str,
    model: &str,
    main: &[(K, f64)],
    other: &[(K, f64)],
) -> Option<Paired> {
    let diffs: Vec<(f64, f64)> = main
        .iter()
        .filter_map(|(k, m)| other.iter().find(|o| o.0 == *k).map(|o| (*m, o.1)))
        .collect();
    (!diffs.is_empty()).then(|| Paired {
        measure: measure.into(),
        trajectory: trajectory.into(),
        model: model.into(),
        wins: diffs.iter().filter(|(m, o)| m < o).count(),
        difference: Spread::of(&diffs.iter().map(|(m, o)| o - m).collect::<Vec<_>>()),
    })
}

fn spread_fields(s: &Spread) -> [String; 2] {
    [format!("{:.4}", s.mean), format!("{:.4}", s.sd)]
}

/// Header of `table_v_seeds.csv`.
pub const TABLE_V_SEEDS_HEADER: &str = "trajectory,model,runs,\
true_pos_mean_um,true_pos_sd_um,true_att_mean_mdeg,true_att_sd_mdeg,\
pos_removed_mean_pct,pos_removed_sd_pct,att_removed_mean_pct,att_removed_sd_pct,\
trk_pos_mean_um,trk_pos_sd_um,trk_att_mean_mdeg,trk_att_sd_mdeg";
/// Header of `table_iii_seeds.csv`.
pub const TABLE_III_SEEDS_HEADER: &str = "trajectory,model,seeds,\
pos_mae_mean_um,pos_mae_sd_um,att_mae_mean_mdeg,att_mae_sd_mdeg,\
pos_rmse_mean_um,pos_rmse_sd_um,att_rmse_mean_mdeg,att_rmse_sd_mdeg";
/// Header of `paired.csv`.
pub const PAIRED_HEADER: &str =
    "measure,trajectory,model,main,pairs,main_wins,difference_mean,difference_sd,verdict";

/// `table_v_seeds.csv`: one line per path and model, SDs over seeds.
pub fn table_v_csv(s: &SeedSummary) -> String {
    csv_text(
        TABLE_V_SEEDS_HEADER,
        s.table_v
            .iter()
            .map(|r| {
                let mut v = vec![
                    r.trajectory.clone(),
                    r.model.clone(),
                    r.truth_pos.n.to_string(),
                ];
                for x in [
                    &r.truth_pos,
                    &r.truth_att,
                    &r.pos_removed,
                    &r.att_removed,
                    &r.tracker_pos,
                    &r.tracker_att,
                ] {
                    v.extend(spread_fields(x));
                }
                v
            })
            .collect(),
    )
}

/// `table_iii_seeds.csv`: one line per path and model, SDs over seeds.
pub fn table_iii_csv(s: &SeedSummary) -> String {
    csv_text(
        TABLE_III_SEEDS_HEADER,
        s.table_iii
            .iter()
            .map(|r| {
                let mut v = vec![
                    r.trajectory.clone(),
                    r.model.clone(),
                    r.pos_mae.n.to_string(),
                ];
                for x in [&r.pos_mae, &r.att_mae, &r.pos_rmse, &r.att_rmse] {
                    v.extend(spread_fields(x));
                }
                v
            })
            .collect(),
    )
}

/// `paired.csv`: one line per comparison.
pub fn paired_csv(s: &SeedSummary) -> String {
    csv_text(
        PAIRED_HEADER,
        s.paired
            .iter()
            .map(|p| {
                let mut v = vec![
                    p.measure.clone(),
                    p.trajectory.clone(),
                    p.model.clone(),
                    s.main.clone(),
                    p.difference.n.to_string(),
                    p.wins.to_string(),
                ];
                v.extend(spread_fields(&p.difference));
                v.push(p.verdict().into());
                v
            })
            .collect(),
    )
}
