//! Accuracy metrics of Table IV on residuals in physical units, the loss bracket of
//! eq. 39 evaluated on the host, and the accumulated long-horizon error of Fig. 9b.
//!
//! Position is scored as a vector: the error of one window is the Euclidean norm of ŷ − y
//! over dx, dy, dz (µm). Attitude is scored as Table V scores it, by the tool axis: the
//! error is the part of the rotation-vector difference (rx, ry, rz, mdeg) across the tool
//! axis a at the window's end, ‖e − (e·a)a‖, which is to first order the angle by which
//! the predicted correction would misplace the axis; the roll about the axis is left out,
//! as the 2R head leaves it free (docs/twin.md "Scoring").
//! MAE = mean ‖ŷ − y‖, RMSE = √(mean ‖ŷ − y‖²), and
//! MAPE = 100 · mean ‖ŷ − y‖ / max(‖y‖, g) %, with the guard g = 5% of the mean label
//! norm of the evaluated set, so a label that happens to pass near zero cannot blow
//! the percentage up (it is scored against g instead).

use serde::Serialize;

use crate::data::Dataset;

/// The share of the mean label norm below which MAPE divides by the guard instead.
pub const MAPE_GUARD: f64 = 0.05;

/// MAE, RMSE, MAPE for position (µm) and attitude (mdeg) over `count` windows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Metrics {
    /// Windows scored.
    pub count: usize,
    /// Mean Euclidean position error over dx, dy, dz, µm.
    pub pos_mae: f64,
    /// RMS of the position error, µm.
    pub pos_rmse: f64,
    /// Mean position error relative to the label's norm (guarded by [`MAPE_GUARD`]), %.
    pub pos_mape: f64,
    /// Mean attitude error across the tool axis, mdeg (docs/twin.md "Scoring").
    pub att_mae: f64,
    /// RMS of the attitude error, mdeg.
    pub att_rmse: f64,
    /// Mean attitude error relative to the label's (guarded by [`MAPE_GUARD`]), %.
    pub att_mape: f64,
}

fn norm3(v: &[f64; 6], from: usize) -> f64 {
    (v[from].powi(2) + v[from + 1].powi(2) + v[from + 2].powi(2)).sqrt()
}

fn diff(a: &[f64; 6], b: &[f64; 6]) -> [f64; 6] {
    std::array::from_fn(|k| a[k] - b[k])
}

/// The attitude part of `v` (components 3..6) across the unit `axis`: ‖r − (r·a)a‖.
fn tilt(v: &[f64; 6], axis: &[f64; 3]) -> f64 {
    let along = v[3] * axis[0] + v[4] * axis[1] + v[5] * axis[2];
    ((v[3] - along * axis[0]).powi(2)
        + (v[4] - along * axis[1]).powi(2)
        + (v[5] - along * axis[2]).powi(2))
    .sqrt()
}

impl Metrics {
    /// The metrics of several sets of windows scored together: MAE and MAPE the
    /// count-weighted means, RMSE the root of the count-weighted mean square (exact for
    /// MAE and RMSE; each set keeps its own MAPE guard). Sets without windows drop out.
    pub fn pooled<'a>(parts: impl IntoIterator<Item = &'a Metrics>) -> Metrics {
        let parts: Vec<&Metrics> = parts.into_iter().filter(|m| m.count > 0).collect();
        let count: usize = parts.iter().map(|m| m.count).sum();
        if count == 0 {
            return Metrics::default();
        }
        let n = count as f64;
        let mean = |f: &dyn Fn(&Metrics) -> f64| {
            parts.iter().map(|m| m.count as f64 * f(m)).sum::<f64>() / n
        };
        Metrics {
            count,
            pos_mae: mean(&|m| m.pos_mae),
            pos_rmse: mean(&|m| m.pos_rmse * m.pos_rmse).sqrt(),
            pos_mape: mean(&|m| m.pos_mape),
            att_mae: mean(&|m| m.att_mae),
            att_rmse: mean(&|m| m.att_rmse * m.att_rmse).sqrt(),
            att_mape: mean(&|m| m.att_mape),
        }
    }

    /// Scores predictions against labels (both in µm / mdeg), each window's attitude
    /// across its tool axis `axes[i]` (unit, base frame).
    ///
    /// ```
    /// use iastgcn::train::Metrics;
    ///
    /// let truth = [[10.0, 0.0, 0.0, 0.0, 0.0, 2.0]];
    /// let pred = [[7.0, 4.0, 0.0, 0.0, 0.0, 5.0]];
    /// let m = Metrics::of(&pred, &truth, &[[0.0, 0.0, 1.0]]);
    /// assert_eq!((m.pos_mae, m.pos_mape), (5.0, 50.0)); // ‖(−3, 4, 0)‖ µm against 10 µm
    /// assert_eq!(m.att_mae, 0.0); // the roll about the tool axis is not scored
    /// ```
    pub fn of(pred: &[[f64; 6]], truth: &[[f64; 6]], axes: &[[f64; 3]]) -> Metrics {
        assert_eq!(pred.len(), truth.len(), "one prediction per label");
        assert_eq!(axes.len(), truth.len(), "one tool axis per label");
        let n = pred.len();
        if n == 0 {
            return Metrics::default();
        }
        let part = |size: &dyn Fn(&[f64; 6], usize) -> f64| {
            let guard = MAPE_GUARD
                * truth
                    .iter()
                    .enumerate()
                    .map(|(i, y)| size(y, i))
                    .sum::<f64>()
                / n as f64;
            let (mut abs, mut sq, mut pct) = (0.0, 0.0, 0.0);
            for (i, (p, y)) in pred.iter().zip(truth).enumerate() {
                let e = size(&diff(p, y), i);
                abs += e;
                sq += e * e;
                pct += e / size(y, i).max(guard).max(f64::MIN_POSITIVE);
            }
            let nf = n as f64;
            (abs / nf, (sq / nf).sqrt(), 100.0 * pct / nf)
        };
        let (pos_mae, pos_rmse, pos_mape) = part(&|v, _| norm3(v, 0));
        let (att_mae, att_rmse, att_mape) = part(&|v, i| tilt(v, &axes[i]));
        Metrics {
            count: n,
            pos_mae,
            pos_rmse,
            pos_mape,
            att_mae,
            att_rmse,
            att_mape,
        }
    }
}

