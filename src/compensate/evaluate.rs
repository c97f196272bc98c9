//! The paper's tables on the twin: Table III (prediction accuracy on the held-out split
//! per trajectory and model) and Table V (pose error of held-out polishing runs: initial,
//! calibrated, compensated per model).

use std::sync::Arc;

use super::online::{self, Feedback, Online, RunResult};
use super::report::{TableIIIRow, TableVRow, Trace};
use crate::data::{Dataset, OUTPUTS};
use crate::gpu::{Gpu, Recorder};
use crate::graph::Graph;
use crate::model::{Checkpoint, ModelError, Network, Predictor};
use crate::robot::Robot;
use crate::train::metrics::per_recording;
use crate::train::to_physical;
use crate::twin::{Machine, MachineState, PathKind, PathParams, SimConfig};

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

/// A held-out polishing run to compensate: its path and placement on the part, length,
/// seed, and the machine's state when it starts (warm from the session's earlier runs).
#[derive(Clone, Debug)]
pub struct HeldOut {
    pub path: PathKind,
    pub params: PathParams,
    pub seconds: f64,
    pub seed: u64,
    pub start: MachineState,
}

impl HeldOut {
    /// The run's simulation settings.
    pub fn config(&self) -> SimConfig {
        let mut c = SimConfig::new(self.path, self.seconds, self.seed);
        c.path_params = self.params;
        c
    }
}

/// Table V rows, Fig. 11 traces, each model's mean prediction latency (ms), and the
/// machine's state after the run under the calibrated controller (to carry the session
/// on with).
pub struct HeldOutResult {
    pub rows: Vec<TableVRow>,
    pub traces: Vec<Trace>,
    pub latency: Vec<(String, f64)>,
    pub end: MachineState,
}

/// Table V rows and Fig. 11 traces of one held-out run, every stage starting from the
/// same machine state: the nominal controller (initial), the calibrated one
/// (calibrated), the calibrated one fed the true residual with a `window`-step model's
/// latency and rate (oracle), and the calibrated one compensating online with each model.
#[allow(clippy::too_many_arguments)]
pub fn table_v(
    machine: &Machine,
    nominal: &Robot,
    calibrated: &Robot,
    graph: &Graph,
    window: usize,
    models: &mut [(String, Predictor)],
    run: &HeldOut,
    settings: Online,
    mut on_tick: impl FnMut(usize),
) -> anyhow::Result<HeldOutResult> {
    let name = run.path.name().to_string();
    let row = |stage: &str, model: &str, r: &RunResult| TableVRow {
        trajectory: name.clone(),
        stage: stage.into(),
        model: model.into(),
        truth: r.truth,
        tracker: r.tracker,
    };
    let mut rows = Vec::new();
    let mut traces = Vec::new();
    let mut latency = Vec::new();
    let start = || run.start.clone();
    let initial = online::run(
        machine,
        nominal,
        run.config(),
        start(),
        Feedback::None,
        &mut on_tick,
    )?;
    rows.push(row("initial", "-", &initial));
    let plain = online::run(
        machine,
        calibrated,
        run.config(),
        start(),
        Feedback::None,
        &mut on_tick,
    )?;
    rows.push(row("calibrated", "-", &plain));
    traces.push(online::trace(run.path, "calibrated", &plain));
    let oracle = online::run(
        machine,
        calibrated,
        run.config(),
        start(),
        Feedback::Oracle { window, settings },
        &mut on_tick,
    )?;
    rows.push(row("oracle", "true residual", &oracle));
    for (model, predictor) in models.iter_mut() {
        let r = online::run(
            machine,
            calibrated,
            run.config(),
            start(),
            Feedback::Model(predictor, graph, settings),
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
    Ok(HeldOutResult {
        rows,
        traces,
        latency,
        end: plain.end,
    })
}

/// Seconds the machine stands idle between two runs of a session (the operator sets up
/// the next program).
pub const IDLE_BETWEEN_RUNS: f64 = 30.0;

/// A cold machine warmed by `seconds` of polishing (0: left cold) under `controller`,
/// then idle for [`IDLE_BETWEEN_RUNS`]: the start of a held-out session. The warm-up walks
/// the raster turned a quarter turn, which no scored run retraces.
pub fn warm_up(
    machine: &Machine,
    controller: &Robot,
    seconds: f64,
    seed: u64,
) -> anyhow::Result<MachineState> {
    let mut state = machine.cold();
    if seconds > 0.0 {
        let mut config = SimConfig::new(PathKind::Grid, seconds, seed);
        config.path_params.rotation_deg = 90.0;
        state = online::run(machine, controller, config, state, Feedback::None, |_| {})?.end;
        state.idle(IDLE_BETWEEN_RUNS);
    }
    Ok(state)
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
