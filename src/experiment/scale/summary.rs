//! The study's summary files from every finished job: `scale.csv`,
//! `scale_summary.csv`, `scale_validation.csv` and `scale.png` (`scale.md` is
//! `markdown.rs`'s).

use std::path::Path;

use super::markdown::markdown;
use super::points::{points, Point};
use super::records::{records, ScaleRecord};
use super::study::{Study, PAPER_HILBERT_REMOVED};
use crate::error::{Error, Result};
use crate::experiment::recommend::{recommend_runs, Recommendation, ValidationRun};
use crate::experiment::report::seeds::Spread;
use crate::plot::{self, Panel, Series};
use crate::progress::Reporter;
use crate::train::log::csv_text;
use crate::twin::PathKind;

/// `scale.csv` (a row per job, session and path), `scale_summary.csv` (mean and SD over
/// seeds and test sessions per model, size and path), `scale.md`, `scale.png` and, with a
/// validation session, `scale_validation.csv`, from every finished job.
pub fn write_summary(study: &Study, out: &Path, reporter: &mut dyn Reporter) -> Result<()> {
    let all = records(out)?;
    if all.is_empty() {
        return Ok(());
    }
    let validation = study.validation_index();
    // The tables and the plot score the test sessions only.
    let records: Vec<ScaleRecord> = all
        .iter()
        .map(|r| {
            let mut r = r.clone();
            r.paths.retain(|p| Some(p.session) != validation);
            r
        })
        .collect();
    let recommended = recommendations(&all, validation);
    let f = |v: f64| format!("{v:.3}");
    let rows: Vec<Vec<String>> = all
        .iter()
        .flat_map(|r| {
            r.paths.iter().map(move |p| {
                let [pr, ar] = p.removed(p.compensated);
                vec![
                    r.model.clone(),
                    r.minutes.to_string(),
                    r.seed.to_string(),
                    r.train_windows.to_string(),
                    r.epochs.to_string(),
                    p.path.clone(),
                    p.session.to_string(),
                    p.test_windows.to_string(),
                    f(p.test_mae[0]),
                    f(p.test_mae[1]),
                    f(p.calibrated[0]),
                    f(p.oracle[0]),
                    f(p.compensated[0]),
                    f(p.calibrated[1]),
                    f(p.oracle[1]),
                    f(p.compensated[1]),
                    f(pr),
                    f(ar),
                    f(p.open_loop[0]),
                    f(p.open_loop[1]),
                    f(p.replayed[0]),
                    f(p.replayed[1]),
                    if Some(p.session) == validation {
                        "validation"
                    } else {
                        "test"
                    }
                    .into(),
                ]
            })
        })
        .collect();
    let jobs_csv = csv_text(
        "model,minutes,seed,train_windows,epochs,path,held_out_session,test_windows,test_pos_mae_um,\
         test_att_mae_mdeg,calibrated_pos_um,oracle_pos_um,compensated_pos_um,\
         calibrated_att_mdeg,oracle_att_mdeg,compensated_att_mdeg,pos_removed_pct,\
         att_removed_pct,open_loop_pos_um,open_loop_att_mdeg,replayed_pos_um,\
         replayed_att_mdeg,session_role",
        rows,
    );
    let points = points(&records, &study.models);
    let sd = |s: &Spread| [f(s.mean), f(s.sd)];
    let summary_rows = points
        .iter()
        .map(|p| {
            let mut row = vec![
                p.model.clone(),
                p.minutes.to_string(),
                p.train_windows.to_string(),
                p.seeds.to_string(),
                p.sessions.to_string(),
                p.path.clone(),
            ];
            for s in [&p.pos_removed, &p.att_removed, &p.test_pos, &p.test_att] {
                row.extend(sd(s));
            }
            row.extend(p.oracle_removed.map(f));
            for s in p.compensated.iter().chain(&p.open_loop) {
                row.extend(sd(s));
            }
            row
        })
        .collect();
    let summary_csv = csv_text(
        "model,minutes,train_windows,seeds,held_out_sessions,path,pos_removed_mean_pct,\
         pos_removed_sd_pct,\
         att_removed_mean_pct,att_removed_sd_pct,test_pos_mae_mean_um,test_pos_mae_sd_um,\
         test_att_mae_mean_mdeg,test_att_mae_sd_mdeg,oracle_pos_removed_pct,\
         oracle_att_removed_pct,compensated_pos_mean_um,compensated_pos_sd_um,\
         compensated_att_mean_mdeg,compensated_att_sd_mdeg,open_loop_pos_mean_um,\
         open_loop_pos_sd_um,open_loop_att_mean_mdeg,open_loop_att_sd_mdeg",
        summary_rows,
    );
    let mut batch = crate::atomic::Batch::new();
    let io = |p: &Path, e: std::io::Error| Error::io(p, e);
    let mut texts = vec![
        ("scale.csv", jobs_csv),
        ("scale_summary.csv", summary_csv),
        (
            "scale.md",
            markdown(study, (&records, &all), &points, &recommended),
        ),
    ];
    if validation.is_some() {
        texts.push(("scale_validation.csv", validation_csv(&recommended)));
    }
    for (name, text) in texts {
        let path = out.join(name);
        batch
            .add(&path, text.as_bytes())
            .map_err(|e| io(&path, e))?;
    }
    let png = out.join("scale.png");
    batch.add_with(&png, |tmp| {
        plot::draw(tmp, &panels(&points), 2, 3, (1500, 900))
    })?;
    batch.commit().map_err(|e| io(out, e))?;
    for (minutes, r) in &recommended {
        reporter.note(&format!("at {minutes} min per path: {}", r.sentence()));
    }
    reporter.note(&format!(
        "summary of {} finished jobs: {}",
        records.len(),
        out.join("scale.md").display()
    ));
    Ok(())
}

