//! What the demo, `iastgcn reproduce` and `iastgcn scale` share: the twin data of the
//! protocol (the calibration set on a cold machine, the EKF calibration, the training
//! sessions under the calibrated controller), a round of closed-loop training data (a
//! round-0 model compensating the second half of the sessions as they are recorded
//! again), and the fitting of one model (core stage, then refinement, both written to
//! files as they go).

use std::path::{Path, PathBuf};

use super::evaluate::NamedModel;
use crate::calibrate::{self, file, hold_out, pose_errors, EkfConfig};
use crate::compensate::held_out::IDLE_BETWEEN_RUNS;
use crate::compensate::online::{within_limit, ModelInLoop, Online};
use crate::data::{
    read_measurements, record_calibration_set, record_corrected_run, Corrector, DataSources,
    Dataset, RecordedRun,
};
use crate::error::{Error, Result};
use crate::experiment::parallel;
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Checkpoint, Predictor};
use crate::progress::{Notes, Reporter};
use crate::robot::{Geometry, Robot};
use crate::train::refine::AccumulatedCurve;
use crate::train::{self, refine, sibling, EpochRecord, RunConfig, TestMetrics, Trained};
use crate::twin::{
    draw_machine, Correction, Machine, PathKind, PlannedSession, Recipe, RunInfo, SimConfig,
};

/// Seeds of the protocol's runs: every run has its own (written in its `.run.toml`). This
/// one is the calibration set's.
pub const CALIBRATION_SEED: u64 = 101;
/// Seed of the first training recording; the later ones count up from it.
pub const TRAINING_SEED: u64 = 201;
/// The twin's default machine (the seed of its geometric and non-geometric errors).
pub const MACHINE_SEED: u64 = 1;
/// Measurement poses of the calibration set.
const CALIBRATION_POSES: usize = 80;

/// The files of the protocol's data in the folder `dir` recorded with `recipe`: the
/// calibration set, the calibration, and the training recordings (grid, fermat, hilbert
/// of each session in turn).
pub fn data_sources(dir: &Path, recipe: &Recipe) -> DataSources {
    DataSources {
        recordings: (1..=recipe.sessions)
            .flat_map(|s| {
                PathKind::TRAINING
                    .into_iter()
                    .map(move |k| dir.join(recipe.file_name(k, s)))
            })
            .collect(),
        calibration: dir.join("calibration.toml"),
        graph: None,
        robot: None,
    }
}

/// The protocol's data of an earlier run in `dir`, when every file of `recipe` is there;
/// an error when they are there but were recorded with another length than `minutes`
/// per path or on another machine than `machine_seed` (the models trained on them would
/// not belong to this run).
pub fn existing_data(
    dir: &Path,
    minutes: f64,
    machine_seed: u64,
    recipe: &Recipe,
) -> Result<Option<DataSources>> {
    let sources = data_sources(dir, recipe);
    let complete = dir.join("calibration_set.csv").exists()
        && sources.calibration.exists()
        && sources
            .recordings
            .iter()
            .all(|r| r.exists() && RunInfo::sidecar(r).exists());
    if !complete {
        return Ok(None);
    }
    let per_run = minutes / recipe.sessions as f64;
    for r in &sources.recordings {
        let info = RunInfo::read(r).map_err(Error::Invalid)?;
        if (info.seconds - per_run * 60.0).abs() > 1e-6 {
            return Err(Error::Invalid(format!(
                "{}: recorded for {} min, but this run asks for {per_run} min per recording \
                 ({minutes} min per path in {} sessions); use another output folder or the \
                 same protocol.minutes and recipe.sessions",
                r.display(),
                info.seconds / 60.0,
                recipe.sessions
            )));
        }
        if info.machine_seed != machine_seed {
            return Err(Error::Invalid(format!(
                "{}: recorded on twin machine {}, but this run asks for machine {machine_seed}; \
                 use another output folder or the same protocol.machine_seed",
                r.display(),
                info.machine_seed
            )));
        }
    }
    Ok(Some(sources))
}

/// The error of a number of training sessions that cannot be used: the setting
/// `recipe.sessions` and `message`, what it may be.
pub(super) fn sessions_setting(message: String) -> Error {
    Error::Setting {
        setting: "recipe.sessions",
        message,
    }
}

