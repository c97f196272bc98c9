//! The paper's tables on the twin: Table III (prediction accuracy on the held-out split
//! per trajectory and model) and Table V (pose error of held-out polishing runs: initial,
//! calibrated, compensated per model).

use super::recommend::{recommend, validation_session};
use super::report::{
    table_iii_lines, table_v_lines, Report, TableIIIRow, TableVRow, Timing, Trace,
};
use crate::calibrate::file;
use crate::compensate::budget::{error_budget, markdown as budget_markdown};
use crate::compensate::held_out::{warm_up_on, HeldOut, IDLE_BETWEEN_RUNS};
use crate::compensate::online::{self, ErrorStats, Feedback, Online, RunResult};
use crate::data::{DataSources, Dataset};
use crate::error::{ensure, Error, Result};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Backend, Checkpoint, Features, ModelError, Predictor};
use crate::progress::Reporter;
use crate::robot::Robot;
use crate::train::metrics::per_recording;
use crate::train::{
    build_dataset, by_path, data_normalization, recording_stem, sibling, RunConfig, TestMetrics,
};
use crate::twin::{draw_machine, Conditions, Machine, MachineState, PathKind, PathParams};

/// Predictions (µm, mdeg) of a checkpoint for the windows at `positions` of a dataset
/// standardised with the checkpoint's own statistics, through the batched
/// [`Predictor`] path.
pub fn predict_windows(
    device: &Device,
    ck: &Checkpoint,
    data: &Dataset,
    positions: &[usize],
) -> Result<Vec<[f64; 6]>, ModelError> {
    let mut predictor = Predictor::on(device, ck, 64.min(positions.len().max(1)))?;
    let (x, _) = data.gather(positions);
    let mut out = Vec::with_capacity(positions.len());
    predictor.predict_batch(&x, Features::Standardised, &mut out)?;
    Ok(out)
}

/// Table III rows of one model: test-split metrics per path (a recording's rows named
/// by its file stem; the sessions of one path pooled), plus the training-mean baseline
/// as the model `training mean` when `baseline` is set.
pub fn table_iii(
    device: &Device,
    model: &str,
    ck: &Checkpoint,
    data: &Dataset,
    baseline: bool,
) -> Result<Vec<TableIIIRow>, ModelError> {
    let [_, _, test] = data.split_ranges();
    let positions: Vec<usize> = test.collect();
    let pred = predict_windows(device, ck, data, &positions)?;
    let per: Vec<TestMetrics> = data
        .recordings
        .iter()
        .zip(per_recording(data, &positions, &pred))
        .map(|(name, (model, training_mean))| TestMetrics {
            recording: recording_stem(name),
            model,
            training_mean,
        })
        .collect();
    let mut rows = Vec::new();
    // The sessions of one path are one row (docs/twin.md "Sessions").
    for t in by_path(&per) {
        rows.push(TableIIIRow {
            trajectory: t.recording.clone(),
            model: model.to_string(),
            metrics: t.model,
        });
        if baseline {
            rows.push(TableIIIRow {
                trajectory: t.recording,
                model: "training mean".into(),
                metrics: t.training_mean,
            });
        }
    }
    Ok(rows)
}

