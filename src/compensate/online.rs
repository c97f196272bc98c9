//! Online compensation in the twin (docs/twin.md "Scoring", section IV-E): at each
//! control tick the controller streams the sensor values into the causal features, the
//! [`Predictor`] predicts the residual of the window ending at that tick, and the
//! predicted residual is subtracted from the commanded pose of the next tick before
//! inverse kinematics. Every run is scored twice against the path target (position in
//! µm, tool-axis angle in mdeg; the roll about the axis is free, docs/twin.md "Scoring"):
//! by the twin's true pad pose at every tick (hidden truth), and by the tracker's
//! measurements. Both are taken in the frame the part was located in: the cell measures
//! the mirror with the same tracker, so its pose reaches the controller through the
//! controller's registration ([`located`]).

use std::collections::VecDeque;
use std::time::Instant;

use crate::error::{ensure, Error, Result};

use super::ensemble::Ensemble;
use super::sensor_predictor::SensorPredictor;
use crate::graph::Graph;
use crate::model::Predictor;
use crate::robot::Robot;
use crate::stats::Summary;
use crate::twin::{
    located, pose_error, Correction, Machine, MachineState, Mirror, PathKind, Sample, SimConfig,
    Simulation, CHANNELS,
};
use nalgebra::Isometry3;

/// What a compensated (or plain) run measured.
#[derive(Clone, Debug)]
pub struct RunResult {
    /// The true pad pose against the target, every tick.
    pub truth: ErrorStats,
    /// The tracker's measurement against the target, at its samples.
    pub tracker: ErrorStats,
    /// The machine's state at the end of the run (to carry on the session).
    pub end: MachineState,
    /// Per tracker sample: (t, ex, ey, ez) in µm, base frame.
    pub trace: Vec<(f64, f64, f64, f64)>,
    /// Predictions made; 0 without a model.
    pub predictions: usize,
    /// Predictions the controller refused as beyond [`MAX_CORRECTION`].
    pub refused: usize,
    /// Ticks whose corrected target the controller could not reach, run uncorrected
    /// (`twin::Simulation::set_correction`).
    pub unreachable: usize,
    /// Their mean latency, ms; 0 without a model.
    pub predict_ms: f64,
    /// With [`Feedback::OpenLoop`]: how far each prediction was from the tick's true
    /// residual (the oracle's correction), position µm and attitude across the tool axis
    /// mdeg, over the predicting ticks.
    pub open_loop: Option<ErrorStats>,
    /// With [`Feedback::OpenLoop`]: the corrections the model would have set, by tick
    /// (those within [`MAX_CORRECTION`]), for [`Feedback::Replay`].
    pub predicted: Vec<(usize, Correction)>,
    /// With [`Feedback::OpenLoop`]: each prediction's miss and its members' spread.
    pub open_loop_ticks: Vec<OpenLoopTick>,
    /// The true pad error every tick (what `truth` summarises): position µm, attitude
    /// mdeg.
    pub truth_per_tick: [Vec<f64>; 2],
    /// With [`Feedback::Gated`]: the predictions the gate shrank.
    pub shrunk: usize,
}

/// One open-loop prediction: how far it was from the tick's true residual (position µm,
/// attitude across the tool axis mdeg, as [`RunResult::open_loop`] measures the miss) and
/// how far its members were from their mean ([`super::ensemble::spread`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OpenLoopTick {
    /// The control tick the prediction is for (made `look_ahead` ticks before it).
    pub tick: usize,
    /// The miss: position µm, attitude mdeg.
    pub miss: [f64; 2],
    /// The members' root-mean-square distance from their mean (0 for one predictor):
    /// position µm, attitude mdeg (3-D, as a controller computes it without the tool
    /// axis).
    pub spread: [f64; 2],
    /// The prediction's size, the correction's length: position µm, attitude mdeg (3-D).
    pub size: [f64; 2],
}