/// Closed-loop data record the second half of the sessions with a model trained on the
/// first: refuses fewer than two sessions, naming the setting. `alternative` is said after
/// the range when there is one (the demo's open-loop data).
pub(super) fn check_closed_loop_sessions(sessions: usize, alternative: &str) -> Result<()> {
    if sessions < 2 {
        return Err(sessions_setting(format!(
            "closed-loop data record the second half of the sessions with a model trained \
             on the first: 2 sessions or more{alternative}, got {sessions}"
        )));
    }
    Ok(())
}

/// Records the protocol's data into `dir` (created if missing): the calibration set of a
/// cold machine at rest, the EKF calibration (scored on held-out poses), then the
/// training sessions of `recipe` with `minutes` per path in all under the calibrated
/// controller, each starting cold on its day with the machine left idle between runs,
/// all on twin machine `machine_seed`. Returns where the files are.
pub fn record_data(
    dir: &Path,
    minutes: f64,
    machine_seed: u64,
    recipe: &Recipe,
    reporter: &mut dyn Reporter,
) -> Result<DataSources> {
    recipe.validate(minutes).map_err(sessions_setting)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    reporter.note(&format!(
        "== twin machine {machine_seed}: calibration measurements (a cold machine at rest)"
    ));
    let geometry = Geometry::default_asset();
    let machine = draw_machine(geometry.clone(), machine_seed);
    let nominal = Robot::nominal(geometry.clone());
    let set = dir.join("calibration_set.csv");
    let mut info = RunInfo::calibration(CALIBRATION_SEED);
    info.machine_seed = machine_seed;
    let poses =
        record_calibration_set(&machine, &nominal, CALIBRATION_POSES, &info, &set, reporter)?;
    reporter.note(&format!(
        "wrote {} ({poses} measurement poses)",
        set.display()
    ));

    reporter.note("== geometric calibration (EKF)");
    let sources = data_sources(dir, recipe);
    let calibration = &sources.calibration;
    let (fit, held) = hold_out(&read_measurements(&set)?, 5);
    let cal = calibrate::calibrate(&nominal, &fit, &EkfConfig::default())
        .map_err(|e| Error::from(e).context(format!("calibrating from {}", set.display())))?;
    file::save_from(calibration, &cal, fit.len(), Some(machine_seed))?;
    let controller = nominal.with_errors(cal.errors.clone());
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let (before, after) = (
        pose_errors(&nominal, &held)?,
        pose_errors(&controller, &held)?,
    );
    reporter.note(&format!(
        "identified {} parameters from {} poses; wrote {}; on {} held-out poses the mean error \
         falls from {:.1} µm / {:.1} mdeg to {:.1} µm / {:.1} mdeg",
        cal.identified.len(),
        fit.len(),
        calibration.display(),
        held.len(),
        mean(&before.0),
        mean(&before.1),
        mean(&after.0),
        mean(&after.1)
    ));

    // Each session is a day of its own from a cold start: they are recorded one per core,
    // their notes given in order once all are written.
    let plan = recipe.plan(minutes, TRAINING_SEED, machine_seed);
    let controller_name = calibration.display().to_string();
    let sessions: Vec<(usize, PlannedSession)> = plan.into_iter().enumerate().collect();
    sessions_at_once(sessions, true, reporter, |(s, session), notes| {
        let c = session.conditions;
        notes.note(&format!(
            "== training session {} of {}: three recordings under the calibrated controller, \
             starting cold (ambient {:+.2} K from the calibration day's, feed {:.1} mm/s, \
             force {:.1} N)",
            s + 1,
            recipe.sessions,
            c.day.ambient_offset_k,
            c.feed_mm_s,
            c.force_n
        ));
        let to = |kind| dir.join(recipe.file_name(kind, s + 1));
        let target = (&controller, controller_name.as_str());
        record_session(&machine, target, session, &to, None, notes)
    })?;
    Ok(sources)
}