/// Table V rows, Fig. 11 traces, each model's mean prediction latency (ms), and the
/// machine's state after the run under the calibrated controller (to carry the session
/// on with).
pub struct HeldOutResult {
    /// Table V rows: initial, calibrated, oracle, then one compensated row per model.
    pub rows: Vec<TableVRow>,
    /// Fig. 11 traces: the calibrated run, then one per model.
    pub traces: Vec<Trace>,
    /// Each model's name and its mean prediction latency, ms.
    pub latency: Vec<(String, f64)>,
    /// Each model's name, its refused corrections (`online::MAX_CORRECTION`), its
    /// predictions, and the ticks whose corrected target was unreachable.
    pub refused: Vec<(String, usize, usize, usize)>,
    /// The machine's state after the calibrated run.
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
    window: usize,
    models: &mut [LoopModel],
    run: &HeldOut,
    settings: Online,
    mut on_tick: impl FnMut(usize),
) -> Result<HeldOutResult> {
    let name = run.path.name().to_string();
    // Session 0; `held_out_session` numbers the rows of the others.
    let row = |stage: &str, model: &str, r: &RunResult| TableVRow {
        trajectory: name.clone(),
        session: 0,
        stage: stage.into(),
        model: model.into(),
        truth: r.truth,
        tracker: r.tracker,
    };
    let mut rows = Vec::new();
    let mut traces = Vec::new();
    let mut latency = Vec::new();
    let mut refused = Vec::new();
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
    for LoopModel {
        name: model,
        members,
        graph,
    } in models.iter_mut()
    {
        let r = online::run(
            machine,
            calibrated,
            run.config(),
            start(),
            Feedback::Model(members, graph, settings),
            &mut on_tick,
        )?;
        rows.push(row("compensated", model, &r));
        traces.push(online::trace(
            run.path,
            &format!("compensated ({model})"),
            &r,
        ));
        latency.push((model.clone(), r.predict_ms));
        refused.push((model.clone(), r.refused, r.predictions, r.unreachable));
    }
    Ok(HeldOutResult {
        rows,
        traces,
        latency,
        refused,
        end: plain.end,
    })
}

/// Predictors for checkpoints on one device (B = 1, the online path).
pub fn predictors(
    device: &Device,
    models: &[(String, Checkpoint)],
) -> Result<Vec<LoopModel>, ModelError> {
    models
        .iter()
        .map(|(name, ck)| {
            Ok(LoopModel {
                name: name.clone(),
                members: vec![Predictor::on(device, ck, 1)?],
                graph: ck.graph.clone(),
            })
        })
        .collect()
}

/// An ensemble in the control loop, named `name`: the mean of the predictions of
/// `checkpoints` (the seeds of one model), which must read the same sensor graph.
pub fn ensemble(device: &Device, name: &str, checkpoints: &[Checkpoint]) -> Result<LoopModel> {
    let Some(first) = checkpoints.first() else {
        return Err(Error::Invalid(format!("ensemble {name}: no member")));
    };
    if let Some(other) = checkpoints
        .iter()
        .find(|c| c.graph.nodes != first.graph.nodes)
    {
        return Err(Error::Invalid(format!(
            "ensemble {name}: its members read different sensor graphs ([{}] and [{}])",
            first.graph.nodes.join(", "),
            other.graph.nodes.join(", ")
        )));
    }
    Ok(LoopModel {
        name: name.into(),
        members: checkpoints
            .iter()
            .map(|ck| Predictor::on(device, ck, 1))
            .collect::<Result<_, ModelError>>()?,
        graph: first.graph.clone(),
    })
}

/// A model in the control loop: its name, its forward pass (one predictor, or an
/// ensemble's members, whose predictions the controller averages), and the sensor graph
/// its checkpoints read (each model's own: two models may read different sensors).
pub struct LoopModel {
    /// The model's name in the tables.
    pub name: String,
    /// Its forward pass: one predictor, or an ensemble's members.
    pub members: Vec<Predictor>,
    /// The sensor channels it reads, in its node order.
    pub graph: Graph,
}

impl LoopModel {
    /// Where it predicts: the native CPU forward on a CPU adapter, else the adapter.
    pub fn runs_on(&self, device: &Device) -> String {
        self.members
            .first()
            .map_or_else(|| "nowhere".into(), |p| runs_on(device, p))
    }

    /// The window length, ticks, of its first member (the oracle stands in for it).
    pub fn window(&self) -> usize {
        self.members.first().map_or(0, |p| p.config().window)
    }
}

