//! The held-out sessions in the twin: which ones and how long ([`HeldOutConfig`]), and
//! one session's runs, each compensated online by every model, with the open-loop
//! diagnosis ([`held_out_session`]).

use super::models::LoopModel;
use crate::calibrate::file;
use crate::compensate::budget::{error_budget, markdown as budget_markdown};
use crate::compensate::held_out::{warm_up_on, HeldOut, IDLE_BETWEEN_RUNS};
use crate::compensate::online::RunResult;
use crate::compensate::online::{self, ErrorStats, Feedback, Online};
use crate::data::DataSources;
use crate::error::{ensure, Error, Result};
use crate::experiment::parallel;
use crate::experiment::report::{table_v_lines, TableVRow, Trace};
use crate::gpu::Device;
use crate::progress::Reporter;
use crate::robot::Robot;
use crate::twin::MachineState;
use crate::twin::{draw_machine, Conditions, Machine, PathKind, PathParams};

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
        if !(1..=MAX_HELD_OUT_SESSIONS).contains(&self.sessions) {
            return Err(Error::Setting {
                setting: "held_out.sessions",
                message: format!(
                    "1 to {MAX_HELD_OUT_SESSIONS} held-out sessions, got {}",
                    self.sessions
                ),
            });
        }
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

    /// The state held-out session `k` starts from: `machine` cold on its day, warmed
    /// up under `controller` as the session says ([`warm_up_on`]).
    pub fn warm_up(&self, k: usize, machine: &Machine, controller: &Robot) -> Result<MachineState> {
        let plan = self.session(k);
        warm_up_on(
            machine,
            controller,
            plan.warm_up_minutes * 60.0,
            plan.seed.wrapping_add(1000),
            &plan.conditions,
        )
    }

    /// The `i`-th path of [`PathKind::ALL`] in held-out session `k`, from `start`: at its
    /// placement for the session, with the session's seed for it and its day.
    pub fn run(&self, k: usize, i: usize, start: MachineState) -> HeldOut {
        let plan = self.session(k);
        let path = PathKind::ALL[i % PathKind::ALL.len()];
        HeldOut {
            path,
            params: PathParams::held_out_in(path, k),
            seconds: self.minutes * 60.0,
            seed: plan.seed + i as u64,
            start,
            conditions: plan.conditions,
        }
    }
}

impl Default for HeldOutConfig {
    /// The demo's sessions: three, of 0.5 min runs from seed 301, the first after 2 min
    /// of warm-up, a prediction at the default recipe's rate (every tick,
    /// [`recipe::DEFAULT`](crate::experiment::recipe::DEFAULT)).
    fn default() -> HeldOutConfig {
        HeldOutConfig {
            minutes: 0.5,
            seed: 301,
            warm_up_minutes: 2.0,
            every: crate::experiment::recipe::DEFAULT.every,
            sessions: 3,
        }
    }
}

