//! The paper's tables on the twin: Table III (prediction accuracy on the held-out split
//! per trajectory and model) and Table V (pose error of held-out polishing runs: initial,
//! calibrated, compensated per model).

use std::sync::Arc;

use super::online::{self, Online, RunResult};
use super::report::{TableIIIRow, TableVRow, Trace};
use crate::data::{Dataset, OUTPUTS};
use crate::gpu::{Gpu, Recorder};
use crate::graph::Graph;
use crate::model::{Checkpoint, ModelError, Network, Predictor};
use crate::robot::Robot;
use crate::train::metrics::per_recording;
use crate::train::to_physical;
use crate::twin::{Machine, PathKind, SimConfig};

/// Predictions (µm, mdeg) of a checkpoint for the windows at `positions` of a dataset
/// standardised with the checkpoint's own statistics (so the dataset's label statistics
/// are the checkpoint's).
pub fn predict_windows(
    gpu: &Gpu,
    ck: &Checkpoint,
    data: &Dataset,
    positions: &[usize],
) -> Result<Vec<[f64; 6]>, ModelError> {
    let batch = 64.min(positions.len().max(1));
    let net = Network::for_inference(gpu, &ck.config, &ck.graph, batch)?;
    net.load_parameters(gpu, &ck.parameters)?;
    let len = data.window_len();
    let mut out = Vec::with_capacity(positions.len());
    for chunk in positions.chunks(batch) {
        let (mut x, _) = data.gather(chunk);
        x.resize(batch * len, 0.0);
        gpu.write(&net.input, &x)?;
        let mut rec = Recorder::new(gpu);
        net.record_forward(&mut rec)?;
        rec.submit();
        let y = gpu.read_f32(&net.output)?;
        out.extend(to_physical(
            &y[..chunk.len() * OUTPUTS],
            &data.normalization,
        ));
    }
    Ok(out)
}

/// Table III rows of one model: test-split metrics per recording (`names[r]` labels
/// recording r), plus the training-mean baseline as the model `training mean` when
/// `baseline` is set.
pub fn table_iii(
    gpu: &Gpu,
    model: &str,
    ck: &Checkpoint,
    data: &Dataset,
    names: &[String],
    baseline: bool,
) -> Result<Vec<TableIIIRow>, ModelError> {
    let [_, _, test] = data.split_ranges();
    let positions: Vec<usize> = test.collect();
    let pred = predict_windows(gpu, ck, data, &positions)?;
    let mut rows = Vec::new();
    for (name, (metrics, mean)) in names.iter().zip(per_recording(data, &positions, &pred)) {
        rows.push(TableIIIRow {
            trajectory: name.clone(),
            model: model.to_string(),
            metrics,
        });
        if baseline {
            rows.push(TableIIIRow {
                trajectory: name.clone(),
                model: "training mean".into(),
                metrics: mean,
            });
        }
    }
    Ok(rows)
}

/// A held-out polishing run to compensate.
#[derive(Clone, Copy, Debug)]
pub struct HeldOut {
    pub path: PathKind,
    pub seconds: f64,
    pub seed: u64,
}

/// Table V rows, Fig. 11 traces and each model's mean prediction latency (ms).
pub type HeldOutResult = (Vec<TableVRow>, Vec<Trace>, Vec<(String, f64)>);

/// Table V rows and Fig. 11 traces of one held-out run: the nominal controller
/// (initial), the calibrated one (calibrated), and the calibrated one compensating
/// online with each model. Returns also each model's mean prediction latency (ms).
#[allow(clippy::too_many_arguments)]
pub fn table_v(
    machine: &Machine,
    nominal: &Robot,
    calibrated: &Robot,
    graph: &Graph,
    models: &mut [(String, Predictor)],
    run: HeldOut,
    settings: Online,
    mut on_tick: impl FnMut(usize),
) -> anyhow::Result<HeldOutResult> {
    let name = run.path.name().to_string();
    let config = || SimConfig::new(run.path, run.seconds, run.seed);
    let row = |stage: &str, model: &str, r: &RunResult| TableVRow {
        trajectory: name.clone(),
        stage: stage.into(),
        model: model.into(),
        errors: r.errors,
    };
    let mut rows = Vec::new();
    let mut traces = Vec::new();
    let mut latency = Vec::new();
    let initial = online::run(machine, nominal, config(), None, &mut on_tick)?;
    rows.push(row("initial", "-", &initial));
    let plain = online::run(machine, calibrated, config(), None, &mut on_tick)?;
    rows.push(row("calibrated", "-", &plain));
    traces.push(online::trace(run.path, "calibrated", &plain));
    for (model, predictor) in models.iter_mut() {
        let r = online::run(
            machine,
            calibrated,
            config(),
            Some((predictor, graph, settings)),
            &mut on_tick,
        )?;
        rows.push(row("compensated", model, &r));
        traces.push(online::trace(
            run.path,
            &format!("compensated ({model})"),
            &r,
        ));
        latency.push((model.clone(), r.predict_ms));
    }
    Ok((rows, traces, latency))
}

/// Predictors for checkpoints on one device (B = 1, the online path).
pub fn predictors(
    gpu: &Arc<Gpu>,
    models: &[(String, Checkpoint)],
) -> Result<Vec<(String, Predictor)>, ModelError> {
    models
        .iter()
        .map(|(name, ck)| Ok((name.clone(), Predictor::new(gpu.clone(), ck, 1)?)))
        .collect()
}
