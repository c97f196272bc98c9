//! Prediction on recordings: every window end of each recording (on the rows the tracker
//! measured, so that windows have labels), predicted through the batched
//! [`Predictor`] path, with the metrics of Table IV where labels exist, a CSV of every
//! prediction and a PNG of the position residual traces.

use std::path::Path;

use super::metrics::Metrics;
use crate::data::{prepare, split, window_ends, DataSources, FeatureConfig, SplitMode};
use crate::data::{Window, WindowConfig};
use crate::error::{Error, Result};
use crate::gpu::{Device, GpuError};
use crate::model::{Checkpoint, Features, ModelError, Predictor, Residual};
use crate::plot::{self, Panel, Series};

/// Which windows of each recording to predict: all, or one split's (contiguous 70/20/10
/// blocks of each recording).
///
/// ```
/// use iastgcn::train::Subset;
///
/// assert_eq!("test".parse::<Subset>(), Ok(Subset::Test));
/// assert!("holdout".parse::<Subset>().is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Subset {
    /// Every window.
    All,
    /// Windows inside the first 70 % of each recording.
    Train,
    /// Windows inside the next 20 %.
    Validation,
    /// Windows inside the last 10 %.
    Test,
}

impl std::str::FromStr for Subset {
    type Err = String;
    fn from_str(s: &str) -> Result<Subset, String> {
        Ok(match s {
            "all" => Subset::All,
            "train" => Subset::Train,
            "validation" => Subset::Validation,
            "test" => Subset::Test,
            _ => {
                return Err(format!(
                    "unknown split {s:?} (all, train, validation, test)"
                ))
            }
        })
    }
}

/// How to predict on recordings.
#[derive(Clone, Copy, Debug)]
pub struct PredictOptions {
    /// Steps between window ends (≥ 1).
    pub stride: usize,
    /// Which windows.
    pub subset: Subset,
    /// Windows per submit (≥ 1).
    pub batch: usize,
}

/// One predicted window: its last row, that row's time, the prediction and (where the
/// tracker measured) the true residual, µm and mdeg.
#[derive(Clone, Debug)]
pub struct PredictedWindow {
    /// The row the prediction is for, from 0: the window's last row, or the row the
    /// model's `look_ahead` ticks after it.
    pub row: usize,
    /// That row's time, s.
    pub t: f64,
    /// The model's residual.
    pub predicted: Residual,
    /// The label (eq. 19) where the tracker measured at that row.
    pub truth: Option<Residual>,
}

/// The predictions on one recording and their metrics over the labelled windows.
#[derive(Clone, Debug)]
pub struct RecordingPrediction {
    /// The recording's name (its path as given).
    pub recording: String,
    /// Every predicted window, in time order.
    pub windows: Vec<PredictedWindow>,
    /// The metrics over the labelled windows.
    pub metrics: Metrics,
    /// Tool axis at each labelled window's end (the attitude metric's tilt axis).
    axes: Vec<[f64; 3]>,
}

/// Predictions of checkpoint `ck` on the recordings of `sources`.
pub fn predict_recordings(
    device: &Device,
    ck: &Checkpoint,
    sources: &DataSources,
    options: &PredictOptions,
) -> Result<Vec<RecordingPrediction>> {
    if options.stride == 0 || options.batch == 0 {
        return Err(Error::Invalid(format!(
            "stride ({}) and batch ({}) must be at least 1",
            options.stride, options.batch
        )));
    }
    let t_len = ck.config.window;
    let window = WindowConfig {
        length: t_len,
        stride: options.stride,
        look_ahead: ck.config.look_ahead,
        ..WindowConfig::default()
    };
    let inputs = sources.load(&window)?;
    if inputs.graph.nodes != ck.graph.nodes {
        return Err(Error::Invalid(format!(
            "the model was trained on the graph {:?}, the data uses {:?}",
            ck.graph.nodes, inputs.graph.nodes
        )));
    }
    let mut predictor =
        Predictor::on(device, ck, options.batch).map_err(|e| batch_error(e, options.batch))?;
    let mut results = Vec::new();
    for (name, rec) in &inputs.recordings {
        let prepared = prepare(
            name,
            rec,
            &inputs.graph,
            &inputs.robot,
            &FeatureConfig::default(),
        )?;
        // On rows the tracker measured when there are any (so windows have labels), as
        // the dataset does; every `stride` rows otherwise.
        let tracked = prepared.labels.iter().any(Option::is_some);
        let ends: Vec<Window> = window_ends(rec.rows.len(), &window, |e| {
            !tracked || prepared.labels[e].is_some()
        })
        .into_iter()
        .map(|end| Window { recording: 0, end })
        .collect();
        let chosen = match options.subset {
            Subset::All => ends,
            subset => {
                let s = split(&ends, &[rec.rows.len()], &window, SplitMode::Contiguous);
                match subset {
                    Subset::Train => s.train,
                    Subset::Validation => s.validation,
                    _ => s.test,
                }
            }
        };
        let mut x = Vec::with_capacity(chosen.len() * predictor.window_len());
        let mut buf = Vec::new();
        for w in &chosen {
            prepared.window(w.end, t_len, &mut buf);
            x.extend_from_slice(&buf);
        }
        let mut out = Vec::new();
        predictor.predict_batch(&x, Features::Raw, &mut out)?;
        let windows: Vec<PredictedWindow> = chosen
            .iter()
            .zip(out)
            .map(|(w, predicted)| {
                let row = window.label_row(w.end);
                PredictedWindow {
                    row,
                    t: rec.rows[row].t,
                    predicted,
                    truth: prepared.labels[row],
                }
            })
            .collect();
        let (mut pred, mut truth, mut axes) = (Vec::new(), Vec::new(), Vec::new());
        for w in &windows {
            if let (Some(l), Some(a)) = (w.truth, prepared.axes[w.row]) {
                pred.push(w.predicted);
                truth.push(l);
                axes.push(a);
            }
        }
        results.push(RecordingPrediction {
            recording: name.clone(),
            metrics: Metrics::of(&pred, &truth, &axes),
            windows,
            axes,
        });
    }
    Ok(results)
}

