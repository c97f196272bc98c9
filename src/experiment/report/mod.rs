//! The report folder of `iastgcn demo` / `iastgcn evaluate`: Markdown, the machine-readable
//! tables (`table_v.csv`, `table_iii.csv`), timings, and PNGs (loss curves, Fig. 10
//! timings, Fig. 11 residual projection, Fig. 9b accumulated error).

use std::path::{Path, PathBuf};

use crate::error::{write_file, Error, Result};

use crate::plot::{self, Panel, Series};
use crate::train::log::{accumulated_csv, csv_text, distinct, plot_accumulated};
use crate::train::{EpochRecord, Metrics};

pub mod curve;
mod markdown;
pub mod seeds;
pub use markdown::markdown;

pub use crate::compensate::online::{ErrorStats, Trace};

/// One row of the Table V analog.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TableVRow {
    /// The held-out path (`grid`, `fermat`, `hilbert`, `rosette`).
    pub trajectory: String,
    /// The held-out session of the run, from 0 (`evaluate::HeldOutConfig::session`;
    /// reports name it from 1).
    pub session: usize,
    /// `initial`, `calibrated` or `compensated`.
    pub stage: String,
    /// The compensating model (`-` for the initial and calibrated stages).
    pub model: String,
    /// Against the twin's true pad pose, every tick (hidden truth).
    pub truth: ErrorStats,
    /// As the laser tracker measures it, at its samples.
    pub tracker: ErrorStats,
}

impl TableVRow {
    /// The calibrated run of this row's path and held-out session in `rows` (the error a
    /// compensated run is measured against).
    pub fn calibrated_in<'a>(&self, rows: &'a [TableVRow]) -> Option<&'a TableVRow> {
        rows.iter().find(|c| {
            c.stage == "calibrated" && c.trajectory == self.trajectory && c.session == self.session
        })
    }

    /// The share of `calibrated`'s mean true error this run removes, position and
    /// attitude, %.
    pub fn removed_from(&self, calibrated: &TableVRow) -> [f64; 2] {
        let (c, b) = (&calibrated.truth, &self.truth);
        [
            100.0 * (c.position.mean - b.position.mean) / c.position.mean,
            100.0 * (c.attitude.mean - b.attitude.mean) / c.attitude.mean,
        ]
    }

    /// [`TableVRow::removed_from`] the calibrated run of its path and session in `rows`.
    pub fn removed_in(&self, rows: &[TableVRow]) -> Option<[f64; 2]> {
        Some(self.removed_from(self.calibrated_in(rows)?))
    }
}

/// One row of the Table III analog (test-split prediction accuracy).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TableIIIRow {
    /// The training recording whose test block was scored.
    pub trajectory: String,
    /// The model's name, or `training mean` for the baseline.
    pub model: String,
    /// Its prediction errors on that test block.
    pub metrics: Metrics,
}

/// The Fig. 10 analog for one model.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Timing {
    /// The model's name.
    pub model: String,
    /// Mean wall time of a training epoch (core stage).
    pub epoch_seconds: f64,
    /// Latency of one online prediction (B = 1, `Predictor::push`), milliseconds.
    pub infer_ms: f64,
    /// Where it trained: the adapter's name, or the native CPU path and its threads
    /// (`unknown` for a checkpoint without a training log beside it).
    pub trained_on: String,
    /// Where its online predictions ran: the adapter's name, or the native CPU forward.
    pub inference_on: String,
}

/// Fig. 9b curve: (k, mean accumulated position error µm, attitude error mdeg) per horizon.
pub use crate::train::refine::AccumulatedCurve;