/// What the loop does with a prediction whose interval is wide ([`Feedback::Gated`],
/// docs/results.md "Confidence"): the interval's radius is `scale` times the members'
/// spread; beyond `limit` the correction is shrunk towards none by limit / radius (the
/// smaller of the position's and the attitude's factors).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gate {
    /// Radius per unit of spread: position, attitude (a calibrated interval's scale).
    pub scale: [f64; 2],
    /// The widest radius applied in full: position µm, attitude mdeg.
    pub limit: [f64; 2],
}

impl Gate {
    /// The share of a prediction with members' `spread` that is applied, in [0, 1].
    pub fn factor(&self, spread: [f64; 2]) -> f64 {
        (0..2)
            .map(|q| {
                let radius = self.scale[q] * spread[q];
                if radius > self.limit[q] {
                    self.limit[q] / radius
                } else {
                    1.0
                }
            })
            .fold(1.0, f64::min)
            .max(0.0)
    }
}

/// Online compensation settings.
#[derive(Clone, Copy, Debug)]
pub struct Online {
    /// Predict every `every` ticks and hold the correction in between (1 = every tick).
    pub every: usize,
}

impl Default for Online {
    fn default() -> Online {
        Online { every: 1 }
    }
}

/// What feeds the correction during a run.
pub enum Feedback<'p> {
    /// No compensation: the controller's model alone.
    None,
    /// A trained model, predicting from the sensor window ending at each tick: one
    /// predictor, or the members of an ensemble (the seeds of one model, reading the same
    /// graph), whose predictions the controller averages.
    Model(&'p mut [Predictor], &'p Graph, Online),
    /// A trained model predicting as [`Feedback::Model`] does, its predictions scored
    /// against the true residual and never applied: the run is the uncompensated one
    /// (the open-loop prediction error on held-out runs of docs/shift/README.md "Where the
    /// error goes").
    OpenLoop(&'p mut [Predictor], &'p Graph, Online),
    /// An ensemble as [`Feedback::Model`], each correction shrunk by the [`Gate`] when its
    /// members disagree more than it allows.
    Gated(&'p mut [Predictor], &'p Graph, Online, Gate),
    /// Corrections recorded by an open-loop run ([`RunResult::predicted`]), each set after
    /// its tick as the model would have set it: the model's predictions fed forward
    /// without their feedback on its own inputs.
    Replay(&'p [(usize, Correction)]),
    /// The floor: the true residual of the tick, fed back with a model's latency and rate
    /// (from the first tick a `window`-step model could predict, every `every` ticks,
    /// applied from the next tick on).
    Oracle {
        /// The window length, ticks, of the model the oracle stands in for.
        window: usize,
        /// How often it predicts.
        settings: Online,
    },
}

/// The largest correction the controller accepts from a model: 1 mm of position, 1° of
/// attitude. A prediction beyond either (or not finite) is refused: the controller keeps
/// its last accepted correction and counts the refusal ([`RunResult::refused`]). The
/// residuals it compensates are about a tenth of a millimetre and a tenth of a degree;
/// the limit keeps a model that extrapolates wildly from commanding a pose the machine
/// cannot reach. It is the same for every model.
pub const MAX_CORRECTION: (f64, f64) = (1.0, 1.0);

/// Whether the controller accepts correction `c` ([`MAX_CORRECTION`]; false for NaN).
pub fn within_limit(c: &Correction) -> bool {
    let (mm, deg) = MAX_CORRECTION;
    c.dp.norm() <= mm && c.dr.norm() <= deg.to_radians()
}

/// Indices into the twin's [`CHANNELS`] of the graph's nodes.
fn node_channels(graph: &Graph) -> Result<Vec<usize>> {
    graph
        .nodes
        .iter()
        .map(|n| {
            CHANNELS.iter().position(|c| c == n).ok_or_else(|| {
                Error::Invalid(format!("graph node {n:?} is not a twin sensor channel"))
            })
        })
        .collect()
}