/// The held-out session of an evaluation (Table V): how long each run is, its seeds,
/// how long the machine warms up first, and how often the models predict.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldOutConfig {
    /// Length of each held-out run, minutes (> 0).
    pub minutes: f64,
    /// Seed of the first run; the next paths take the following seeds.
    pub seed: u64,
    /// Minutes of polishing that warm the machine before the first scored run (0: cold).
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks.
    pub every: usize,
    /// Held-out sessions Table V scores (1 to [`MAX_HELD_OUT_SESSIONS`]), sessions 0 to
    /// `sessions − 1` of [`HeldOutConfig::session`]; the validation session that chooses
    /// the recommended model is the next one.
    pub sessions: usize,
}

/// The most held-out sessions an evaluation or a study scores on.
pub const MAX_HELD_OUT_SESSIONS: usize = 16;

impl HeldOutConfig {
    /// Refuses what the held-out session cannot run, naming the setting and its range:
    /// runs of (0, 1440] minutes, a warm-up of [0, 1440] minutes, a prediction every
    /// 1 to 10 000 ticks, 1 to 16 sessions.
    pub fn validate(&self) -> Result<()> {
        ensure((1..=MAX_HELD_OUT_SESSIONS).contains(&self.sessions), || {
            format!(
                "--held-out-sessions: 1 to {MAX_HELD_OUT_SESSIONS} held-out sessions, got {}",
                self.sessions
            )
        })?;
        let day = 1440.0;
        ensure(
            self.minutes.is_finite() && self.minutes > 0.0 && self.minutes <= day,
            || {
                format!(
                    "held-out runs must last more than 0 and at most {day} min, got {} min",
                    self.minutes
                )
            },
        )?;
        ensure(
            self.warm_up_minutes.is_finite() && (0.0..=day).contains(&self.warm_up_minutes),
            || {
                format!(
                    "the warm-up lasts 0 to {day} min, got {} min",
                    self.warm_up_minutes
                )
            },
        )?;
        ensure((1..=10_000).contains(&self.every), || {
            format!(
                "models predict every 1 to 10000 control ticks, got every {}",
                self.every
            )
        })
    }
}

/// One session of a held-out evaluation ([`HeldOutConfig::session`]): how the machine
/// starts, the first run's seed, and the day's conditions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldOutSession {
    /// Its index, from 0.
    pub index: usize,
    /// Minutes of polishing that warm the machine first (0: cold).
    pub warm_up_minutes: f64,
    /// Seed of its first run; the next paths take the following seeds.
    pub seed: u64,
    /// Its day, feed and force.
    pub conditions: Conditions,
}

impl HeldOutSession {
    /// `cold` or `warm-up N min`, the day's ambient offset, feed and force, for reports.
    pub fn describe(&self) -> String {
        let start = if self.warm_up_minutes > 0.0 {
            format!("{} min warm-up", self.warm_up_minutes)
        } else {
            "cold".to_string()
        };
        let c = &self.conditions;
        format!(
            "{start}, ambient {:+.2} K, feed {:.1} mm/s, force {:.1} N, seeds from {}",
            c.day.ambient_offset_k, c.feed_mm_s, c.force_n, self.seed
        )
    }
}

impl HeldOutConfig {
    /// Table V's held-out sessions in words: `3 held-out sessions (1: 2 min warm-up,
    /// ambient …; 2: cold, …; 3: …)`.
    pub fn describe_sessions(&self) -> String {
        let each: Vec<String> = (0..self.sessions)
            .map(|k| format!("{}: {}", k + 1, self.session(k).describe()))
            .collect();
        format!(
            "{} held-out session(s) ({})",
            self.sessions,
            each.join("; ")
        )
    }

    /// Held-out session `k` (docs/twin.md "Scoring"). Session 0 is the evaluation's own:
    /// the calibration day at the default feed and force, `warm_up_minutes` of warm-up,
    /// seeds from `seed`. Session k ≥ 1 is another day, its conditions drawn as a
    /// multi-session training set's are ([`Conditions::draw`] from `seed · 1000 + k`),
    /// seeds from `seed + 10k`; odd sessions start cold, even ones after three times the
    /// warm-up. Each runs the paths at [`PathParams::held_out_in`] for its index.
    pub fn session(&self, k: usize) -> HeldOutSession {
        if k == 0 {
            return HeldOutSession {
                index: 0,
                warm_up_minutes: self.warm_up_minutes,
                seed: self.seed,
                conditions: Conditions::NOMINAL,
            };
        }
        HeldOutSession {
            index: k,
            warm_up_minutes: if k % 2 == 1 {
                0.0
            } else {
                3.0 * self.warm_up_minutes
            },
            seed: self.seed + 10 * k as u64,
            conditions: Conditions::draw(self.seed * 1000 + k as u64),
        }
    }
}