/// Metrics over the labelled windows of every recording together.
pub fn overall_metrics(results: &[RecordingPrediction]) -> Metrics {
    let (mut pred, mut truth, mut axes) = (Vec::new(), Vec::new(), Vec::new());
    for r in results {
        let labelled = r
            .windows
            .iter()
            .filter_map(|w| Some((w.predicted, w.truth?)));
        for ((p, t), a) in labelled.zip(&r.axes) {
            pred.push(p);
            truth.push(t);
            axes.push(*a);
        }
    }
    Metrics::of(&pred, &truth, &axes)
}

/// The CSV of every prediction: one row per window end, predicted and (where the tracker
/// measured) true residual.
pub fn predictions_csv(results: &[RecordingPrediction]) -> String {
    let mut csv = String::from("recording,row,t,pred_dx_um,pred_dy_um,pred_dz_um,pred_rx_mdeg,pred_ry_mdeg,pred_rz_mdeg,true_dx_um,true_dy_um,true_dz_um,true_rx_mdeg,true_ry_mdeg,true_rz_mdeg\n");
    for r in results {
        for w in &r.windows {
            csv += &format!("{},{},{:.4}", r.recording, w.row, w.t);
            for v in w.predicted {
                csv += &format!(",{v:.4}");
            }
            for k in 0..6 {
                match w.truth {
                    Some(l) => csv += &format!(",{:.4}", l[k]),
                    None => csv += ",",
                }
            }
            csv.push('\n');
        }
    }
    csv
}

/// Writes the predictions CSV to `out` and the position residual traces (true against
/// predicted, one row of dx, dy, dz panels per recording) to `out` with `.png`; every
/// file is complete before either replaces an older one. Returns the PNG's path.
pub fn write_predictions(
    out: &Path,
    results: &[RecordingPrediction],
) -> Result<std::path::PathBuf> {
    let mut panels = Vec::new();
    for r in results {
        let labelled: Vec<(&PredictedWindow, Residual)> = r
            .windows
            .iter()
            .filter_map(|w| Some((w, w.truth?)))
            .collect();
        let short = Path::new(&r.recording)
            .file_stem()
            .map_or(r.recording.clone(), |s| s.to_string_lossy().into_owned());
        for (k, axis) in ["dx", "dy", "dz"].iter().enumerate() {
            let line = |pick: &dyn Fn(&(&PredictedWindow, Residual)) -> f64| {
                labelled.iter().map(|l| (l.0.t, pick(l))).collect()
            };
            panels.push(Panel {
                title: format!("{short}: {axis}"),
                x_label: "t (s)".into(),
                y_label: "µm".into(),
                series: vec![
                    Series::new("true", line(&|l| l.1[k])),
                    Series::new("predicted", line(&|l| l.0.predicted[k])),
                ],
                equal_aspect: false,
                log_x: false,
                integer_x: false,
            });
        }
    }
    let png = out.with_extension("png");
    let rows = (panels.len() / 3).max(1);
    // Both are written in full before either replaces an older file.
    let mut batch = crate::atomic::Batch::new();
    batch.add_with(&png, |tmp| {
        plot::draw(tmp, &panels, rows, 3, (1500, 330 * rows as u32))
    })?;
    batch
        .add(out, predictions_csv(results).as_bytes())
        .map_err(|e| Error::io(out, e))?;
    batch.commit().map_err(|e| Error::io(out, e))?;
    Ok(png)
}

/// `error` from building work of `batch` windows (`PredictOptions::batch`, the forward's
/// batch), as the setting `predict.batch` with the batch that fits where it is too large
/// for the adapter: "predict.batch: 4096 windows: tensor x needs 9.1 GiB; this adapter
/// allows 2.0 GiB per buffer (…); 512 fit".
pub fn batch_error(error: impl Into<Error>, batch: usize) -> Error {
    let error = error.into();
    let gpu = error
        .find::<GpuError>()
        .or(match error.find::<ModelError>() {
            Some(ModelError::Gpu(e)) => Some(e),
            _ => None,
        });
    match gpu.and_then(|e| e.fitting_count(batch).map(|n| (e, n))) {
        Some((e, n)) => Error::Setting {
            setting: "predict.batch",
            message: format!("{batch} windows: {e}; {n} fit"),
        },
        None => error,
    }
}
