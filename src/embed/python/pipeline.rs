//! The demo's steps as Python functions for notebooks: `record_data`, `calibrate`,
//! `calibrate_arm`, `train`, `refine`, `adapt`, `evaluate`, each with an optional
//! progress callback, their results as dictionaries.

use std::path::PathBuf;

use pyo3::prelude::*;
use serde::Serialize;

use super::convert::{raise, to_python};
use super::progress::long_call;
use crate::data::DataSources;
use crate::experiment::calibration::{
    calibrate_hybrid, calibrate_serial, ErrorRow, HoldOut, Scoring,
};
use crate::experiment::evaluate::HeldOutConfig;
use crate::gpu::Device;
use crate::model::Checkpoint;
use crate::robot::{Description, ErrorParams};
use crate::train::{self, build_dataset, RunConfig};

fn scoring(hold_out_every: usize, test: Option<PathBuf>) -> Scoring {
    match test {
        Some(t) => Scoring::TestFile(t),
        None => Scoring::HoldOut(HoldOut::Every(hold_out_every)),
    }
}

/// record_data(out, minutes=2.0, machine_seed=1, recipe="use-like", sessions=None, placement=None, path_order=None, closed_loop=None, config=None, progress=None) -> dict
///
/// The demo's data on the twin, into the folder `out`: a calibration set of a cold
/// machine, its EKF calibration, and `minutes` of training recordings per path (grid,
/// fermat, hilbert), in the sessions of the named `recipe` ("use-like", the default: 4
/// sessions at spread placements, the second half recorded again closed loop; "paper":
/// one session at the training placement, open loop; docs/usage.md "Recipes");
/// `sessions`, `placement` ("fixed", "varied" or "spread") and `path_order` ("fixed" or
/// "rotated") change them (docs/twin.md "Sessions"). Closed loop (`closed_loop`, default
/// the recipe's): a round-0 IASTGCN of the run config `config` (TOML; the demo's without
/// one) is trained on the first half of the sessions into `out/round0` and compensates
/// the second half as it is recorded again into `out/closed-loop`, as the demo does.
/// Returns the files: {"recordings": [...] (what to train on: with a closed loop, the
/// first half open loop and the second half closed loop), "calibration": ...,
/// "calibration_set": ..., "closed_loop": what the round did, in words, or None}.
#[pyfunction]
#[pyo3(signature = (out, minutes=2.0, machine_seed=1, recipe="use-like", sessions=None, placement=None, path_order=None, closed_loop=None, config=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn record_data<'py>(
    py: Python<'py>,
    out: PathBuf,
    minutes: f64,
    machine_seed: u64,
    recipe: &str,
    sessions: Option<usize>,
    placement: Option<&str>,
    path_order: Option<&str>,
    closed_loop: Option<bool>,
    config: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    if !(minutes.is_finite() && minutes > 0.0) {
        return Err(raise(format!("minutes must be positive, got {minutes}")));
    }
    use crate::experiment::recipe::NamedRecipe;
    let named = NamedRecipe::parse(recipe).ok_or_else(|| {
        raise(format!(
            "recipe: {recipe:?} is not one of {}",
            NamedRecipe::names()
        ))
    })?;
    let recipe = crate::twin::Recipe {
        sessions: sessions.unwrap_or(named.sessions.sessions),
        placement: match placement {
            Some(p) => p.parse().map_err(raise)?,
            None => named.sessions.placement,
        },
        path_order: match path_order {
            Some(o) => o.parse().map_err(raise)?,
            None => named.sessions.path_order,
        },
    };
    recipe
        .validate(minutes)
        .map_err(|m| raise(format!("sessions: {m}")))?;
    let closed_loop = closed_loop.unwrap_or(named.closed_loop);
    if closed_loop && recipe.sessions < 2 {
        return Err(raise(format!(
            "closed_loop: the second half of the sessions is recorded again with a model \
             trained on the first, so it needs 2 sessions or more, got {}; give \
             closed_loop=False for open-loop data",
            recipe.sessions
        )));
    }
    let (sources, how) = long_call(py, progress, |r| {
        use crate::experiment::protocol::{self, ClosedLoopRound, ModelFiles};
        let sources = protocol::record_data(&out, minutes, machine_seed, &recipe, r)?;
        if !closed_loop {
            return Ok((sources, None));
        }
        let mut round0 = match &config {
            Some(path) => RunConfig::load(path)?,
            None => RunConfig::demo(),
        };
        round0.model.variant = crate::model::Variant::Iastgcn;
        let models = out.join("round0");
        std::fs::create_dir_all(&models).map_err(|e| crate::error::Error::io(&models, e))?;
        let round = ClosedLoopRound {
            recipe: &recipe,
            minutes,
            machine_seed,
            every: named.every,
            name: "round0".into(),
            files: ModelFiles::named(&models, "round0", true),
            dir: out.join("closed-loop"),
        };
        let device = open_device()?;
        let (union, how) = protocol::record_closed_loop(&device, &round, &round0, &sources, r)?;
        Ok((
            union,
            Some(format!("{how}; {}", round.training_set("a model"))),
        ))
    })?;
    #[derive(Serialize)]
    struct Files {
        recordings: Vec<PathBuf>,
        calibration: PathBuf,
        calibration_set: PathBuf,
        closed_loop: Option<String>,
    }
    to_python(
        py,
        &Files {
            recordings: sources.recordings,
            calibration: sources.calibration,
            calibration_set: out.join("calibration_set.csv"),
            closed_loop: how,
        },
    )
}