impl Default for HeldOutConfig {
    /// The demo's sessions: three, of 0.5 min runs from seed 301, the first after 2 min
    /// of warm-up, a prediction every 5 ticks.
    fn default() -> HeldOutConfig {
        HeldOutConfig {
            minutes: 0.5,
            seed: 301,
            warm_up_minutes: 2.0,
            every: 5,
            sessions: 3,
        }
    }
}

/// A checkpoint with the name the tables give it, and its mean training time per epoch
/// (NaN when unknown).
#[derive(Clone, Debug)]
pub struct NamedModel {
    /// The model's name in the tables.
    pub name: String,
    /// Its weights, config, graph and normalisation.
    pub checkpoint: Checkpoint,
    /// Mean wall time of a training epoch, s (NaN when unknown).
    pub epoch_seconds: f64,
    /// Where it trained (`unknown` without a training log).
    pub trained_on: String,
}

impl NamedModel {
    /// The checkpoint at `path`, named by its file stem (an older demo's
    /// `<model>.seed<k>-refined` is `<model>.seed<k>`: [`super::report::seeds::model_name`]); a
    /// `<stem>.log.csv` beside it gives its training time per epoch and where it trained.
    pub fn load(path: &std::path::Path) -> Result<NamedModel> {
        let name = path.file_stem().map_or("model".into(), |s| {
            super::report::seeds::model_name(&s.to_string_lossy()).to_string()
        });
        let (epoch_seconds, trained_on) =
            read_training_log(&sibling(path, ".log.csv")).unwrap_or((f64::NAN, "unknown".into()));
        Ok(NamedModel {
            name,
            checkpoint: Checkpoint::load(path)?,
            epoch_seconds,
            trained_on,
        })
    }
}

/// The mean `seconds` of the core epochs in a training log (of every epoch when it has
/// no core stage, as a refined model's log) and where they ran (`train::log::trained_on`
/// of those epochs; `unknown` in logs written before that column), if the log exists
/// and has epochs.
fn read_training_log(log: &std::path::Path) -> Option<(f64, String)> {
    let mut reader = csv::Reader::from_path(log).ok()?;
    let header = reader.headers().ok()?.clone();
    let column = |name: &str| header.iter().position(|h| h == name);
    let (stage, seconds, on) = (column("stage")?, column("seconds")?, column("trained_on"));
    let rows: Vec<csv::StringRecord> = reader.records().filter_map(|r| r.ok()).collect();
    let core: Vec<&csv::StringRecord> = rows
        .iter()
        .filter(|r| r.get(stage) == Some("core"))
        .collect();
    let picked = if core.is_empty() {
        rows.iter().collect()
    } else {
        core
    };
    let values: Vec<f64> = picked
        .iter()
        .filter_map(|r| r.get(seconds)?.parse().ok())
        .collect();
    if values.is_empty() {
        return None;
    }
    let trained_on = crate::train::log::trained_on(
        on.into_iter()
            .flat_map(|c| picked.iter().filter_map(move |r| r.get(c))),
    );
    Some((values.iter().sum::<f64>() / values.len() as f64, trained_on))
}