/// Everything the report shows.
#[derive(Clone, Debug, Default)]
pub struct Report {
    /// The Markdown heading.
    pub title: String,
    /// One sentence under it: the result a reader came for (the recommended model on the
    /// held-out Hilbert runs), when there is one.
    pub headline: Option<String>,
    /// The GPU adapter the models ran on.
    pub adapter: String,
    /// What produced it (config file, recordings, split mode).
    pub setup: Vec<String>,
    /// Wall time of the whole run, s.
    pub wall_seconds: f64,
    /// The Table V analog: pose errors of the held-out runs.
    pub table_v: Vec<TableVRow>,
    /// The Table III analog: test-split prediction accuracy.
    pub table_iii: Vec<TableIIIRow>,
    /// The Fig. 10 analog: training and inference time per model.
    pub timings: Vec<Timing>,
    /// Training history per model.
    pub histories: Vec<(String, Vec<EpochRecord>)>,
    /// The Fig. 11 analog: residual traces of the held-out runs.
    pub traces: Vec<Trace>,
    /// Fig. 9b: (k, position µm, attitude mdeg) before and after refinement.
    pub accumulated: Option<(AccumulatedCurve, AccumulatedCurve)>,
    /// Free-text findings appended to the Markdown.
    pub notes: Vec<String>,
    /// Markdown sections (heading, body) placed right after the setup, before the tables.
    pub sections: Vec<(String, String)>,
    /// The learning curve (error against training-set size), when measured.
    pub curve: Vec<curve::CurvePoint>,
    /// The recommended model's best seed (its full name), when one was chosen.
    pub recommended: Option<String>,
}

/// Header of `table_v.csv`: every statistic against the hidden truth (`true_`) and as
/// the tracker measured it (`trk_`).
pub const TABLE_V_HEADER: &str = "trajectory,held_out_session,stage,model,\
true_pos_mean_um,true_pos_sd_um,true_pos_max_um,true_att_mean_mdeg,true_att_sd_mdeg,true_att_max_mdeg,\
trk_pos_mean_um,trk_pos_sd_um,trk_pos_max_um,trk_att_mean_mdeg,trk_att_sd_mdeg,trk_att_max_mdeg";
/// Header of `table_iii.csv`.
pub const TABLE_III_HEADER: &str =
    "trajectory,model,pos_mae_um,pos_rmse_um,pos_mape_pct,att_mae_mdeg,att_rmse_mdeg,att_mape_pct";
/// Header of `timings.csv`.
pub const TIMINGS_HEADER: &str = "model,epoch_seconds,infer_ms,trained_on,inference_on";

/// What one file of the report folder is.
#[derive(Clone, Debug, PartialEq)]
enum Kind {
    Markdown,
    Compensated,
    TableV,
    TableIII,
    Timings,
    Fig10,
    /// The trajectory whose traces it shows.
    Fig11(String),
    Losses,
    Accumulated,
    AccumulatedCsv,
    TableVSeeds,
    TableIIISeeds,
    Paired,
    LossesCsv,
    CurveCsv,
    CurvePng,
}

struct Entry {
    name: String,
    what: String,
    kind: Kind,
}

/// A file-name-safe form of a trajectory name.
fn slug(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "trajectory".into()
    } else {
        s
    }
}