/// Records `sessions` with `record` (which notes what it did into the [`Notes`] it is
/// given), one per core where `native` (nothing of theirs on a GPU's queue), else one
/// after another; shows one bar over the sessions on `reporter`, then their notes in the
/// sessions' order. Returns each session's runs, in order.
fn sessions_at_once<J: Send>(
    sessions: Vec<J>,
    native: bool,
    reporter: &mut dyn Reporter,
    record: impl Fn(J, &mut Notes) -> Result<Vec<RecordedRun>> + Sync,
) -> Result<Vec<Vec<RecordedRun>>> {
    let count = sessions.len();
    let workers = parallel::workers(native).min(count);
    reporter.begin(
        &format!("recording {count} session(s), {workers} at a time"),
        count as u64,
    );
    let mut done = 0;
    let recorded = parallel::run_all(
        sessions,
        workers,
        |session, tick| {
            let mut notes = Notes::default();
            let runs = record(session, &mut notes);
            tick();
            runs.map(|r| (r, notes.0))
        },
        || {
            done += 1;
            reporter.update(done, "");
        },
    );
    reporter.end();
    let mut runs = Vec::with_capacity(count);
    for (r, notes) in recorded? {
        for line in notes {
            reporter.note(&line);
        }
        runs.push(r);
    }
    Ok(runs)
}

/// Records one training session (`session`, from [`Recipe::plan`]) on `machine` under
/// `controller` (the model and its name for the sidecars), cold on its day with the
/// machine idle between runs, each run into `to(path)`; with `correct`, a model corrects
/// the commands as the runs go ([`record_corrected_run`]). Returns the runs.
pub fn record_session(
    machine: &Machine,
    (controller, name): (&Robot, &str),
    session: PlannedSession,
    to: &dyn Fn(PathKind) -> PathBuf,
    mut correct: Option<Corrector<'_>>,
    reporter: &mut dyn Reporter,
) -> Result<Vec<RecordedRun>> {
    let mut state = machine.cold_on(session.conditions.day);
    let mut runs = Vec::new();
    for mut info in session.runs {
        let kind: PathKind = info.path.parse().map_err(Error::Invalid)?;
        let path = &to(kind);
        info.controller = name.to_string();
        let correct = correct.as_mut().map(|c| &mut **c as Corrector<'_>);
        let run = record_corrected_run(
            machine, controller, info, state, path, None, correct, reporter,
        )?;
        reporter.note(&format!(
            "wrote {} ({} rows, {} tracker samples, seed {}, {} start)",
            path.display(),
            run.rows,
            run.tracker_samples,
            run.info.seed,
            run.info.start
        ));
        state = run.end.clone();
        state.idle(IDLE_BETWEEN_RUNS);
        runs.push(run);
    }
    Ok(runs)
}

/// One round of closed-loop training data (docs/usage.md "`demo`" and "`scale`"): a
/// round-0 model trained on the first half of a recipe's sessions compensates the other
/// sessions as they are recorded again, on the same days, placements and seeds as their
/// open-loop recordings, under the calibrated controller.
pub struct ClosedLoopRound<'a> {
    /// The recipe of the open-loop recordings.
    pub recipe: &'a Recipe,
    /// Their minutes per path.
    pub minutes: f64,
    /// The twin machine they were recorded on.
    pub machine_seed: u64,
    /// The round-0 model predicts every this many control ticks.
    pub every: usize,
    /// The round-0 model's name in the notes.
    pub name: String,
    /// Where the round-0 model is written (its core stage only).
    pub files: ModelFiles,
    /// Where the closed-loop recordings go (kept, and not recorded again, when complete).
    pub dir: PathBuf,
}

impl ClosedLoopRound<'_> {
    /// What `who` trained on once the round has run, in words: the first half of the
    /// sessions open loop and the rest closed loop.
    pub fn training_set(&self, who: &str) -> String {
        let (half, n) = (self.recipe.sessions / 2, self.recipe.sessions);
        format!(
            "{who} trained on sessions 1-{half} open loop and {}-{n} closed loop",
            half + 1
        )
    }
}