/// Table III (each model on the test split of `sources`, windowed as `config` says and
/// standardised with the model's own statistics) and Table V (every path of one held-out
/// session in the twin, compensated by each model), with the Hilbert run's error budget,
/// Fig. 11 traces and Fig. 10 timings, added to `report`. Each model reads the sensors of
/// its own checkpoint's graph online; the oracle runs at the first model's window; Fig.
/// 11 shows the first model named `iastgcn` or `iastgcn.seed<k>` (or the first).
pub fn evaluate(
    device: &Device,
    report: &mut Report,
    models: &[NamedModel],
    sources: &DataSources,
    config: &RunConfig,
    held: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let Some(first) = models.first() else {
        return Err(Error::Invalid("no model to evaluate".into()));
    };
    held.validate()?;
    reporter.note("== Table III: prediction accuracy on the held-out split");
    let windowed = Graph::load_or_default(sources.graph.as_deref())?;
    let mut rows: Vec<TableIIIRow> = Vec::new();
    for (i, m) in models.iter().enumerate() {
        let mut c = config.clone();
        c.model = m.checkpoint.config.clone();
        let fixed =
            data_normalization(&m.checkpoint.normalization).map_err(|e| e.context(&m.name))?;
        // The test windows are read with the sources' graph: a model that reads other
        // sensors would be scored on the wrong channels.
        if windowed.nodes != m.checkpoint.graph.nodes {
            return Err(Error::Invalid(format!(
                "{}: the model reads the sensors [{}], but the recordings are windowed with \
                 the graph [{}] (--graph); evaluate models with another sensor graph in a \
                 call of their own with their graph",
                m.name,
                m.checkpoint.graph.nodes.join(", "),
                windowed.nodes.join(", ")
            )));
        }
        let (_, data) = build_dataset(sources, &c, Some(&fixed))?;
        rows.extend(table_iii(device, &m.name, &m.checkpoint, &data, i == 0)?);
    }
    for line in table_iii_lines(&rows) {
        reporter.note(&line);
    }
    report.table_iii = rows;

    reporter.note("== Table V: compensation of held-out runs in the twin");
    let checkpoints: Vec<(String, Checkpoint)> = models
        .iter()
        .map(|m| (m.name.clone(), m.checkpoint.clone()))
        .collect();
    let mut in_loop = predictors(device, &checkpoints)?;
    let table_v_session = SessionOptions {
        budget: true,
        ..SessionOptions::rows(0)
    };
    let session = held_out_session(
        device,
        &mut in_loop,
        sources,
        held,
        table_v_session,
        reporter,
    )?;
    if let Some(budget) = session.budget {
        report.sections.push((
            format!("Error budget: {} (held-out run)", PathKind::Hilbert.name()),
            format!(
                "The hidden tool-pose error of this run split by source (RMS over every tick, \
                 against the path target; `iastgcn budget` gives it for any run):\n\n{budget}"
            ),
        ));
    }
    report.table_v.extend(session.rows);
    // The other held-out sessions: Table V's rows only (its traces, budget and timings
    // are the first session's).
    for k in 1..held.sessions {
        reporter.note(&format!(
            "== Table V, held-out session {} of {}: {}",
            k + 1,
            held.sessions,
            held.session(k).describe()
        ));
        let other = held_out_session(
            device,
            &mut in_loop,
            sources,
            held,
            SessionOptions::rows(k),
            reporter,
        )?;
        report.table_v.extend(other.rows);
        report.setup.extend(other.refusals);
    }

    reporter.note(
        "== recommended model: every model in the loop on a validation session (not in Table V)",
    );
    let validation_index = validation_session(held.sessions);
    let validation = held_out_session(
        device,
        &mut in_loop,
        sources,
        held,
        SessionOptions::rows(validation_index),
        reporter,
    )?;
    let recommendation = recommend(&validation.rows);
    reporter.note(&recommendation.sentence());
    report.headline = recommendation.headline(&report.table_v);
    report.recommended = recommendation
        .best
        .map(|i| recommendation.scores[i].best_seed.clone());
    report.setup.push(recommendation.sentence());
    report.sections.push((
        "Recommended model".into(),
        recommendation.markdown(
            (
                validation_index + 1,
                &held.session(validation_index).describe(),
            ),
            held.minutes,
        ),
    ));
    report.setup.push(format!(
        "held-out session (Table V): twin machine {}, the machine the recordings were taken \
         on (their `.run.toml` sidecars; machine 1 when none has one)",
        session.machine_seed
    ));
    report.setup.extend(session.calibration_warning);
    report.setup.extend(session.refusals);
    // Fig. 11 shows before/after: calibration only, and the main model.
    let main = models
        .iter()
        .find(|m| super::report::seeds::split_name(&m.name).0 == "iastgcn")
        .unwrap_or(first)
        .name
        .clone();
    let keep = format!("compensated ({main})");
    report.traces.extend(
        session
            .traces
            .into_iter()
            .filter(|t| t.label == "calibrated" || t.label == keep),
    );
    report.timings = models
        .iter()
        .zip(session.latency_ms)
        .zip(session.ran_on)
        .map(|((m, infer_ms), inference_on)| Timing {
            model: m.name.clone(),
            epoch_seconds: m.epoch_seconds,
            infer_ms,
            trained_on: m.trained_on.clone(),
            inference_on,
        })
        .collect();
    Ok(())
}