/// The files of the report folder for `r`, in the order they are written (report.md last).
fn plan(r: &Report) -> Vec<Entry> {
    let entry = |name: &str, what: String, kind: Kind| Entry {
        name: name.into(),
        what,
        kind,
    };
    let mut out = Vec::new();
    if r.table_v.iter().any(|row| row.stage != "initial") {
        out.push(entry(
            "compensated.png",
            "The result at a glance: mean position (µm) and attitude (mdeg) error against the \
             hidden truth on each held-out path, after calibration alone, with the oracle, \
             and with each model's compensation, each the mean over the held-out sessions \
             and the model's seeds (the uncompensated initial error is left out: it would \
             dwarf the rest)."
                .into(),
            Kind::Compensated,
        ));
    }
    out.extend([
        entry(
            "table_v.csv",
            "Table V analog, machine-readable: mean/SD/max position (µm) and attitude (mdeg) \
             error per trajectory and stage (initial, calibrated, compensated per model)."
                .into(),
            Kind::TableV,
        ),
        entry(
            "table_iii.csv",
            "Table III analog, machine-readable: test-split MAE/RMSE/MAPE of the predicted \
             residuals, position (µm) and attitude (mdeg), per trajectory and model."
                .into(),
            Kind::TableIII,
        ),
        entry(
            "timings.csv",
            "Fig. 10 analog, machine-readable: training seconds per epoch and inference \
             milliseconds per window for each model, with the adapter."
                .into(),
            Kind::Timings,
        ),
    ]);
    if seeds::summarize(r).is_some() {
        out.extend([
            entry(
                "table_v_seeds.csv",
                "Table V over training seeds, machine-readable: mean and sample SD over the \
                 seeds of each model's compensated mean error (truth and tracker) and of the \
                 share of the calibrated error it removed."
                    .into(),
                Kind::TableVSeeds,
            ),
            entry(
                "table_iii_seeds.csv",
                "Table III over training seeds, machine-readable: mean and sample SD of the \
                 test-split MAE and RMSE per trajectory and model."
                    .into(),
                Kind::TableIIISeeds,
            ),
            entry(
                "paired.csv",
                "Paired comparison of every model with the main one, seed by seed: wins, \
                 mean and SD of the difference, verdict."
                    .into(),
                Kind::Paired,
            ),
        ]);
    }
    if !r.timings.is_empty() {
        out.push(entry(
            "fig10_timings.png",
            "Fig. 10 analog: training time per epoch (left) and inference time per window \
             (right) for each model."
                .into(),
            Kind::Fig10,
        ));
    }
    let mut used: Vec<String> = Vec::new();
    for trajectory in distinct(r.traces.iter().map(|t| t.trajectory.as_str())) {
        let mut name = format!("fig11_{}.png", slug(trajectory));
        let mut k = 2;
        while used.contains(&name) {
            name = format!("fig11_{}_{k}.png", slug(trajectory));
            k += 1;
        }
        used.push(name.clone());
        out.push(entry(
            &name,
            format!(
                "Fig. 11 analog for the {trajectory} trajectory: XY projection of the position \
                 residual (µm) before and after compensation (left) and its magnitude over \
                 time (right)."
            ),
            Kind::Fig11(trajectory.into()),
        ));
    }
    if r.histories.iter().any(|(_, h)| !h.is_empty()) {
        out.push(entry(
            "losses.png",
            "Training and validation loss per epoch (standardised), one panel per model.".into(),
            Kind::Losses,
        ));
        out.push(entry(
            "losses.csv",
            "The same curves, machine-readable: `model,stage,epoch,train_loss,val_loss`.".into(),
            Kind::LossesCsv,
        ));
    }
    if !r.curve.is_empty() {
        out.push(entry(
            "learning_curve.png",
            "Learning curve: validation MAE (position, attitude) against the number of \
             training windows, per model, mean over seeds with ± SD marks."
                .into(),
            Kind::CurvePng,
        ));
        out.push(entry(
            "learning_curve.csv",
            "The learning curve, machine-readable: validation and test MAE (mean and SD \
             over seeds) per model and share of the training windows."
                .into(),
            Kind::CurveCsv,
        ));
    }
    if r.accumulated.is_some() {
        out.push(entry(
            "accumulated.csv",
            "Fig. 9b analog, machine-readable: accumulated error over k consecutive windows \
             before and after refinement."
                .into(),
            Kind::AccumulatedCsv,
        ));
        out.push(entry(
            "accumulated.png",
            "Fig. 9b analog: mean accumulated position and attitude error over k consecutive \
             windows, before and after refinement."
                .into(),
            Kind::Accumulated,
        ));
    }
    out.push(entry("report.md", "This report.".into(), Kind::Markdown));
    out
}

/// `table_v.csv`: one line per row, in the given order; µm and mdeg with 4 decimals.
pub fn table_v_csv(rows: &[TableVRow]) -> String {
    csv_text(
        TABLE_V_HEADER,
        rows.iter()
            .map(|r| {
                let mut v = vec![
                    r.trajectory.clone(),
                    r.session.to_string(),
                    r.stage.clone(),
                    r.model.clone(),
                ];
                for e in [&r.truth, &r.tracker] {
                    let (p, a) = (&e.position, &e.attitude);
                    v.extend([p.mean, p.sd, p.max, a.mean, a.sd, a.max].map(|x| format!("{x:.4}")));
                }
                v
            })
            .collect(),
    )
}