/// A trained model (one predictor, or an ensemble's members) in a control loop: it
/// reads its graph's channels every tick and predicts every `settings.every` ticks once
/// its window is full. [`run`] scores it; the recorder of closed-loop training data
/// (`experiment::scale`, docs/usage.md "scale", `--closed-loop`) records with it.
pub struct ModelInLoop<'p> {
    ensemble: Ensemble<&'p mut Predictor>,
    nodes: Vec<usize>,
    values: Vec<Option<f64>>,
    settings: Online,
}

impl<'p> ModelInLoop<'p> {
    /// The model `members` (predictions averaged), reading `graph`'s channels, at the
    /// control period `dt`, s; its members start a new run.
    pub fn new(
        members: &'p mut [Predictor],
        graph: &Graph,
        settings: Online,
        dt: f64,
    ) -> Result<ModelInLoop<'p>> {
        ensure(!members.is_empty(), || {
            "a model in the loop needs at least one predictor".to_string()
        })?;
        ensure(settings.every >= 1, || {
            format!(
                "models predict every 1 or more control ticks, got every {}",
                settings.every
            )
        })?;
        let nodes = node_channels(graph)?;
        let mut sensors = Vec::with_capacity(members.len());
        for member in members.iter_mut() {
            member.reset();
            sensors.push(SensorPredictor::new(member, dt)?);
        }
        Ok(ModelInLoop {
            ensemble: Ensemble::new(sensors, None)?,
            values: vec![None; nodes.len()],
            nodes,
            settings,
        })
    }

    /// Ticks after the window's last tick whose residual the model predicts
    /// (its `look_ahead`): a prediction made on tick t is for tick t + this.
    pub fn look_ahead(&self) -> usize {
        self.ensemble.first().config().look_ahead
    }

    /// Forgets the run so far (a new run starts).
    pub fn reset(&mut self) {
        self.ensemble.reset();
    }

    /// Control tick `tick` of the run with the twin's `channels`: the members' mean
    /// prediction as a correction (position mm, rotation vector rad, base frame) on a
    /// predicting tick, `None` otherwise. The caller applies it or not
    /// ([`within_limit`]).
    pub fn tick(&mut self, tick: usize, channels: &[Option<f64>]) -> Result<Option<Correction>> {
        for (v, &c) in self.values.iter_mut().zip(self.nodes.iter()) {
            *v = channels[c];
        }
        let full = self.ensemble.push_values(&self.values)?;
        if !(full && tick.is_multiple_of(self.settings.every)) {
            return Ok(None);
        }
        // Every ring is full, so there is a window to predict.
        let r = self.ensemble.predict_latest()?.unwrap_or_default();
        Ok(Some(Correction {
            dp: nalgebra::Vector3::new(r[0], r[1], r[2]) * 1e-3,
            dr: nalgebra::Vector3::new(r[3], r[4], r[5]).map(|v| (v * 1e-3).to_radians()),
        }))
    }

    /// How far the members' last predictions were from their mean
    /// ([`super::ensemble::spread`]: position µm, attitude mdeg); zeros before one.
    pub fn spread(&self) -> [f64; 2] {
        self.ensemble.spread().unwrap_or_default()
    }
}

/// Runs one polishing path on `machine` from `start` (its state from earlier runs of the
/// session), driven by `controller` and corrected by `feedback`; `on_tick` sees the
/// progress (ticks done).
pub fn run(
    machine: &Machine,
    controller: &Robot,
    config: SimConfig,
    start: MachineState,
    feedback: Feedback<'_>,
    mut on_tick: impl FnMut(usize),
) -> Result<RunResult> {
    let mut ticks = 0;
    run_observed(machine, controller, config, start, feedback, |_, _| {
        ticks += 1;
        on_tick(ticks)
    })
}