/// calibrate(measurements, out=None, hold_out_every=5, test=None, recordings=()) -> dict
///
/// EKF calibration of the hybrid machine from a measurement set (CSV: q1..q5,
/// x, y, z, rx, ry, rz). Every `hold_out_every`-th pose is held out and scored (or
/// every pose is fitted and the poses of the file `test` scored), and each recording's
/// tracker poses. Writes the calibration file to `out` when given. Returns the
/// identified parameters, the condition numbers, the EKF stages and the error rows
/// (position µm, attitude mdeg: mean, sd, max) before and after.
#[pyfunction]
#[pyo3(signature = (measurements, out=None, hold_out_every=5, test=None, recordings=Vec::new()))]
pub(super) fn calibrate<'py>(
    py: Python<'py>,
    measurements: PathBuf,
    out: Option<PathBuf>,
    hold_out_every: usize,
    test: Option<PathBuf>,
    recordings: Vec<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let scoring = scoring(hold_out_every, test);
    let done = long_call(py, None, |_| {
        let geometry = crate::robot::Geometry::default_asset();
        let done = calibrate_hybrid(geometry, &measurements, &scoring, &recordings)?;
        if let Some(out) = &out {
            done.save(out)?;
        }
        Ok(done)
    })?;
    #[derive(Serialize)]
    struct Stage {
        name: &'static str,
        round: usize,
        parameters: usize,
        sweeps: usize,
        gamma: f64,
    }
    #[derive(Serialize)]
    struct Result {
        identified: Vec<String>,
        parameters: usize,
        fitted: usize,
        condition: Vec<f64>,
        stages: Vec<Stage>,
        errors: Vec<ErrorRow>,
    }
    let names = ErrorParams::names();
    let c = &done.calibration;
    to_python(
        py,
        &Result {
            identified: c.identified.iter().map(|&k| names[k].clone()).collect(),
            parameters: names.len(),
            fitted: done.fitted,
            condition: c.condition.clone(),
            stages: c
                .stages
                .iter()
                .map(|s| Stage {
                    name: s.name,
                    round: s.round,
                    parameters: s.parameters,
                    sweeps: s.sweeps,
                    gamma: s.gamma,
                })
                .collect(),
            errors: done.rows,
        },
    )
}

/// calibrate_arm(description, poses, out=None, hold_out_every=5, test=None) -> dict
///
/// Calibration of a serial arm (docs/arms.md) from its description file and its pose
/// file (CSV of joint angles and tracker points): registration, the identifiability
/// table, Levenberg–Marquardt. Writes the calibrated description to `out` when given.
/// Returns the parameters (start, calibrated, SD, unit), the ones kept nominal and
/// why, the condition number, and the position error rows (µm) before and after.
#[pyfunction]
#[pyo3(signature = (description, poses, out=None, hold_out_every=5, test=None))]
pub(super) fn calibrate_arm<'py>(
    py: Python<'py>,
    description: PathBuf,
    poses: PathBuf,
    out: Option<PathBuf>,
    hold_out_every: usize,
    test: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let scoring = scoring(hold_out_every, test);
    let (arm, done) = long_call(py, None, |_| {
        let Description::Serial(arm) = Description::load_or_default(Some(&description))? else {
            return Err(crate::error::Error::Invalid(format!(
                "{}: not a serial arm's description (kind = \"serial\"); the hybrid \
                 machine is calibrated with calibrate()",
                description.display()
            )));
        };
        let done = calibrate_serial(&arm, &poses, &scoring)?;
        if let Some(out) = &out {
            done.save(out)?;
        }
        Ok((arm, done))
    })?;
    #[derive(Serialize)]
    struct Parameter {
        name: String,
        start: f64,
        calibrated: f64,
        sd: f64,
        unit: &'static str,
    }
    #[derive(Serialize)]
    struct Kept {
        name: String,
        reason: String,
    }
    #[derive(Serialize)]
    struct Result {
        parameters: Vec<Parameter>,
        kept_nominal: Vec<Kept>,
        condition: f64,
        iterations: usize,
        fitted: usize,
        scored: usize,
        errors: Vec<ErrorRow>,
    }
    let c = &done.calibration;
    let names = arm.names();
    let parameters = c
        .identified
        .iter()
        .enumerate()
        .map(|(k, &i)| {
            let (unit, f) = arm.param_kind(i).display();
            Parameter {
                name: names[i].clone(),
                start: c.registered.values[i] * f,
                calibrated: c.arm.values[i] * f,
                sd: c.sd[k] * f,
                unit,
            }
        })
        .collect();
    to_python(
        py,
        &Result {
            parameters,
            kept_nominal: c
                .kept
                .iter()
                .map(|k| Kept {
                    name: k.name.clone(),
                    reason: k.reason.clone(),
                })
                .collect(),
            condition: c.condition,
            iterations: c.iterations,
            fitted: c.poses,
            scored: done.scored,
            errors: done.rows.clone(),
        },
    )
}