/// `table_iii.csv`: one line per row, in the given order; µm and mdeg with 4 decimals,
/// percentages with 3.
pub fn table_iii_csv(rows: &[TableIIIRow]) -> String {
    csv_text(
        TABLE_III_HEADER,
        rows.iter()
            .map(|r| {
                let m = &r.metrics;
                vec![
                    r.trajectory.clone(),
                    r.model.clone(),
                    format!("{:.4}", m.pos_mae),
                    format!("{:.4}", m.pos_rmse),
                    format!("{:.3}", m.pos_mape),
                    format!("{:.4}", m.att_mae),
                    format!("{:.4}", m.att_rmse),
                    format!("{:.3}", m.att_mape),
                ]
            })
            .collect(),
    )
}

/// `losses.csv`: every model's loss per epoch, in the order of `histories`.
pub fn losses_csv(histories: &[(String, Vec<EpochRecord>)]) -> String {
    csv_text(
        "model,stage,epoch,train_loss,val_loss",
        histories
            .iter()
            .flat_map(|(model, history)| {
                history.iter().map(move |r| {
                    vec![
                        model.clone(),
                        r.stage.clone(),
                        r.epoch.to_string(),
                        format!("{:.6e}", r.train_loss),
                        format!("{:.6e}", r.val_loss),
                    ]
                })
            })
            .collect(),
    )
}

/// `timings.csv`: seconds per epoch and milliseconds per window with 4 decimals.
pub fn timings_csv(rows: &[Timing]) -> String {
    csv_text(
        TIMINGS_HEADER,
        rows.iter()
            .map(|t| {
                vec![
                    t.model.clone(),
                    format!("{:.4}", t.epoch_seconds),
                    format!("{:.4}", t.infer_ms),
                    t.trained_on.clone(),
                    t.inference_on.clone(),
                ]
            })
            .collect(),
    )
}

/// Fig. 11 for one trajectory: the (ex, ey) cloud of each trace, equal aspect, with the
/// origin marked, and |e_xy| over time.
fn plot_fig11(path: &Path, trajectory: &str, traces: &[&Trace]) -> Result<(), plot::PlotError> {
    let mut cloud: Vec<Series> = traces
        .iter()
        .map(|t| Series::scatter(&t.label, t.points.iter().map(|p| (p.1, p.2)).collect()))
        .collect();
    cloud.push(Series::scatter("target (0, 0)", vec![(0.0, 0.0)]));
    let magnitude: Vec<Series> = traces
        .iter()
        .map(|t| {
            Series::new(
                &t.label,
                t.points.iter().map(|p| (p.0, p.1.hypot(p.2))).collect(),
            )
        })
        .collect();
    let panels = [
        Panel {
            title: format!("{trajectory}: XY position residual"),
            x_label: "ex (µm)".into(),
            y_label: "ey (µm)".into(),
            series: cloud,
            equal_aspect: true,
            log_x: false,
            integer_x: false,
        },
        Panel {
            title: format!("{trajectory}: |e_xy| over time"),
            x_label: "t (s)".into(),
            y_label: "|e_xy| (µm)".into(),
            series: magnitude,
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        },
    ];
    plot::draw(path, &panels, 1, 2, (1300, 600))
}

