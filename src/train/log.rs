//! The training log as CSV (one row per epoch, every stage) and the loss curves as PNG.

use std::path::Path;

use super::trainer::EpochRecord;
use crate::plot::{self, Panel, PlotError, Series};

/// Writes the epoch history as CSV (atomically).
pub fn write_csv(path: &Path, history: &[EpochRecord]) -> anyhow::Result<()> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record([
        "stage",
        "epoch",
        "step",
        "train_loss",
        "val_loss",
        "lr",
        "seconds",
        "windows_per_s",
    ])?;
    for r in history {
        w.write_record([
            r.stage.clone(),
            r.epoch.to_string(),
            r.step.to_string(),
            format!("{:.6e}", r.train_loss),
            format!("{:.6e}", r.val_loss),
            format!("{:.6e}", r.lr),
            format!("{:.3}", r.seconds),
            format!("{:.1}", r.windows_per_s),
        ])?;
    }
    let bytes = w.into_inner()?;
    crate::atomic::write(path, &bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
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