/// [`run`], with `on_sample` shown every tick's sample and the true pad pose in the frame
/// the part was located in ([`located`]): what the polishing stage removes glass with
/// (docs/polishing.md).
pub fn run_observed(
    machine: &Machine,
    controller: &Robot,
    config: SimConfig,
    start: MachineState,
    feedback: Feedback<'_>,
    mut on_sample: impl FnMut(&Sample, &Isometry3<f64>),
) -> Result<RunResult> {
    let every = match &feedback {
        Feedback::Model(_, _, settings)
        | Feedback::OpenLoop(_, _, settings)
        | Feedback::Gated(_, _, settings, _)
        | Feedback::Oracle { settings, .. } => settings.every,
        Feedback::None | Feedback::Replay(_) => 1,
    };
    ensure(every >= 1, || {
        format!("models predict every 1 or more control ticks, got every {every}")
    })?;
    let dt = config.dt;
    let registration = controller.tracker_from_base().inverse();
    let mut sim = Simulation::resume(machine, controller, Mirror::default(), config, start)?;
    let mut model = None;
    let mut oracle = None;
    let apply = !matches!(feedback, Feedback::OpenLoop(..));
    let mut replay: &[(usize, Correction)] = &[];
    let mut gate = None;
    let mut shrunk = 0usize;
    match feedback {
        Feedback::None => {}
        Feedback::Replay(corrections) => replay = corrections,
        Feedback::Model(members, graph, settings)
        | Feedback::OpenLoop(members, graph, settings) => {
            model = Some(ModelInLoop::new(members, graph, settings, dt)?);
        }
        Feedback::Gated(members, graph, settings, g) => {
            model = Some(ModelInLoop::new(members, graph, settings, dt)?);
            gate = Some(g);
        }
        Feedback::Oracle { window, settings } => oracle = Some((window, settings)),
    }
    let (mut miss_pos, mut miss_att) = (Vec::new(), Vec::new());
    // Open-loop predictions waiting for the tick they are for (a look-ahead model's are
    // for a later tick than the one they are made on), with their spread.
    let ahead = model.as_ref().map_or(0, ModelInLoop::look_ahead);
    let mut pending: VecDeque<(usize, Correction, [f64; 2])> = VecDeque::new();
    let mut predicted = Vec::new();
    let mut open_loop_ticks = Vec::new();
    let (mut pos, mut att, mut trace) = (Vec::new(), Vec::new(), Vec::new());
    let (mut true_pos, mut true_att) = (Vec::new(), Vec::new());
    let (mut predictions, mut predict_time, mut refused) = (0usize, 0f64, 0usize);
    let mut tick = 0usize;
    while let Some(sample) = sim.step() {
        let s = sample.map_err(|e| {
            Error::from(e).context(format!("twin at t = {:.2} s", tick as f64 * dt))
        })?;
        let actual = located(machine, controller, &s.hidden.actual.pose);
        let (p, a) = pose_error(&s.hidden.target, &actual);
        true_pos.push(p);
        true_att.push(a);
        if let Some(m) = &s.tracker {
            let base = registration * m;
            let (p, a) = pose_error(&s.hidden.target, &base);
            let e = (base.translation.vector - s.hidden.target.position) * 1e3;
            pos.push(p);
            att.push(a);
            trace.push((s.t, e.x, e.y, e.z));
        }
        if let Some(model) = model.as_mut() {
            let began = Instant::now();
            if let Some(mut c) = model.tick(tick, &s.channels)? {
                if let Some(g) = &gate {
                    let f = g.factor(model.spread());
                    if f < 1.0 {
                        shrunk += 1;
                        c.dp *= f;
                        c.dr *= f;
                    }
                }
                predict_time += began.elapsed().as_secs_f64();
                predictions += 1;
                let within = within_limit(&c);
                if !apply {
                    let spread = model.spread();
                    pending.push_back((tick + ahead, c, spread));
                    if within {
                        predicted.push((tick, c));
                    }
                } else if within {
                    sim.set_correction(c);
                } else {
                    // Also refuses NaN, which fails both comparisons.
                    refused += 1;
                }
            }
        }
        // Each open-loop prediction is scored against the true residual of its tick.
        while let Some(&(_, c, spread)) = pending.front().filter(|p| p.0 == tick) {
            pending.pop_front();
            let (p, a) = prediction_miss(&s, &actual, c.dp, c.dr);
            miss_pos.push(p);
            miss_att.push(a);
            open_loop_ticks.push(OpenLoopTick {
                tick,
                miss: [p, a],
                spread,
                size: [c.dp.norm() * 1e3, c.dr.norm().to_degrees() * 1e3],
            });
        }
        if let Some(((k, c), rest)) = replay.split_first() {
            if *k == tick {
                sim.set_correction(*c);
                predictions += 1;
                replay = rest;
            }
        }
        if let Some((window, settings)) = oracle {
            if tick + 1 >= window && tick.is_multiple_of(settings.every) {
                predictions += 1;
                sim.set_correction(true_residual(&s, &actual));
            }
        }
        tick += 1;
        on_sample(&s, &actual);
    }
    let summary = |v: &[f64]| {
        Summary::of(v)
            .ok_or_else(|| Error::Invalid("the tracker measured nothing in this run".into()))
    };
    Ok(RunResult {
        truth: ErrorStats {
            position: summary(&true_pos)?,
            attitude: summary(&true_att)?,
        },
        shrunk,
        tracker: ErrorStats {
            position: summary(&pos)?,
            attitude: summary(&att)?,
        },
        end: sim.machine_state(),
        unreachable: sim.unreachable_corrections(),
        trace,
        predictions,
        refused,
        predict_ms: if model.is_some() && predictions > 0 {
            1e3 * predict_time / predictions as f64
        } else {
            0.0
        },
        predicted,
        open_loop_ticks,
        truth_per_tick: [true_pos, true_att],
        open_loop: if apply {
            None
        } else {
            let short = || Error::Invalid("the run was too short for a single prediction".into());
            Some(ErrorStats {
                position: Summary::of(&miss_pos).ok_or_else(short)?,
                attitude: Summary::of(&miss_att).ok_or_else(short)?,
            })
        },
    })
}