/// Where `predictor`'s predictions run: "native CPU forward", or the adapter's name.
pub fn runs_on(device: &Device, predictor: &Predictor) -> String {
    match predictor.backend() {
        Backend::Native => "native CPU forward".to_string(),
        Backend::Device => device.name(),
    }
}

/// What one held-out session gave ([`held_out_session`]).
pub struct Session {
    /// Table V rows of every path: initial, calibrated, oracle, then each model.
    pub rows: Vec<TableVRow>,
    /// Every run's tracker trace (Fig. 11), path by path.
    pub traces: Vec<Trace>,
    /// Each model's mean latency of one online prediction, ms.
    pub latency_ms: Vec<f64>,
    /// Where each model's online predictions ran (the native CPU forward or the adapter).
    pub ran_on: Vec<String>,
    /// A line per path where the controller refused a model's corrections.
    pub refusals: Vec<String>,
    /// The twin machine the session ran on (the recordings' machine).
    pub machine_seed: u64,
    /// A warning when the calibration was measured on another machine than the session's.
    pub calibration_warning: Option<String>,
    /// The Hilbert run's error budget as Markdown, when asked for.
    pub budget: Option<String>,
    /// When asked for: per path and model, the open-loop diagnosis ([`OpenLoopScore`]).
    pub open_loop: Vec<OpenLoopScore>,
}

/// The open-loop diagnosis of one model on one held-out run (docs/shift/README.md
/// "Where the error goes").
#[derive(Clone, Debug)]
pub struct OpenLoopScore {
    /// The path.
    pub path: String,
    /// The model.
    pub model: String,
    /// How far its predictions along the uncompensated run were from the true residual
    /// (µm, tool-axis mdeg; [`online::Feedback::OpenLoop`]).
    pub miss: ErrorStats,
    /// The run's true error with those predictions fed forward as corrections, each
    /// from the tick the model would have set it, without their feedback on the model's
    /// inputs ([`online::Feedback::Replay`]).
    pub replayed: ErrorStats,
}

/// Which held-out session [`held_out_session`] runs and what it measures beyond Table V.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SessionOptions {
    /// The session's index ([`HeldOutConfig::session`]; the evaluation's own is 0).
    pub index: usize,
    /// The Hilbert run's error budget by source.
    pub budget: bool,
    /// Each model's open-loop diagnosis ([`OpenLoopScore`]).
    pub open_loop: bool,
}

impl SessionOptions {
    /// Session `index`, Table V's rows only.
    pub fn rows(index: usize) -> SessionOptions {
        SessionOptions {
            index,
            budget: false,
            open_loop: false,
        }
    }
}

