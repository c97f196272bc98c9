//! The learning curve: error against the size of the training set. Each point is one
//! model trained (core stage) on a share of the training windows, over its seeds, and
//! scored in µm and mdeg on the unchanged validation and test splits (physical units,
//! since each share standardises with its own training statistics).

use std::fmt::Write as _;
use std::path::Path;

use super::seeds::Spread;
use crate::plot::{self, Panel, PlotError, Series};
use crate::train::log::{csv_text, distinct};

/// One model at one share of the training windows, over its seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct CurvePoint {
    /// The model.
    pub model: String,
    /// Share of the training windows, (0, 1].
    pub fraction: f64,
    /// Training windows at that share.
    pub windows: usize,
    /// Validation MAE, position µm.
    pub val_pos: Spread,
    /// Validation MAE, attitude mdeg.
    pub val_att: Spread,
    /// Test MAE, position µm.
    pub test_pos: Spread,
    /// Test MAE, attitude mdeg.
    pub test_att: Spread,
}

/// Header of `learning_curve.csv`.
pub const CURVE_HEADER: &str = "model,fraction,train_windows,seeds,\
val_pos_mae_mean_um,val_pos_mae_sd_um,val_att_mae_mean_mdeg,val_att_mae_sd_mdeg,\
test_pos_mae_mean_um,test_pos_mae_sd_um,test_att_mae_mean_mdeg,test_att_mae_sd_mdeg";

/// `learning_curve.csv`: one line per model and share.
pub fn csv(points: &[CurvePoint]) -> String {
    csv_text(
        CURVE_HEADER,
        points
            .iter()
            .map(|p| {
                let mut v = vec![
                    p.model.clone(),
                    format!("{}", p.fraction),
                    p.windows.to_string(),
                    p.val_pos.n.to_string(),
                ];
                for s in [&p.val_pos, &p.val_att, &p.test_pos, &p.test_att] {
                    v.extend([format!("{:.4}", s.mean), format!("{:.4}", s.sd)]);
                }
                v
            })
            .collect(),
    )
}

/// The Markdown section.
pub fn markdown(points: &[CurvePoint]) -> String {
    let mut out = String::from(
        "## Learning curve: error against training-set size\n\n\
         Each model's core stage trained on the first share of every recording's training \
         block (as if it had been recorded for less time), validation and test blocks \
         unchanged, over the training seeds; MAE in µm / mdeg (mean ± sample SD over \
         seeds), before refinement. A curve still falling at the full share says more data \
         would lower the error; curves that cross say more data could change the ranking.\n\n\
         | Model | Share | Training windows | Validation MAE pos. (µm) | Validation MAE att. (mdeg) | Test MAE pos. (µm) | Test MAE att. (mdeg) |\n\
         |---|---:|---:|---:|---:|---:|---:|\n",
    );
    let text = |s: &Spread| format!("{:.2} ± {:.2}", s.mean, s.sd);
    for p in points {
        let _ = writeln!(
            out,
            "| {} | {:.0} % | {} | {} | {} | {} | {} |",
            p.model,
            100.0 * p.fraction,
            p.windows,
            text(&p.val_pos),
            text(&p.val_att),
            text(&p.test_pos),
            text(&p.test_att)
        );
    }
    out.push('\n');
    out
}

/// `learning_curve.png`: validation MAE (position, attitude) against training windows,
/// one line per model, with the seed SD as a band of two thin lines.
pub fn plot(path: &Path, points: &[CurvePoint]) -> Result<(), PlotError> {
    let models = distinct(points.iter().map(|p| p.model.as_str()));
    let panel = |what: &str, unit: &str, pick: fn(&CurvePoint) -> Spread| {
        let mut series = Vec::new();
        for m in &models {
            let of: Vec<&CurvePoint> = points.iter().filter(|p| p.model == *m).collect();
            let line = |k: f64| -> Vec<(f64, f64)> {
                of.iter()
                    .map(|p| {
                        let s = pick(p);
                        (p.windows as f64, s.mean + k * s.sd)
                    })
                    .collect()
            };
            series.push(Series::new(m.to_string(), line(0.0)));
            series.push(Series::scatter(format!("{m} ± SD"), {
                let mut band = line(-1.0);
                band.extend(line(1.0));
                band
            }));
        }
        Panel {
            title: format!("validation MAE, {what}, against training-set size"),
            x_label: "training windows".into(),
            y_label: format!("{what} MAE ({unit})"),
            series,
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        }
    };
    let panels = [
        panel("position", "µm", |p| p.val_pos),
        panel("attitude", "mdeg", |p| p.val_att),
    ];
    plot::draw(path, &panels, 1, 2, (1300, 520))
}