/// [`run`] with `feedback`, and the true residual of each of its ticks: the located
/// actual pose against the pose the controller expected, what the oracle feeds back.
pub fn with_true_residuals(
    machine: &Machine,
    controller: &Robot,
    config: SimConfig,
    start: MachineState,
    feedback: Feedback<'_>,
) -> Result<(RunResult, Vec<Correction>)> {
    let mut residuals = Vec::with_capacity(config.steps());
    let result = run_observed(machine, controller, config, start, feedback, |s, actual| {
        residuals.push(true_residual(s, actual))
    })?;
    Ok((result, residuals))
}

/// The true residual of a tick: the located actual pose against the commanded one.
fn true_residual(s: &crate::twin::Sample, actual: &Isometry3<f64>) -> Correction {
    let commanded = &s.hidden.commanded;
    Correction {
        dp: actual.translation.vector - commanded.translation.vector,
        dr: (actual.rotation * commanded.rotation.inverse()).scaled_axis(),
    }
}

/// The look-ahead oracle's corrections for [`Feedback::Replay`]: on each tick the oracle
/// would act (from the first a `window`-step model could predict, every `every` ticks),
/// the true residual of the tick `ahead` ticks on (1: the **next** tick, the one the
/// correction takes effect on), from
/// a run's `residuals` ([`with_true_residuals`]). The oracle of [`Feedback::Oracle`]
/// sets the residual of the tick just measured instead; the difference is the floor a
/// model that predicts ahead could reach (docs/results.md "The look-ahead floor").
/// Corrections change the residuals they correct (the pad sits elsewhere on the glass),
/// so [`look_ahead_oracle`] iterates.
pub fn look_ahead(
    residuals: &[Correction],
    window: usize,
    every: usize,
    ahead: usize,
) -> Vec<(usize, Correction)> {
    (0..residuals.len().saturating_sub(ahead))
        .filter(|&t| t + 1 >= window && t.is_multiple_of(every.max(1)))
        .map(|t| (t, residuals[t + ahead]))
        .collect()
}

/// Passes of the look-ahead oracle's fixed point where Table V and the floor run it
/// ([`look_ahead_oracle`]; the fourth moves the mean error by hundredths of a µm,
/// docs/results.md "The look-ahead floor").
pub const LOOK_AHEAD_PASSES: usize = 4;