/// Held-out session `options.index` of `held` ([`HeldOutConfig::session`]) on the
/// machine the recordings of `sources` were taken on, under their calibration: the
/// machine warms up, then every path runs in turn, each stage of a path (initial,
/// calibrated, oracle, each of `models` in the loop: predictors or ensembles,
/// [`predictors`], [`ensemble`]) from the same state, and the session carries on from the
/// calibrated run's end, so the rows of the initial, calibrated and oracle stages do not
/// depend on the models. The first model gives the window of the oracle. With
/// `options.budget`, the Hilbert run's error budget by source too. With
/// `options.open_loop`, each model also predicts along every path's uncompensated run
/// from the same start, its predictions scored against the true residual and never
/// applied, then fed forward ([`Session::open_loop`]).
pub fn held_out_session(
    device: &Device,
    models: &mut [LoopModel],
    sources: &DataSources,
    held: &HeldOutConfig,
    options: SessionOptions,
    reporter: &mut dyn Reporter,
) -> Result<Session> {
    let k = options.index;
    let Some(first) = models.first() else {
        return Err(Error::Invalid("no model to compensate with".into()));
    };
    held.validate()?;
    let geometry = sources.geometry()?;
    let cal = file::load(&sources.calibration)?;
    // The held-out session runs on the machine the recordings were taken on.
    let machine_seed = sources.machine_seed()?;
    let machine = draw_machine(geometry.clone(), machine_seed);
    let nominal = Robot::nominal(geometry.clone());
    let calibrated = cal.robot(geometry);
    // The oracle stands in for a model of the first one's window.
    let window = first.window();
    let ran_on: Vec<String> = models.iter().map(|m| m.runs_on(device)).collect();
    let mut latency = vec![(0.0, 0usize); models.len()];
    let mut session = Session {
        rows: Vec::new(),
        traces: Vec::new(),
        latency_ms: Vec::new(),
        ran_on,
        refusals: Vec::new(),
        machine_seed,
        calibration_warning: None,
        budget: None,
        open_loop: Vec::new(),
    };
    if let Some(m) = cal.machine_seed.filter(|&m| m != machine_seed) {
        let warning = format!(
            "warning: the calibration {} was measured on twin machine {m}, but the recordings \
             and this held-out session are on machine {machine_seed}: the calibrated rows \
             compensate another machine's geometric errors",
            sources.calibration.display()
        );
        reporter.note(&warning);
        session.calibration_warning = Some(warning);
    }
    let plan = held.session(k);
    let mut state = warm_up_on(
        &machine,
        &calibrated,
        plan.warm_up_minutes * 60.0,
        plan.seed.wrapping_add(1000),
        &plan.conditions,
    )?;
    for (i, path) in PathKind::ALL.into_iter().enumerate() {
        let run = HeldOut {
            path,
            params: PathParams::held_out_in(path, k),
            seconds: held.minutes * 60.0,
            seed: plan.seed + i as u64,
            start: state.clone(),
            conditions: plan.conditions,
        };
        // One budget (the Hilbert run's) keeps the demo in its time; `iastgcn budget`
        // gives any other.
        if options.budget && path == PathKind::Hilbert {
            let b = error_budget(&machine, &calibrated, &run.config(), &run.start)?;
            session.budget = Some(budget_markdown(&b));
        }
        let stages = 3 + models.len() * if options.open_loop { 3 } else { 1 };
        let ticks = run.config().steps() * stages;
        reporter.begin(&format!("compensating {}", path.name()), ticks as u64);
        let mut done = 0u64;
        let mut tick = |_| {
            done += 1;
            if done.is_multiple_of(50) {
                reporter.update(done, "");
            }
        };
        let settings = Online { every: held.every };
        let mut result = table_v(
            &machine,
            &nominal,
            &calibrated,
            window,
            models,
            &run,
            settings,
            &mut tick,
        )?;
        if options.open_loop {
            for m in models.iter_mut() {
                let score = open_loop_score(&machine, &calibrated, &run, m, settings, &mut tick)?;
                session.open_loop.extend(score);
            }
        }
        reporter.end();
        for row in result.rows.iter_mut() {
            row.session = k;
        }
        for line in table_v_lines(&result.rows) {
            reporter.note(&line);
        }
        session.rows.extend(result.rows);
        for (model, n, of, ticks) in result.refused.iter().filter(|r| r.1 + r.3 > 0) {
            let (mm, deg) = crate::compensate::online::MAX_CORRECTION;
            let line = format!(
                "{}: the controller refused {n} of {of} corrections predicted by {model} (beyond {mm} mm or {deg}°; it kept its last accepted correction) and ran {ticks} ticks uncorrected because the corrected target was unreachable",
                path.name()
            );
            reporter.note(&line);
            session.refusals.push(line);
        }
        state = result.end;
        state.idle(IDLE_BETWEEN_RUNS);
        session.traces.extend(result.traces);
        for (slot, (_, ms)) in latency.iter_mut().zip(result.latency) {
            slot.0 += ms;
            slot.1 += 1;
        }
    }
    session.latency_ms = latency
        .iter()
        .map(|(ms, n)| ms / (*n).max(1) as f64)
        .collect();
    Ok(session)
}