/// The files of a run: recordings, calibration, graph and robot description.
fn sources(
    recordings: Vec<PathBuf>,
    calibration: PathBuf,
    graph: Option<PathBuf>,
    robot: Option<PathBuf>,
) -> DataSources {
    DataSources {
        recordings,
        calibration,
        graph,
        robot,
    }
}

/// Opens the default adapter (`IASTGCN_ADAPTER` picks one by name), or the native CPU
/// where there is none.
fn open_device() -> crate::error::Result<Device> {
    Device::open(None).map_err(|e| crate::error::Error::from(e).context("opening the adapter"))
}

/// train(recordings, calibration, out, config=None, variant=None, max_epochs=None,
///       patience=None, graph=None, robot=None, resume=None, progress=None) -> dict
///
/// Trains a model on `recordings` (labels: residuals under `calibration`) with the run
/// config `config` (TOML; the paper's values without one) and writes its checkpoint to
/// `out` (plus the training log and resumable state beside it). Returns the best
/// validation loss, its epoch, the epochs run, why it stopped, the history and the
/// test-split metrics per recording.
#[pyfunction(name = "train")]
#[pyo3(signature = (recordings, calibration, out, config=None, variant=None, max_epochs=None, patience=None, graph=None, robot=None, resume=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn train_model<'py>(
    py: Python<'py>,
    recordings: Vec<PathBuf>,
    calibration: PathBuf,
    out: PathBuf,
    config: Option<PathBuf>,
    variant: Option<String>,
    max_epochs: Option<usize>,
    patience: Option<usize>,
    graph: Option<PathBuf>,
    robot: Option<PathBuf>,
    resume: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let sources = sources(recordings, calibration, graph, robot);
    let trained = long_call(py, progress, |r| {
        let mut config = RunConfig::read(config.as_deref(), variant.as_deref())?;
        if let Some(n) = max_epochs {
            config.train.max_epochs = n;
        }
        if let Some(n) = patience {
            config.train.patience = n;
        }
        config.validate().map_err(crate::error::Error::Invalid)?;
        let (graph, data) = build_dataset(&sources, &config, None)?;
        r.note(data.summary().trim_end());
        let device = open_device()?;
        train::train(&device, &data, &graph, &config, &out, resume.as_deref(), r)
    })?;
    to_python(py, &trained)
}

/// refine(recordings, calibration, model, out, config=None, graph=None, robot=None,
///        progress=None) -> dict
///
/// The refinement stages (Algorithm 2) of the checkpoint `model` on `recordings`,
/// written to `out`. Returns the verdict, the validation loss of the core stage and of
/// the refined model, whether the core weights were kept, and the test metrics before
/// and after.
#[pyfunction(name = "refine")]
#[pyo3(signature = (recordings, calibration, model, out, config=None, graph=None, robot=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn refine_model<'py>(
    py: Python<'py>,
    recordings: Vec<PathBuf>,
    calibration: PathBuf,
    model: PathBuf,
    out: PathBuf,
    config: Option<PathBuf>,
    graph: Option<PathBuf>,
    robot: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let sources = sources(recordings, calibration, graph, robot);
    #[derive(Serialize)]
    struct Result {
        verdict: String,
        core_validation_loss: f64,
        refined_validation_loss: f64,
        kept_core: bool,
        test_before: Vec<train::TestMetrics>,
        test_after: Vec<train::TestMetrics>,
    }
    let result = long_call(py, progress, |r| {
        let ck = Checkpoint::load(&model)?;
        let config = RunConfig::read(config.as_deref(), None)?;
        let device = open_device()?;
        let refined = train::refine_checkpoint(&device, &sources, &config, &ck, r)
            .map_err(|e| e.context(model.display()))?;
        refined.save(&ck, &out)?;
        Ok(Result {
            verdict: refined.verdict(),
            core_validation_loss: refined.core_val,
            refined_validation_loss: refined.refined_val,
            kept_core: refined.kept_core,
            test_before: refined.metrics_before,
            test_after: refined.metrics_after,
        })
    })?;
    to_python(py, &result)
}

