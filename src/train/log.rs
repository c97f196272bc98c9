//! The training log as CSV (one row per epoch, every stage) and the loss curves as PNG.

use std::path::Path;

use super::trainer::EpochRecord;
use crate::error::{write_file, Error, Result};
use crate::plot::{self, Panel, PlotError, Series};

/// Where a history's epochs ran, in order, each device once per run of epochs: `NVIDIA
/// H200`, or `NVIDIA H200, then native CPU (2 threads)` for a job resumed elsewhere
/// (`unknown` without epochs or names).
///
/// ```
/// use iastgcn::train::log::trained_on;
/// let epochs = ["NVIDIA H200", "NVIDIA H200", "native CPU (2 threads)"];
/// assert_eq!(trained_on(epochs), "NVIDIA H200, then native CPU (2 threads)");
/// assert_eq!(trained_on(Vec::<&str>::new()), "unknown");
/// ```
pub fn trained_on<'a>(epochs: impl IntoIterator<Item = &'a str>) -> String {
    let mut places: Vec<&str> = Vec::new();
    for on in epochs.into_iter().filter(|on| !on.is_empty()) {
        if places.last() != Some(&on) {
            places.push(on);
        }
    }
    if places.is_empty() {
        "unknown".into()
    } else {
        places.join(", then ")
    }
}

/// Writes the epoch history as CSV (atomically).
pub fn write_csv(path: &Path, history: &[EpochRecord]) -> Result<()> {
    write_file(path, history_csv(history).as_bytes())
}

/// The epoch history as CSV text, one row per epoch.
pub fn history_csv(history: &[EpochRecord]) -> String {
    let header = [
        "stage",
        "epoch",
        "step",
        "train_loss",
        "val_loss",
        "lr",
        "seconds",
        "windows_per_s",
        "validation_seconds",
        "readback_seconds",
        "trained_on",
    ]
    .join(",");
    let rows = history
        .iter()
        .map(|r| {
            vec![
                r.stage.clone(),
                r.epoch.to_string(),
                r.step.to_string(),
                format!("{:.6e}", r.train_loss),
                format!("{:.6e}", r.val_loss),
                format!("{:.6e}", r.lr),
                format!("{:.3}", r.seconds),
                format!("{:.1}", r.windows_per_s),
                format!("{:.3}", r.validation_seconds),
                format!("{:.3}", r.readback_seconds),
                r.trained_on.clone(),
            ]
        })
        .collect();
    csv_text(&header, rows)
}

/// Reads an epoch history written by [`write_csv`]; the error names the file and line.
pub fn read_csv(path: &Path) -> Result<Vec<EpochRecord>> {
    read_rows(path)
}

/// Reads every row of a CSV file with a header into `T` (columns by name; others are
/// ignored); the error names the file and line.
pub fn read_rows<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    let bad = |e: csv::Error| {
        let line = e
            .position()
            .map_or(String::new(), |p| format!(":{}", p.line()));
        Error::Invalid(format!("{}{line}: {e}", path.display()))
    };
    let mut reader = csv::Reader::from_path(path).map_err(bad)?;
    reader.deserialize().map(|r| r.map_err(bad)).collect()
}

/// Distinct values in order of first appearance.
pub fn distinct<'a>(values: impl Iterator<Item = &'a str>) -> Vec<&'a str> {
    let mut out: Vec<&str> = Vec::new();
    for v in values {
        if !out.contains(&v) {
            out.push(v);
        }
    }
    out
}

/// Train/validation loss per epoch, one panel per model; epochs count on across stages,
/// one pair of series per stage.
pub fn plot_losses(path: &Path, histories: &[(String, Vec<EpochRecord>)]) -> Result<(), PlotError> {
    let panels: Vec<Panel> = histories
        .iter()
        .filter(|(_, h)| !h.is_empty())
        .map(|(model, history)| {
            let stages = distinct(history.iter().map(|r| r.stage.as_str()));
            let mut series = Vec::new();
            for stage in &stages {
                let points = |f: fn(&EpochRecord) -> f64| -> Vec<(f64, f64)> {
                    history
                        .iter()
                        .enumerate()
                        .filter(|(_, r)| r.stage == *stage)
                        .map(|(i, r)| ((i + 1) as f64, f(r)))
                        .collect()
                };
                let (train, val) = if stages.len() == 1 {
                    ("train".to_string(), "validation".to_string())
                } else {
                    (format!("{stage} train"), format!("{stage} validation"))
                };
                series.push(Series::new(train, points(|r| r.train_loss)));
                series.push(Series::new(val, points(|r| r.val_loss)));
            }
            Panel {
                title: format!("{model}: loss"),
                x_label: if stages.len() == 1 {
                    "epoch".into()
                } else {
                    "epoch (all stages)".into()
                },
                y_label: "loss (standardised)".into(),
                series,
                equal_aspect: false,
                log_x: false,
                integer_x: true,
            }
        })
        .collect();
    let n = panels.len().max(1);
    let cols = n.min(3);
    let rows = n.div_ceil(cols);
    plot::draw(
        path,
        &panels,
        rows,
        cols,
        (520 * cols as u32, 420 * rows as u32),
    )
}