/// What one held-out session gave ([`held_out_session`]).
pub struct Session {
    /// The session's index ([`HeldOutConfig::session`]).
    pub index: usize,
    /// The machine's state at the start of each path's runs, in the order of
    /// [`PathKind::ALL`] (for more models on the same runs: [`more_models`]).
    pub starts: Vec<MachineState>,
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

impl Session {
    /// One session of every model from `parts` (the same session's runs: the first from
    /// [`held_out_session`], the others from [`more_models`] after it), as if all the
    /// models had run together: each path's rows, traces and refusals in turn, the
    /// stages and then the models in the parts' order; the first part's budget, machine
    /// and warning.
    pub fn merge(parts: Vec<Session>) -> Result<Session> {
        let mut parts = parts.into_iter();
        let Some(mut first) = parts.next() else {
            return Err(Error::Invalid("no session to merge".into()));
        };
        let rest: Vec<Session> = parts.collect();
        if let Some(other) = rest.iter().find(|s| s.index != first.index) {
            return Err(Error::Invalid(format!(
                "held-out sessions {} and {} cannot be merged: they are different sessions",
                first.index + 1,
                other.index + 1
            )));
        }
        let paths: Vec<&str> = PathKind::ALL.iter().map(|p| p.name()).collect();
        let mut rows = Vec::new();
        let mut traces = Vec::new();
        let mut refusals = Vec::new();
        let mut open_loop = Vec::new();
        for path in &paths {
            let on = |trajectory: &str| trajectory == *path;
            for part in std::iter::once(&first).chain(&rest) {
                rows.extend(part.rows.iter().filter(|r| on(&r.trajectory)).cloned());
                traces.extend(part.traces.iter().filter(|t| on(&t.trajectory)).cloned());
                refusals.extend(
                    part.refusals
                        .iter()
                        .filter(|l| l.split(": ").next() == Some(*path))
                        .cloned(),
                );
                open_loop.extend(part.open_loop.iter().filter(|o| on(&o.path)).cloned());
            }
        }
        first.rows = rows;
        first.traces = traces;
        first.refusals = refusals;
        first.open_loop = open_loop;
        for part in rest {
            first.latency_ms.extend(part.latency_ms);
            first.ran_on.extend(part.ran_on);
        }
        Ok(first)
    }
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
    session_runs(
        device,
        models,
        sources,
        held,
        options,
        Start::WarmUp,
        reporter,
    )
}

/// [`held_out_session`] from `start` instead of the state after the session's warm-up:
/// the state after something done first (the morning minute,
/// [`crate::experiment::morning`], recorded from [`session_start`]).
pub fn held_out_session_from(
    device: &Device,
    models: &mut [LoopModel],
    sources: &DataSources,
    held: &HeldOutConfig,
    options: SessionOptions,
    start: MachineState,
    reporter: &mut dyn Reporter,
) -> Result<Session> {
    session_runs(
        device,
        models,
        sources,
        held,
        options,
        Start::Given(Box::new(start)),
        reporter,
    )
}

/// The twin machine of the recordings of `sources`, its controller under their
/// calibration, and the state held-out session `k` of `held` starts from (after its
/// warm-up), as [`held_out_session`] runs it.
pub fn session_start(
    sources: &DataSources,
    held: &HeldOutConfig,
    k: usize,
) -> Result<(Machine, Robot, MachineState)> {
    held.validate()?;
    let geometry = sources.geometry()?;
    let cal = file::load(&sources.calibration)?;
    let machine = draw_machine(geometry.clone(), sources.machine_seed()?);
    let calibrated = cal.robot(geometry);
    let start = held.warm_up(k, &machine, &calibrated)?;
    Ok((machine, calibrated, start))
}

/// Where a session's first run starts.
enum Start<'s> {
    /// After the session's warm-up.
    WarmUp,
    /// From this state.
    Given(Box<MachineState>),
    /// From the states another session's runs started from ([`more_models`]).
    After(&'s Session),
}

/// More models on the runs of `after` (a session [`held_out_session`] ran, Table V's rows
/// only): each path's runs start from the state `after`'s did, so its rows are the ones
/// these models would have had beside `after`'s; the initial, calibrated and oracle
/// stages, which do not depend on the models, are not run again. [`Session::merge`]
/// puts the two together as one session of all the models.
pub fn more_models(
    device: &Device,
    models: &mut [LoopModel],
    sources: &DataSources,
    held: &HeldOutConfig,
    after: &Session,
    reporter: &mut dyn Reporter,
) -> Result<Session> {
    let options = SessionOptions::rows(after.index);
    session_runs(
        device,
        models,
        sources,
        held,
        options,
        Start::After(after),
        reporter,
    )
}

/// [`held_out_session`] from `start`, or [`more_models`] with [`Start::After`].
fn session_runs(
    device: &Device,
    models: &mut [LoopModel],
    sources: &DataSources,
    held: &HeldOutConfig,
    options: SessionOptions,
    start: Start<'_>,
    reporter: &mut dyn Reporter,
) -> Result<Session> {
    let k = options.index;
    let after = match start {
        Start::After(after) => Some(after),
        _ => None,
    };
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
    // Where each model predicted, and beside how many other runs its times were taken.
    let sharing = runs_at_a_time(models);
    let ran_on: Vec<String> = models
        .iter()
        .map(|m| match sharing {
            1 => m.runs_on(device),
            n => format!("{} ({n} runs at a time)", m.runs_on(device)),
        })
        .collect();
    let mut latency = vec![(0.0, 0usize); models.len()];
    let mut session = Session {
        index: k,
        starts: Vec::new(),
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
    if let Some(m) = cal
        .machine_seed
        .filter(|&m| m != machine_seed && after.is_none())
    {
        let warning = format!(
            "warning: the calibration {} was measured on twin machine {m}, but the recordings \
             and this held-out session are on machine {machine_seed}: the calibrated rows \
             compensate another machine's geometric errors",
            sources.calibration.display()
        );
        reporter.note(&warning);
        session.calibration_warning = Some(warning);
    }
    let mut state = match start {
        Start::After(_) => None,
        Start::Given(ref state) => Some((**state).clone()),
        Start::WarmUp => Some(held.warm_up(k, &machine, &calibrated)?),
    };
    for (i, path) in PathKind::ALL.into_iter().enumerate() {
        // The warm-up's chain of states, or the one `after`'s runs started from.
        let start = match &state {
            Some(state) => state.clone(),
            None => after
                .and_then(|after| after.starts.get(i))
                .cloned()
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "held-out session {} has no start for {}",
                        k + 1,
                        path.name()
                    ))
                })?,
        };
        session.starts.push(start.clone());
        let run = held.run(k, i, start);
        // One budget (the Hilbert run's) keeps the demo in its time; `iastgcn budget`
        // gives any other.
        if options.budget && path == PathKind::Hilbert {
            let b = error_budget(&machine, &calibrated, &run.config(), &run.start)?;
            session.budget = Some(budget_markdown(&b));
        }
        let stages = if after.is_some() { 0 } else { 3 }
            + models.len() * if options.open_loop { 3 } else { 1 };
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
            after.is_none(),
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
        if let Some(mut end) = result.end {
            end.idle(IDLE_BETWEEN_RUNS);
            state = Some(end);
        }
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
pub(super) fn open_loop_score(
    machine: &Machine,
    calibrated: &Robot,
    run: &HeldOut,
    model: &mut LoopModel,
    settings: Online,
    mut on_tick: impl FnMut(usize),
) -> Result<Option<OpenLoopScore>> {
    let open = run.run(
        machine,
        calibrated,
        Feedback::OpenLoop(&mut model.members, &model.graph, settings),
        &mut on_tick,
    )?;
    let replayed = run.run(
        machine,
        calibrated,
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
    /// The machine's state after the calibrated run (none where the stages were not
    /// run: [`more_models`]).
    pub end: Option<MachineState>,
}

/// How many of a held-out path's runs ([`table_v`]) run at a time: one per core when every
/// model predicts on the native CPU path, else one (the device's queue stays with one
/// thread). The models' online prediction times are measured so, beside the other runs.
pub fn runs_at_a_time(models: &[LoopModel]) -> usize {
    let all_native = models.iter().all(LoopModel::predicts_natively);
    parallel::workers(all_native).min(3 + models.len())
}

/// The oracle row's name in Table V: the true residual, of the tick the correction acts
/// on for a model that looks `ahead`.
pub fn oracle_name(ahead: usize) -> String {
    match ahead {
        0 => "true residual".into(),
        n => format!("true residual, {n} tick(s) ahead"),
    }
}

/// Table V rows and Fig. 11 traces of one held-out run, every stage starting from the
/// same machine state: with `stages`, the nominal controller (initial), the calibrated one
/// (calibrated) and the calibrated one fed the true residual with a `window`-step model's
/// latency and rate (oracle); then the calibrated one compensating online with each model
/// (without `stages` only these, and no `end`: [`more_models`]). The runs go
/// [`runs_at_a_time`] at a time; the rows come in this order whichever ran first, and
/// `on_tick` is called once per tick of every run, on the calling thread.
#[allow(clippy::too_many_arguments)]
pub fn table_v(
    machine: &Machine,
    nominal: &Robot,
    calibrated: &Robot,
    window: usize,
    models: &mut [LoopModel],
    run: &HeldOut,
    settings: Online,
    stages: bool,
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
    // Every run starts from the same state and none reads another's: they run on every
    // core when every model predicts on the native CPU path.
    enum Job<'m> {
        Initial,
        Calibrated,
        Oracle,
        Model(&'m mut LoopModel),
    }
    let names: Vec<String> = models.iter().map(|m| m.name.clone()).collect();
    // The oracle stands in for the first model: its look-ahead too.
    let ahead = models.first().map_or(0, LoopModel::look_ahead);
    let workers = runs_at_a_time(models);
    let mut jobs = if stages {
        vec![Job::Initial, Job::Calibrated, Job::Oracle]
    } else {
        Vec::new()
    };
    jobs.extend(models.iter_mut().map(Job::Model));
    let results = parallel::run_all(
        jobs,
        workers,
        |job, tick| {
            let (controller, feedback) = match job {
                Job::Initial => (nominal, Feedback::None),
                Job::Calibrated => (calibrated, Feedback::None),
                Job::Oracle if ahead > 0 => {
                    // Several runs to a fixed point: its ticks counted when it is done.
                    let config = run.config();
                    let r = online::oracle(
                        machine, calibrated, &config, &run.start, window, settings, ahead,
                    )?;
                    (0..config.steps()).for_each(|_| tick());
                    return Ok(r);
                }
                Job::Oracle => (calibrated, Feedback::Oracle { window, settings }),
                Job::Model(LoopModel { members, graph, .. }) => {
                    (calibrated, Feedback::Model(members, graph, settings))
                }
            };
            run.run(machine, controller, feedback, |_| tick())
        },
        || on_tick(0),
    )?;
    let mut results = results.into_iter();
    // invariant: one result per job, the three controllers (with `stages`) and then the
    // models.
    let mut next = || results.next().expect("one result per job");
    let mut rows = Vec::new();
    let mut traces = Vec::new();
    let mut end = None;
    if stages {
        let (initial, plain, oracle) = (next(), next(), next());
        rows.extend([
            row("initial", "-", &initial),
            row("calibrated", "-", &plain),
            row("oracle", &oracle_name(ahead), &oracle),
        ]);
        traces.push(online::trace(run.path, "calibrated", &plain));
        end = Some(plain.end);
    }
    let mut latency = Vec::new();
    let mut refused = Vec::new();
    for model in names {
        let r = next();
        rows.push(row("compensated", &model, &r));
        traces.push(online::trace(
            run.path,
            &format!("compensated ({model})"),
            &r,
        ));
        latency.push((model.clone(), r.predict_ms));
        refused.push((model, r.refused, r.predictions, r.unreachable));
    }
    Ok(HeldOutResult {
        rows,
        traces,
        latency,
        refused,
        end,
    })
}