/// The open-loop diagnosis of `model` on `run` (from its start, under `calibrated`): its
/// predictions along the uncompensated run against the true residual, then fed forward.
fn open_loop_score(
    machine: &Machine,
    calibrated: &Robot,
    run: &HeldOut,
    model: &mut LoopModel,
    settings: Online,
    mut on_tick: impl FnMut(usize),
) -> Result<Option<OpenLoopScore>> {
    let open = online::run(
        machine,
        calibrated,
        run.config(),
        run.start.clone(),
        Feedback::OpenLoop(&mut model.members, &model.graph, settings),
        &mut on_tick,
    )?;
    let replayed = online::run(
        machine,
        calibrated,
        run.config(),
        run.start.clone(),
        Feedback::Replay(&open.predicted),
        &mut on_tick,
    )?;
    Ok(open.open_loop.map(|miss| OpenLoopScore {
        path: run.path.name().to_string(),
        model: model.name.clone(),
        miss,
        replayed: replayed.truth,
    }))
}

/// Tables III and V of `models` into `report`, with the table of how much each model's
/// graph convolution mixes the sensors.
pub(super) fn tables(
    device: &Device,
    report: &mut Report,
    models: &[NamedModel],
    sources: &DataSources,
    config: &RunConfig,
    held_out: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    evaluate(device, report, models, sources, config, held_out, reporter)?;
    if let Some(table) = graph_mixing_table(models) {
        report
            .sections
            .push(("Graph convolution after training".into(), table));
    }
    Ok(())
}

/// The report's table of how much each model's graph convolution mixes the sensors
/// (`model::graph_mixing`, per block); None when no model has one.
fn graph_mixing_table(models: &[NamedModel]) -> Option<String> {
    let rows: Vec<(&str, Vec<f64>)> = models
        .iter()
        .map(|m| {
            let c = &m.checkpoint;
            (
                m.name.as_str(),
                crate::model::graph_mixing(&c.config, &c.graph, &c.parameters),
            )
        })
        .filter(|(_, v)| !v.is_empty())
        .collect();
    let blocks = rows.iter().map(|(_, v)| v.len()).max()?;
    let mut out = String::from(
        "How much each block's graph convolution mixes the sensors after training: \
         ‖Ψ − diag Ψ‖ / ‖diag Ψ‖ (Frobenius) with Ψ = Σ_k θ_k basis_k (docs/model.md \
         step 3). 0 is the identity, no mixing: the wavelet convolution starts there with \
         every θ = 1, and stays near it unless its θ move apart; the Chebyshev convolution \
         of `iastgcn-s` starts near 0.95 on the embedded graph.\n\n| Model |",
    );
    for l in 1..=blocks {
        out.push_str(&format!(" Block {l} |"));
    }
    out.push_str("\n|---|");
    out.push_str(&"---:|".repeat(blocks));
    out.push('\n');
    for (name, v) in rows {
        out.push_str(&format!("| {name} |"));
        for l in 0..blocks {
            match v.get(l) {
                Some(x) => out.push_str(&format!(" {x:.3} |")),
                None => out.push_str(" |"),
            }
        }
        out.push('\n');
    }
    Some(out)
}