/// CSV text of `rows` under the comma-separated `header`.
pub fn csv_text(header: &str, rows: Vec<Vec<String>>) -> String {
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    // invariant: writing to a Vec cannot fail, and the fields are UTF-8 strings.
    w.write_record(header.split(',')).expect("in-memory CSV");
    for row in rows {
        w.write_record(&row).expect("in-memory CSV");
    }
    String::from_utf8(w.into_inner().expect("in-memory CSV")).expect("UTF-8 fields")
}

/// The Fig. 9b table: horizon, position and attitude before and after refinement.
pub fn accumulated_csv(before: &[(usize, f64, f64)], after: &[(usize, f64, f64)]) -> String {
    let mut ks: Vec<usize> = before.iter().chain(after).map(|r| r.0).collect();
    ks.sort_unstable();
    ks.dedup();
    let cell = |v: &[(usize, f64, f64)], k: usize, pick: fn(&(usize, f64, f64)) -> f64| {
        v.iter()
            .find(|r| r.0 == k)
            .map_or(String::new(), |r| format!("{:.4}", pick(r)))
    };
    csv_text(
        "horizon,pos_before_um,att_before_mdeg,pos_after_um,att_after_mdeg",
        ks.into_iter()
            .map(|k| {
                vec![
                    k.to_string(),
                    cell(before, k, |r| r.1),
                    cell(before, k, |r| r.2),
                    cell(after, k, |r| r.1),
                    cell(after, k, |r| r.2),
                ]
            })
            .collect(),
    )
}

/// Fig. 9b's curves before and after refinement, read back from a file
/// [`accumulated_csv`] wrote (the 4 decimals it keeps); the error names the file and line.
#[allow(clippy::type_complexity)]
pub fn read_accumulated(path: &Path) -> Result<(Vec<(usize, f64, f64)>, Vec<(usize, f64, f64)>)> {
    #[derive(serde::Deserialize)]
    struct Row {
        horizon: usize,
        pos_before_um: Option<f64>,
        att_before_mdeg: Option<f64>,
        pos_after_um: Option<f64>,
        att_after_mdeg: Option<f64>,
    }
    let rows: Vec<Row> = read_rows(path)?;
    let pairs = |pick: fn(&Row) -> (Option<f64>, Option<f64>)| -> Vec<(usize, f64, f64)> {
        rows.iter()
            .filter_map(|r| match pick(r) {
                (Some(p), Some(a)) => Some((r.horizon, p, a)),
                _ => None,
            })
            .collect()
    };
    Ok((
        pairs(|r| (r.pos_before_um, r.att_before_mdeg)),
        pairs(|r| (r.pos_after_um, r.att_after_mdeg)),
    ))
}

/// The Fig. 9b chart: accumulated position and attitude error before and after refinement.
pub fn plot_accumulated(
    path: &Path,
    before: &[(usize, f64, f64)],
    after: &[(usize, f64, f64)],
) -> Result<(), plot::PlotError> {
    type Pick = fn(&(usize, f64, f64)) -> f64;
    let series = |v: &[(usize, f64, f64)], pick: Pick, name: &str| {
        Series::new(name, v.iter().map(|r| (r.0 as f64, pick(r))).collect())
    };
    // Refinement that kept the incoming weights draws one curve over the other: say so.
    let same = before == after;
    let panel = |title: &str, unit: &str, pick: Pick| Panel {
        title: if same {
            format!("{title} (refinement kept the weights: one curve)")
        } else {
            title.into()
        },
        x_label: "consecutive windows k".into(),
        y_label: format!("mean |Σ(ŷ−y)| ({unit})"),
        series: vec![
            series(before, pick, "before refinement"),
            series(after, pick, "after refinement"),
        ],
        equal_aspect: false,
        log_x: false,
        integer_x: true,
    };
    plot::draw(
        path,
        &[
            panel("accumulated position error", "µm", |r| r.1),
            panel("accumulated attitude error", "mdeg", |r| r.2),
        ],
        1,
        2,
        (1100, 420),
    )
}