/// adapt(recordings, calibration, model, out, method="offset", config=None, graph=None,
///       robot=None, progress=None) -> dict
///
/// The morning minute (docs/model.md "The morning minute"): the checkpoint `model`
/// adapted to the day of `recordings` (a minute or two of one path with tracker samples)
/// by `method` ("offset", "fine-tune" or "fine-tune:EPOCHS:LR"), written to `out`: the
/// adapted weights when they lower the loss on the recording's last fifth, else the
/// trained ones. Returns the verdict, whether the trained weights were kept, the judging
/// loss before and adapted, the windows that adapted and judged, and the offset's shift
/// (µm, mdeg).
#[pyfunction(name = "adapt")]
#[pyo3(signature = (recordings, calibration, model, out, method="offset", config=None, graph=None, robot=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn adapt_model<'py>(
    py: Python<'py>,
    recordings: Vec<PathBuf>,
    calibration: PathBuf,
    model: PathBuf,
    out: PathBuf,
    method: &str,
    config: Option<PathBuf>,
    graph: Option<PathBuf>,
    robot: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let method: train::Adaptation = method.parse().map_err(raise)?;
    let sources = sources(recordings, calibration, graph, robot);
    #[derive(Serialize)]
    struct Result {
        verdict: String,
        kept_trained: bool,
        loss_before: f64,
        loss_adapted: f64,
        windows: [usize; 2],
        offset: [f64; 6],
    }
    let result = long_call(py, progress, |r| {
        let ck = Checkpoint::load(&model)?;
        let config = RunConfig::read(config.as_deref(), None)?;
        let device = open_device()?;
        let how = train::AdaptConfig::new(method, &config);
        let adapted = train::adapt(&device, &sources, &ck, &how, r)
            .map_err(|e| e.context(model.display()))?;
        adapted.checkpoint(&ck).save(&out)?;
        Ok(Result {
            verdict: adapted.verdict(),
            kept_trained: adapted.kept_trained,
            loss_before: adapted.loss_before,
            loss_adapted: adapted.loss_after,
            windows: adapted.windows,
            offset: adapted.offset,
        })
    })?;
    to_python(py, &result)
}

/// evaluate(models, recordings, calibration, out, config=None, held_out_minutes=None,
///          held_out_seed=None, graph=None, progress=None, held_out_sessions=None) -> dict
///
/// Tables III and V for the checkpoints `models`: each on the test split of
/// `recordings`, and compensating `held_out_sessions` (default 3) held-out sessions of
/// the twin online (runs of `held_out_minutes`, default 0.5, a prediction every tick as
/// the default recipe predicts), scored against the hidden truth and the tracker; each
/// Table V row names its `session` (from 0). Writes the report folder `out` (report.md,
/// CSVs, PNGs). Returns the rows of both tables, the timings, the report's headline (the
/// recommended model on the held-out Hilbert runs, or None) and the report's path.
#[pyfunction(name = "evaluate")]
#[pyo3(signature = (models, recordings, calibration, out, config=None, held_out_minutes=None, held_out_seed=None, graph=None, progress=None, held_out_sessions=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn evaluate_models<'py>(
    py: Python<'py>,
    models: Vec<PathBuf>,
    recordings: Vec<PathBuf>,
    calibration: PathBuf,
    out: PathBuf,
    config: Option<PathBuf>,
    held_out_minutes: Option<f64>,
    held_out_seed: Option<u64>,
    graph: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
    held_out_sessions: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let sources = sources(recordings, calibration, graph, None);
    let mut held = HeldOutConfig::default();
    if let Some(k) = held_out_sessions {
        held.sessions = k;
    }
    if let Some(m) = held_out_minutes {
        held.minutes = m;
    }
    if let Some(s) = held_out_seed {
        held.seed = s;
    }
    #[derive(Serialize)]
    struct Result {
        table_iii: Vec<crate::experiment::report::TableIIIRow>,
        table_v: Vec<crate::experiment::report::TableVRow>,
        timings: Vec<crate::experiment::report::Timing>,
        headline: Option<String>,
        report: PathBuf,
    }
    let result = long_call(py, progress, |r| {
        let config = RunConfig::read(config.as_deref(), None)?;
        std::fs::create_dir_all(&out).map_err(|e| crate::error::Error::io(&out, e))?;
        let device = open_device()?;
        let report = crate::experiment::evaluate::evaluation_report(
            device, &models, &sources, &config, &held, &out, r,
        )?;
        Ok(Result {
            table_iii: report.table_iii,
            table_v: report.table_v,
            timings: report.timings,
            headline: report.headline,
            report: out.join("report.md"),
        })
    })?;
    to_python(py, &result)
}