/// Per recording of `data` (index = recording): the metrics of `pred` (µm, mdeg, one per
/// entry of `positions`) against the labels, and those of predicting the training mean.
pub fn per_recording(
    data: &Dataset,
    positions: &[usize],
    pred: &[[f64; 6]],
) -> Vec<(Metrics, Metrics)> {
    (0..data.recordings.len())
        .map(|r| {
            let idx: Vec<usize> = (0..positions.len())
                .filter(|&i| data.windows[positions[i]].recording == r)
                .collect();
            let truth: Vec<[f64; 6]> = idx.iter().map(|&i| data.labels[positions[i]]).collect();
            let axes: Vec<[f64; 3]> = idx.iter().map(|&i| data.axes[positions[i]]).collect();
            let model: Vec<[f64; 6]> = idx.iter().map(|&i| pred[i]).collect();
            let mean = vec![data.normalization.label_mean; idx.len()];
            (
                Metrics::of(&model, &truth, &axes),
                Metrics::of(&mean, &truth, &axes),
            )
        })
        .collect()
}

/// ℓ of eq. 39 for one window: Σ_j w_j (ŷ_j − y_j)², w = 1 (position), P (attitude).
pub fn window_loss(pred: &[f32], truth: &[f32], penalty: f64) -> f64 {
    pred.iter()
        .zip(truth)
        .enumerate()
        .map(|(j, (p, y))| {
            let e = (*p as f64) - (*y as f64);
            if j < 3 {
                e * e
            } else {
                penalty * e * e
            }
        })
        .sum()
}

/// The loss of docs/model.md "Refinement" for one ensemble of m windows (rows of `pred`,
/// `truth`, `outputs` values each): mean per-window ℓ plus ℓ of the means. For m = 1 it
/// is the plain ℓ.
pub fn ensemble_loss(pred: &[f32], truth: &[f32], outputs: usize, penalty: f64) -> f64 {
    let m = pred.len() / outputs;
    let per: f64 = pred
        .chunks(outputs)
        .zip(truth.chunks(outputs))
        .map(|(p, y)| window_loss(p, y, penalty))
        .sum::<f64>()
        / m as f64;
    if m == 1 {
        return per;
    }
    let mean = |v: &[f32]| -> Vec<f32> {
        (0..outputs)
            .map(|j| {
                (v.iter()
                    .skip(j)
                    .step_by(outputs)
                    .map(|&x| x as f64)
                    .sum::<f64>()
                    / m as f64) as f32
            })
            .collect()
    };
    per + window_loss(&mean(pred), &mean(truth), penalty)
}

/// Accumulated error of Fig. 9b: for horizons k = 1..=`horizon`, the mean over every run
/// of consecutive windows and every start in it of ‖Σ_{j<k} (ŷ − y)‖, position (µm)
/// and attitude (mdeg). Horizons no run is long enough for are left out.
pub fn accumulated_error(
    runs: &[Vec<([f64; 6], [f64; 6])>],
    horizon: usize,
) -> Vec<(usize, f64, f64)> {
    let mut out = Vec::new();
    for k in 1..=horizon {
        let (mut pos, mut att, mut n) = (0.0, 0.0, 0usize);
        for run in runs.iter().filter(|r| r.len() >= k) {
            for start in 0..=run.len() - k {
                let mut s = [0.0; 6];
                for (p, y) in &run[start..start + k] {
                    for j in 0..6 {
                        s[j] += p[j] - y[j];
                    }
                }
                pos += norm3(&s, 0);
                att += norm3(&s, 3);
                n += 1;
            }
        }
        if n > 0 {
            out.push((k, pos / n as f64, att / n as f64));
        }
    }
    out
}