/// Two panels per trajectory (position, attitude), against the hidden truth: a bar for
/// the calibrated controller, the oracle and each model (its `<model>.seed<k>` runs
/// together), each the mean over the held-out sessions and the model's seeds (the
/// uncompensated initial error is left out: it would dwarf the rest).
fn plot_compensated(path: &Path, rows: &[TableVRow]) -> Result<(), plot::PlotError> {
    let trajectories = distinct(rows.iter().map(|r| r.trajectory.as_str()));
    let shown: Vec<&TableVRow> = rows.iter().filter(|r| r.stage != "initial").collect();
    let label = |r: &TableVRow| -> String {
        match r.stage.as_str() {
            "compensated" => seeds::split_name(&r.model).0.to_string(),
            stage => stage.to_string(),
        }
    };
    let named: Vec<String> = shown.iter().map(|r| label(r)).collect();
    let labels = distinct(named.iter().map(String::as_str));
    let mut sessions: Vec<usize> = rows.iter().map(|r| r.session).collect();
    sessions.sort_unstable();
    sessions.dedup();
    let sessions = sessions.len();
    let seeded = shown
        .iter()
        .any(|r| seeds::split_name(&r.model).1.is_some());
    let over = match (sessions, seeded) {
        (1, false) => String::new(),
        (n, false) => format!(", mean of {n} held-out sessions"),
        (n, true) => format!(", mean of {n} held-out sessions × the seeds"),
    };
    let mut panels = Vec::new();
    for trajectory in &trajectories {
        let mean_of = |l: &str, pick: fn(&TableVRow) -> f64| -> f64 {
            let v: Vec<f64> = shown
                .iter()
                .filter(|r| &r.trajectory == trajectory && label(r) == l)
                .map(|r| pick(r))
                .collect();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        let bars = |pick: fn(&TableVRow) -> f64| -> Vec<Series> {
            labels
                .iter()
                .enumerate()
                .map(|(i, l)| Series::bars(*l, vec![(i as f64, mean_of(l, pick))]))
                .collect()
        };
        for (what, unit, pick) in [
            (
                "position",
                "µm",
                (|r: &TableVRow| r.truth.position.mean) as fn(&TableVRow) -> f64,
            ),
            ("attitude", "mdeg", |r: &TableVRow| r.truth.attitude.mean),
        ] {
            panels.push(Panel {
                title: format!("{trajectory}: mean {what} error vs truth{over}"),
                y_label: format!("{what} ({unit})"),
                series: bars(pick),
                ..Panel::default()
            });
        }
    }
    let width = (260 + 90 * labels.len() as u32).clamp(600, 1300);
    plot::draw(
        path,
        &panels,
        trajectories.len().max(1),
        2,
        (2 * width, 380 * trajectories.len().max(1) as u32),
    )
}

/// Fig. 10: a bar per model (its `<model>.seed<k>` runs as their mean) for the training
/// time per epoch and the online inference time per window.
fn plot_fig10(path: &Path, timings: &[Timing]) -> Result<(), plot::PlotError> {
    let adapters = distinct(timings.iter().map(|t| t.trained_on.as_str())).join(", ");
    let inference = distinct(timings.iter().map(|t| t.inference_on.as_str())).join(", ");
    let models = distinct(timings.iter().map(|t| seeds::split_name(&t.model).0));
    let seeded = timings
        .iter()
        .any(|t| seeds::split_name(&t.model).1.is_some());
    let over = if seeded { ", mean over seeds" } else { "" };
    let bars = |pick: fn(&Timing) -> f64| -> Vec<Series> {
        models
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let v: Vec<f64> = timings
                    .iter()
                    .filter(|t| seeds::split_name(&t.model).0 == *m)
                    .map(pick)
                    .collect();
                let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
                Series::bars(*m, vec![(i as f64, mean)])
            })
            .collect()
    };
    let panels = [
        Panel {
            title: format!("training time per epoch ({adapters}{over})"),
            x_label: "model".into(),
            y_label: "s / epoch".into(),
            series: bars(|t| t.epoch_seconds),
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        },
        Panel {
            title: format!("inference time per window ({inference}{over})"),
            x_label: "model".into(),
            y_label: "ms / window".into(),
            series: bars(|t| t.infer_ms),
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        },
    ];
    let width = (260 + 110 * models.len() as u32).clamp(520, 1100);
    plot::draw(path, &panels, 1, 2, (2 * width, 440))
}