/// Runs `round`: trains the round-0 model (`config`) on the first half of `sources`'
/// sessions, then records the others again with it compensating. Returns the first
/// half's recordings with the closed-loop ones (the same minutes as `sources`), and
/// what happened in words.
pub fn record_closed_loop(
    device: &Device,
    round: &ClosedLoopRound<'_>,
    config: &RunConfig,
    sources: &DataSources,
    reporter: &mut dyn Reporter,
) -> Result<(DataSources, String)> {
    let recipe = round.recipe;
    let name = &round.name;
    let half = recipe.sessions / 2;
    if half == 0 {
        return Err(Error::Invalid(format!(
            "closed-loop data record the second half of the sessions with a model trained \
             on the first: give 2 sessions or more, got {}",
            recipe.sessions
        )));
    }
    let mut union = sources.clone();
    union.recordings.truncate(half * PathKind::TRAINING.len());
    let trained = {
        let (graph, data) = train::build_dataset(&union, config, None)?;
        train_core(device, &data, &graph, config, name, &round.files, reporter)?
    };
    let round0 = Checkpoint::load(&round.files.core)?;
    let dir = &round.dir;
    let to = |kind: PathKind, s: usize| dir.join(recipe.file_name(kind, s));
    let recorded: Vec<PathBuf> = (half + 1..=recipe.sessions)
        .flat_map(|s| PathKind::TRAINING.map(|k| to(k, s)))
        .collect();
    let complete = recorded
        .iter()
        .all(|r| r.exists() && RunInfo::sidecar(r).exists());
    let mut error = (f64::NAN, f64::NAN);
    if !complete {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let geometry = sources.geometry()?;
        let machine = draw_machine(geometry.clone(), round.machine_seed);
        let controller = file::calibrated_robot(geometry, &sources.calibration)?;
        let controller_name = format!(
            "{} with {name} compensating (every {} ticks)",
            sources.calibration.display(),
            round.every
        );
        let dt = SimConfig::new(PathKind::Grid, 1.0, 0).dt;
        let settings = Online { every: round.every };
        let plan = recipe.plan(round.minutes, TRAINING_SEED, round.machine_seed);
        let sessions: Vec<(usize, PlannedSession)> =
            plan.into_iter().enumerate().skip(half).collect();
        // A predictor per session: each run starts its model afresh anyway.
        let per_session = sessions_at_once(
            sessions,
            device.prefers_native(),
            reporter,
            |(s, session), notes| {
                notes.note(&format!(
                    "== {name}: training session {} of {} recorded with it compensating",
                    s + 1,
                    recipe.sessions
                ));
                let mut members = vec![Predictor::on(device, &round0, 1)?];
                let mut model = ModelInLoop::new(&mut members, &round0.graph, settings, dt)?;
                let mut correct =
                    |tick: usize, channels: &[Option<f64>]| -> Result<Option<Correction>> {
                        if tick == 0 {
                            model.reset();
                        }
                        Ok(model.tick(tick, channels)?.filter(within_limit))
                    };
                let to = |kind: PathKind| to(kind, s + 1);
                let target = (&controller, controller_name.as_str());
                record_session(&machine, target, session, &to, Some(&mut correct), notes)
            },
        )?;
        let runs: Vec<RecordedRun> = per_session.into_iter().flatten().collect();
        let n = runs.len().max(1) as f64;
        error = (
            runs.iter().map(|r| r.mean_target_error[0]).sum::<f64>() / n,
            runs.iter().map(|r| r.mean_target_error[1]).sum::<f64>() / n,
        );
    }
    union.recordings.extend(recorded);
    let measured = if error.0.is_finite() {
        format!(
            "; its corrections left a mean true error against the path target of {:.1} µm / \
             {:.1} mdeg (tool axis) in those runs",
            error.0, error.1
        )
    } else {
        String::new()
    };
    Ok((
        union,
        format!(
            "round 0 ({name}) trained on sessions 1-{half} (best validation loss {:.4} at \
             epoch {} of {}) compensated sessions {}-{} as they were recorded again{measured}",
            trained.best_val,
            trained.best_epoch,
            trained.epochs,
            half + 1,
            recipe.sessions,
        ),
    ))
}

/// The mean core-stage epoch time of a history (NaN without core epochs).
pub fn epoch_seconds(history: &[EpochRecord]) -> f64 {
    let core: Vec<f64> = history
        .iter()
        .filter(|r| r.stage == "core")
        .map(|r| r.seconds)
        .collect();
    if core.is_empty() {
        f64::NAN
    } else {
        core.iter().sum::<f64>() / core.len() as f64
    }
}

/// One model fitted by [`fit_model`].
pub struct Fitted {
    /// The model to evaluate (refined, or the core weights when refinement did not help).
    pub model: NamedModel,
    /// The core stage's epochs.
    pub core: Vec<EpochRecord>,
    /// The refinement stages' epochs.
    pub refinement: Vec<EpochRecord>,
    /// Best validation loss of the core stage, and its epoch.
    pub best_val: f64,
    /// The epoch of `best_val`.
    pub best_epoch: usize,
    /// What refinement did (its per-window validation losses and which weights it kept).
    pub verdict: String,
    /// Fig. 9b before and after refinement.
    pub accumulated: (AccumulatedCurve, AccumulatedCurve),
    /// Validation-split metrics of the core stage's best weights, per recording.
    pub validation: Vec<TestMetrics>,
    /// Test-split metrics of the core stage's best weights, per recording.
    pub test: Vec<TestMetrics>,
}

