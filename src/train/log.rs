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

/// Training and validation loss per epoch, one panel per stage (log-free linear axes).
pub fn plot_losses(path: &Path, title: &str, history: &[EpochRecord]) -> Result<(), PlotError> {
    let mut stages: Vec<&str> = Vec::new();
    for r in history {
        if !stages.contains(&r.stage.as_str()) {
            stages.push(&r.stage);
        }
    }
    let panels: Vec<Panel> = stages
        .iter()
        .map(|stage| {
            let rows = history.iter().filter(|r| r.stage == *stage);
            let points = |f: fn(&EpochRecord) -> f64| {
                rows.clone()
                    .map(|r| (r.epoch as f64, f(r)))
                    .collect::<Vec<_>>()
            };
            Panel {
                title: format!("{title}: {stage}"),
                x_label: "epoch".into(),
                y_label: "loss (standardised)".into(),
                series: vec![
                    Series::new("train", points(|r| r.train_loss)),
                    Series::new("validation", points(|r| r.val_loss)),
                ],
                equal_aspect: false,
            }
        })
        .collect();
    let n = panels.len().max(1);
    plot::draw(path, &panels, 1, n, (520 * n as u32, 420))
}