/// Writes the report folder `dir` (created if missing): `compensated.png` (when Table V
/// has rows beyond the initial ones), `report.md`, `table_v.csv`,
/// `table_iii.csv`, `timings.csv`, `fig10_timings.png` (when there are timings),
/// `fig11_<trajectory>.png` for every trajectory that has traces (Fig. 11 for the Hilbert
/// one is the one the paper shows), `losses.png` (train/val loss per epoch, one panel per
/// model; when some model has a history), and `accumulated.png` plus `accumulated.csv`
/// when `accumulated` is Some. Every file is written atomically; `report.md` is written
/// last. Returns the paths written.
pub fn write(dir: &Path, r: &Report) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let text = |path: &Path, s: &str| write_file(path, s.as_bytes());
    let mut written = Vec::new();
    for e in plan(r) {
        let path = dir.join(&e.name);
        match &e.kind {
            Kind::Markdown => text(&path, &markdown(r))?,
            Kind::Compensated => plot_compensated(&path, &r.table_v)?,
            Kind::TableV => text(&path, &table_v_csv(&r.table_v))?,
            Kind::TableIII => text(&path, &table_iii_csv(&r.table_iii))?,
            Kind::Timings => text(&path, &timings_csv(&r.timings))?,
            Kind::TableVSeeds | Kind::TableIIISeeds | Kind::Paired => {
                if let Some(summary) = seeds::summarize(r) {
                    let body = match e.kind {
                        Kind::TableVSeeds => seeds::table_v_csv(&summary),
                        Kind::TableIIISeeds => seeds::table_iii_csv(&summary),
                        _ => seeds::paired_csv(&summary),
                    };
                    text(&path, &body)?
                }
            }
            Kind::Fig10 => plot_fig10(&path, &r.timings)?,
            Kind::Fig11(trajectory) => {
                let traces: Vec<&Trace> = r
                    .traces
                    .iter()
                    .filter(|t| &t.trajectory == trajectory)
                    .collect();
                plot_fig11(&path, trajectory, &traces)?
            }
            Kind::Losses => crate::train::log::plot_losses(&path, &r.histories)?,
            Kind::LossesCsv => text(&path, &losses_csv(&r.histories))?,
            Kind::CurveCsv => text(&path, &curve::csv(&r.curve))?,
            Kind::CurvePng => curve::plot(&path, &r.curve)?,
            Kind::Accumulated => {
                if let Some((before, after)) = &r.accumulated {
                    plot_accumulated(&path, before, after)?
                }
            }
            Kind::AccumulatedCsv => {
                if let Some((before, after)) = &r.accumulated {
                    text(&path, &accumulated_csv(before, after))?
                }
            }
        }
        written.push(path);
    }
    Ok(written)
}

/// The report's wall time since `began`, then the folder `out` written ([`write`]) and a
/// line saying where; returns the report.
pub fn finish(
    mut report: Report,
    began: std::time::Instant,
    out: &Path,
    reporter: &mut dyn crate::progress::Reporter,
) -> Result<Report> {
    report.wall_seconds = began.elapsed().as_secs_f64();
    let files = write(out, &report)?;
    reporter.note(&format!(
        "report: {} ({} files), {:.0} s in all",
        out.join("report.md").display(),
        files.len(),
        report.wall_seconds
    ));
    Ok(report)
}

/// Table III rows as aligned text lines (for a terminal).
pub fn table_iii_lines(rows: &[TableIIIRow]) -> Vec<String> {
    let w = rows
        .iter()
        .map(|r| r.model.chars().count())
        .max()
        .unwrap_or(0)
        .max(20);
    rows.iter()
        .map(|r| {
            let m = &r.metrics;
            format!(
                "  {:<10} {:<w$} MAE {:>7.2} µm / {:>6.2} mdeg  RMSE {:>7.2} / {:>6.2}  MAPE {:>6.1}% / {:>6.1}%",
                r.trajectory, r.model, m.pos_mae, m.att_mae, m.pos_rmse, m.att_rmse, m.pos_mape, m.att_mape
            )
        })
        .collect()
}

/// Table V rows as aligned text lines under a two-line header (for a terminal).
pub fn table_v_lines(rows: &[TableVRow]) -> Vec<String> {
    // The model column is as wide as its longest name, so the numbers stay in columns.
    let w = rows
        .iter()
        .map(|r| r.model.chars().count())
        .max()
        .unwrap_or(0)
        .max(14);
    let units = 32 + w;
    let mut out = vec![
        format!(
            "{:<10} {:<12} {:<w$} {:<7} {:>9} {:>8} {:>9}   {:>8} {:>7} {:>8}",
            "path", "stage", "model", "vs", "pos mean", "SD", "max", "att mean", "SD", "max"
        ),
        format!("{:<units$} {:>28}   {:>25}", "", "(µm)", "(mdeg)"),
    ];
    for r in rows {
        for (what, e) in [("truth", &r.truth), ("tracker", &r.tracker)] {
            let (p, a) = (e.position, e.attitude);
            out.push(format!(
                "{:<10} {:<12} {:<w$} {:<7} {:>9.1} {:>8.1} {:>9.1}   {:>8.2} {:>7.2} {:>8.2}",
                r.trajectory, r.stage, r.model, what, p.mean, p.sd, p.max, a.mean, a.sd, a.max
            ));
        }
    }
    out
}