/// The recommendation at each size from the validation session's scores of every record
/// (each seed a run of its model; a seed ensemble a model of its own), by size; empty
/// without a validation session.
pub(super) fn recommendations(
    records: &[ScaleRecord],
    validation: Option<usize>,
) -> Vec<(f64, Recommendation)> {
    let Some(k) = validation else {
        return Vec::new();
    };
    let mut sizes: Vec<f64> = records.iter().map(|r| r.minutes).collect();
    sizes.sort_by(f64::total_cmp);
    sizes.dedup();
    sizes
        .into_iter()
        .map(|minutes| {
            let runs: Vec<ValidationRun> = records
                .iter()
                .filter(|r| r.minutes == minutes)
                .map(|r| ValidationRun {
                    model: r.model.clone(),
                    run: r.name.clone(),
                    shares: r
                        .paths
                        .iter()
                        .filter(|p| p.session == k)
                        .map(|p| p.removed(p.compensated))
                        .collect(),
                })
                .collect();
            (minutes, recommend_runs(&runs))
        })
        .collect()
}

/// `scale_validation.csv`: every model's score on the validation session, by size.
pub(super) fn validation_csv(recommended: &[(f64, Recommendation)]) -> String {
    let f = |v: f64| format!("{v:.3}");
    let rows = recommended
        .iter()
        .flat_map(|(minutes, r)| {
            r.scores.iter().enumerate().map(move |(i, v)| {
                vec![
                    minutes.to_string(),
                    v.model.clone(),
                    v.seeds.to_string(),
                    f(v.position),
                    f(v.attitude),
                    f(v.score()),
                    (Some(i) == r.best).to_string(),
                    v.best_seed.clone(),
                ]
            })
        })
        .collect();
    csv_text(
        "minutes,model,seeds,pos_removed_pct,att_removed_pct,score,recommended,best_run",
        rows,
    )
}

/// The plot: position error removed on each held-out path, Hilbert's attitude, and the
/// test MAE over the three training paths, against training windows (log axis); the
/// calibration (0 %), the oracle and on Hilbert the paper's figure as lines.
pub(super) fn panels(points: &[Point]) -> Vec<Panel> {
    let mut models: Vec<&str> = Vec::new();
    for p in points {
        if !models.contains(&p.model.as_str()) {
            models.push(&p.model);
        }
    }
    let span = points
        .iter()
        .map(|p| p.train_windows as f64)
        .fold((f64::MAX, 0f64), |(a, b), w| (a.min(w), b.max(w)));
    let level = |name: &str, y: f64| Series::new(name, vec![(span.0, y), (span.1, y)]);
    let removed = |path: &str, att: bool| {
        let at = |p: &&Point| p.path == path;
        let mut series: Vec<Series> = models
            .iter()
            .map(|&m| {
                let pts = points
                    .iter()
                    .filter(|p| at(p) && p.model == m)
                    .map(|p| {
                        let s = if att { &p.att_removed } else { &p.pos_removed };
                        (p.train_windows as f64, s.mean)
                    })
                    .collect();
                Series::new(m, pts)
            })
            .collect();
        let oracle = points
            .iter()
            .filter(at)
            .map(|p| p.oracle_removed[usize::from(att)]);
        let n = points.iter().filter(at).count().max(1) as f64;
        series.push(level("oracle", oracle.sum::<f64>() / n));
        series.push(level("calibration", 0.0));
        if path == PathKind::Hilbert.name() {
            series.push(level("paper", PAPER_HILBERT_REMOVED[usize::from(att)]));
        }
        Panel {
            title: format!(
                "{path}: {} error removed",
                if att { "attitude" } else { "position" }
            ),
            x_label: "training windows".into(),
            y_label: "% of calibrated error".into(),
            series,
            log_x: true,
            ..Panel::default()
        }
    };
    let mut out: Vec<Panel> = PathKind::ALL
        .iter()
        .map(|p| removed(p.name(), false))
        .collect();
    out.push(removed(PathKind::Hilbert.name(), true));
    let test = models
        .iter()
        .map(|&m| {
            let mut by_size: Vec<(f64, f64, usize)> = Vec::new();
            for p in points
                .iter()
                .filter(|p| p.model == m && p.test_pos.mean.is_finite())
            {
                match by_size.iter_mut().find(|s| s.0 == p.train_windows as f64) {
                    Some(s) => (s.1, s.2) = (s.1 + p.test_pos.mean, s.2 + 1),
                    None => by_size.push((p.train_windows as f64, p.test_pos.mean, 1)),
                }
            }
            Series::new(m, by_size.iter().map(|s| (s.0, s.1 / s.2 as f64)).collect())
        })
        .collect();
    out.push(Panel {
        title: "test split: position MAE (mean of 3 paths)".into(),
        x_label: "training windows".into(),
        y_label: "µm".into(),
        series: test,
        log_x: true,
        ..Panel::default()
    });
    out
}