/// The oracle standing in for a `window`-step model that predicts every
/// `settings.every` ticks and `ahead` ticks ahead: [`Feedback::Oracle`] for a model of
/// the tick just measured (`ahead` 0), the look-ahead oracle ([`look_ahead_oracle`],
/// [`LOOK_AHEAD_PASSES`]) for one that predicts the tick its correction acts on.
#[allow(clippy::too_many_arguments)]
pub fn oracle(
    machine: &Machine,
    controller: &Robot,
    config: &SimConfig,
    start: &MachineState,
    window: usize,
    settings: Online,
    ahead: usize,
) -> Result<RunResult> {
    if ahead == 0 {
        let feedback = Feedback::Oracle { window, settings };
        return run(
            machine,
            controller,
            config.clone(),
            start.clone(),
            feedback,
            |_| {},
        );
    }
    let (r, _) = look_ahead_oracle(
        machine,
        controller,
        config,
        start,
        window,
        settings.every,
        ahead,
        LOOK_AHEAD_PASSES,
    )?;
    Ok(r)
}

/// The look-ahead oracle on one run, as a fixed point: the uncompensated run's residuals
/// give the first corrections ([`look_ahead`]), the run they correct gives the next ones,
/// `passes` times in all (at least 1). Returns the last run and, per pass, its true
/// position error, µm (how far the iteration moved).
#[allow(clippy::too_many_arguments)]
pub fn look_ahead_oracle(
    machine: &Machine,
    controller: &Robot,
    config: &SimConfig,
    start: &MachineState,
    window: usize,
    every: usize,
    ahead: usize,
    passes: usize,
) -> Result<(RunResult, Vec<f64>)> {
    let (_, mut residuals) = with_true_residuals(
        machine,
        controller,
        config.clone(),
        start.clone(),
        Feedback::None,
    )?;
    let mut history = Vec::new();
    let mut last = None;
    for _ in 0..passes.max(1) {
        let corrections = look_ahead(&residuals, window, every, ahead);
        let (r, next) = with_true_residuals(
            machine,
            controller,
            config.clone(),
            start.clone(),
            Feedback::Replay(&corrections),
        )?;
        history.push(r.truth.position.mean);
        residuals = next;
        last = Some(r);
    }
    let last = last.ok_or_else(|| Error::Invalid("no pass of the look-ahead oracle".into()))?;
    Ok((last, history))
}

/// How far a prediction (dp mm, dr rotation vector rad) is from the true residual of its
/// tick (the located actual pose against the pose the controller expected, what the
/// oracle feeds back): position µm, and the attitude difference across the tool axis
/// mdeg (the roll about the axis is free, as in Table III and V).
fn prediction_miss(
    s: &crate::twin::Sample,
    actual: &nalgebra::Isometry3<f64>,
    dp: nalgebra::Vector3<f64>,
    dr: nalgebra::Vector3<f64>,
) -> (f64, f64) {
    let truth = true_residual(s, actual);
    let axis = s.hidden.target.axis.normalize();
    let e = dr - truth.dr;
    let across = e - axis * e.dot(&axis);
    (
        (dp - truth.dp).norm() * 1e3,
        across.norm().to_degrees() * 1e3,
    )
}

/// A trace for the report.
pub fn trace(trajectory: PathKind, label: &str, r: &RunResult) -> Trace {
    Trace {
        trajectory: trajectory.name().to_string(),
        label: label.to_string(),
        points: r.trace.clone(),
    }
}

/// Mean / SD / max of the position (µm) and attitude (mdeg) pose errors of one run.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ErrorStats {
    /// Pad position error, µm.
    pub position: Summary,
    /// Tool-axis angle error, mdeg.
    pub attitude: Summary,
}

/// Per-tracker-sample pose error of one compensation run (for Fig. 11).
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    /// The held-out path.
    pub trajectory: String,
    /// e.g. `calibrated`, `compensated (iastgcn)`.
    pub label: String,
    /// (t s, ex µm, ey µm, ez µm): measured minus target position, base frame.
    pub points: Vec<(f64, f64, f64, f64)>,
}