/// Training seeds as `demo` and `reproduce` take them: at least one, none twice.
pub fn check_seeds(seeds: &[u64]) -> Result<()> {
    if seeds.is_empty() {
        return Err(Error::Invalid("give at least one training seed".into()));
    }
    for (i, s) in seeds.iter().enumerate() {
        if seeds[..i].contains(s) {
            return Err(Error::Invalid(format!(
                "seeds: training seed {s} is listed twice"
            )));
        }
    }
    Ok(())
}

/// Where [`fit_model`] writes one model: the core stage's best checkpoint (with its
/// resumable state, log and loss plot beside it) and the refined checkpoint (with its
/// log, loss plot and Fig. 9b files).
#[derive(Clone, Debug)]
pub struct ModelFiles {
    /// Core stage checkpoint.
    pub core: PathBuf,
    /// Refined checkpoint (the one evaluated).
    pub refined: PathBuf,
    /// Continue the core stage from its state file when one exists (after an
    /// interruption) instead of starting afresh.
    pub resume: bool,
}

impl ModelFiles {
    /// The files of the model `name` (`<model>.seed<k>` or a plain variant name) in
    /// `dir`, in the one naming scheme of `demo`, `reproduce` and `evaluate --robot`
    /// (docs/usage.md "Checkpoint names"): the refined checkpoint, the model that is
    /// evaluated, is `<name>.safetensors`; the core stage's is `<name>.core.safetensors`,
    /// with its `.state.safetensors`, `.log.csv` and `.loss.png`.
    pub fn named(dir: &Path, name: &str, resume: bool) -> ModelFiles {
        ModelFiles {
            core: dir.join(format!("{name}{CORE_SUFFIX}.safetensors")),
            refined: dir.join(format!("{name}.safetensors")),
            resume,
        }
    }
}

/// The report's line on training data recorded without a closed-loop round.
pub const OPEN_LOOP_DATA: &str =
    "open-loop data: every training session recorded under the calibrated controller alone";

/// What the core stage's checkpoint adds to the model's name in its file name.
pub const CORE_SUFFIX: &str = ".core";

/// The core stage of `config`'s variant on `data` into `files.core`, resuming from its
/// state file when `files.resume` and one exists; the model is named `name` in the notes.
pub fn train_core(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    config: &RunConfig,
    name: &str,
    files: &ModelFiles,
    reporter: &mut dyn Reporter,
) -> Result<Trained> {
    let state = sibling(&files.core, ".state.safetensors");
    let from = (files.resume && state.exists()).then_some(state.as_path());
    let trained = train::train(device, data, graph, config, &files.core, from, reporter)?;
    reporter.note(&format!(
        "{name}: best validation loss {:.4} at epoch {} of {}",
        trained.best_val, trained.best_epoch, trained.epochs
    ));
    Ok(trained)
}

/// Trains `config`'s variant on `data` (core stage with early stopping, resuming from the
/// core checkpoint's state file when `files.resume` and one exists), then refines it the
/// same way for every model; the evaluated model is named `name`.
pub fn fit_model(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    config: &RunConfig,
    name: &str,
    files: &ModelFiles,
    reporter: &mut dyn Reporter,
) -> Result<Fitted> {
    let trained = train_core(device, data, graph, config, name, files, reporter)?;
    let core = Checkpoint::load(&files.core)?;
    let r = refine(device, data, graph, config, &core.parameters, reporter)?;
    let verdict = r.verdict();
    reporter.note(&format!("{name}: refinement {verdict}"));
    let refined = r.save(&core, &files.refined)?;
    let trained_on =
        crate::train::log::trained_on(trained.history.iter().map(|r| r.trained_on.as_str()));
    Ok(Fitted {
        model: NamedModel {
            name: name.to_string(),
            checkpoint: refined,
            epoch_seconds: epoch_seconds(&trained.history),
            trained_on,
        },
        core: trained.history,
        refinement: r.history,
        best_val: trained.best_val,
        best_epoch: trained.best_epoch,
        verdict,
        accumulated: (r.before, r.after),
        validation: trained.validation,
        test: trained.test,
    })
}
