//! Fitting a model from start to end: the dataset of a run config, the stage loop with
//! its reporting, the core training run with its checkpoint, resumable state, log and
//! loss plot (and the last good weights when it diverges), and the test-split metrics.

use std::path::{Path, PathBuf};

use super::pollination::{pollinate, Pollination};
use super::{
    checkpoint, core_stage, log, metrics, normalization, to_physical, Metrics, RunConfig,
    TrainError, TrainState, Trainer,
};
use crate::data::{self, DataSources, Dataset, SplitMode, WindowConfig};
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Parameters, Variant};
use crate::progress::Reporter;

/// The sibling of `out` with `suffix` in place of its extension (`m.safetensors` →
/// `m.state.safetensors`).
pub fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or("model".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}{suffix}"))
}

/// The windows of a run config.
pub fn window_config(config: &RunConfig) -> WindowConfig {
    WindowConfig {
        length: config.model.window,
        stride: config.data.stride,
        train_kept: config.data.train_fraction,
        validation_kept: config.data.validation_fraction,
        look_ahead: config.model.look_ahead,
        ..WindowConfig::default()
    }
}

/// The split of a run config: contiguous blocks, or the paper's random split.
pub fn split_mode(config: &RunConfig) -> SplitMode {
    if config.data.split == "random" {
        SplitMode::Random {
            seed: config.data.split_seed,
        }
    } else {
        SplitMode::Contiguous
    }
}

/// The dataset of `sources` windowed and split as `config` says, standardised with
/// `fixed` (a model's statistics) or its own training split's.
pub fn build_dataset(
    sources: &DataSources,
    config: &RunConfig,
    fixed: Option<&data::Normalization>,
) -> Result<(Graph, Dataset)> {
    sources.dataset(&window_config(config), split_mode(config), fixed)
}

/// Test-split metrics of one recording: the model's, and those of predicting the
/// training-split mean.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TestMetrics {
    /// The recording's name.
    pub recording: String,
    /// The model's metrics on its test block.
    pub model: Metrics,
    /// Those of predicting the training-split label mean (the baseline).
    pub training_mean: Metrics,
}

/// A recording's file stem (`data/grid.s01.csv` is `grid.s01`), as Table III names it.
pub fn recording_stem(recording: &str) -> String {
    Path::new(recording)
        .file_stem()
        .map_or(recording.to_string(), |s| s.to_string_lossy().into_owned())
}

/// The path a recording belongs to: its file name up to the first dot (`grid.csv` and
/// `data/grid.s03.csv` are both `grid`).
pub fn recording_path(recording: &str) -> String {
    let name = Path::new(recording)
        .file_name()
        .map_or(recording.to_string(), |s| s.to_string_lossy().into_owned());
    name.split('.').next().unwrap_or(&name).to_string()
}

/// Metrics per path: the recordings of one path (the sessions of a multi-session
/// training set, docs/twin.md "Sessions") pooled with [`Metrics::pooled`], named by the
/// path, in the order each path first appears. A path with one recording keeps it as it
/// is, name included.
pub fn by_path(metrics: &[TestMetrics]) -> Vec<TestMetrics> {
    let mut paths: Vec<String> = Vec::new();
    for m in metrics {
        let p = recording_path(&m.recording);
        if !paths.contains(&p) {
            paths.push(p);
        }
    }
    paths
        .into_iter()
        .map(|p| {
            let group: Vec<&TestMetrics> = metrics
                .iter()
                .filter(|m| recording_path(&m.recording) == p)
                .collect();
            if let [one] = group[..] {
                return one.clone();
            }
            TestMetrics {
                recording: p,
                model: Metrics::pooled(group.iter().map(|m| &m.model)),
                training_mean: Metrics::pooled(group.iter().map(|m| &m.training_mean)),
            }
        })
        .collect()
}

/// Test-split metrics per recording of the trainer's current weights.
pub fn test_metrics(trainer: &Trainer, data: &Dataset) -> Result<Vec<TestMetrics>, TrainError> {
    let [_, _, test] = data.split_ranges();
    split_metrics(trainer, data, test)
}

/// Validation-split metrics per recording of the trainer's current weights (in µm and
/// mdeg, so comparable between datasets standardised differently).
pub fn validation_metrics(
    trainer: &Trainer,
    data: &Dataset,
) -> Result<Vec<TestMetrics>, TrainError> {
    let [_, validation, _] = data.split_ranges();
    split_metrics(trainer, data, validation)
}

fn split_metrics(
    trainer: &Trainer,
    data: &Dataset,
    range: std::ops::Range<usize>,
) -> Result<Vec<TestMetrics>, TrainError> {
    let positions: Vec<usize> = range.collect();
    let pred = to_physical(&trainer.predict(&positions)?, &data.normalization);
    Ok(data
        .recordings
        .iter()
        .zip(metrics::per_recording(data, &positions, &pred))
        .map(|(name, (model, mean))| TestMetrics {
            recording: name.clone(),
            model,
            training_mean: mean,
        })
        .collect())
}

/// Runs the trainer's stage to its end, reporting every epoch to `reporter` (as task
/// `label`) and calling `on_epoch` with whether the validation loss improved; restores
/// the best weights.
pub fn run_stage(
    trainer: &mut Trainer,
    label: &str,
    reporter: &mut dyn Reporter,
    mut on_epoch: impl FnMut(&Trainer, bool) -> Result<()>,
) -> Result<()> {
    reporter.begin(&format!("{label} epoch"), trainer.stage.max_epochs as u64);
    reporter.update(trainer.progress.epoch as u64, "");
    let first = trainer.progress.history.len();
    let mut files_seconds = 0.0;
    while !trainer.finished() {
        let (r, improved) = trainer.run_epoch()?;
        reporter.update(
            r.epoch as u64,
            &format!(
                "loss {:.4} val {:.4} lr {:.2e} {:.0} win/s{}",
                r.train_loss,
                r.val_loss,
                r.lr,
                r.windows_per_s,
                if improved { " *" } else { "" }
            ),
        );
        let began = std::time::Instant::now();
        on_epoch(trainer, improved)?;
        files_seconds += began.elapsed().as_secs_f64();
    }
    reporter.end();
    if let Some(cost) = EpochCost::of(&trainer.progress.history[first..], files_seconds) {
        reporter.note(&format!("{label}: {cost}"));
    }
    trainer.restore_best()?;
    Ok(())
}

/// Where a stage's epochs spent their time beyond the training steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpochCost {
    /// Epochs counted.
    pub epochs: usize,
    /// Training steps (submitted back to back, one readback of the step losses), s.
    pub steps: f64,
    /// Validation passes, s.
    pub validation: f64,
    /// Parameter and optimiser-state readbacks, s.
    pub readbacks: f64,
    /// Checkpoint, state, log and plot files written after each epoch, s.
    pub files: f64,
}

impl EpochCost {
    /// The totals over `history` plus the file writes timed by the caller; None for no
    /// epoch.
    pub fn of(history: &[super::EpochRecord], files: f64) -> Option<EpochCost> {
        (!history.is_empty()).then(|| EpochCost {
            epochs: history.len(),
            steps: history.iter().map(|r| r.seconds).sum(),
            validation: history.iter().map(|r| r.validation_seconds).sum(),
            readbacks: history.iter().map(|r| r.readback_seconds).sum(),
            files,
        })
    }

    /// Everything beyond the steps, as a fraction of the steps' time.
    pub fn overhead(&self) -> f64 {
        (self.validation + self.readbacks + self.files) / self.steps
    }
}

impl std::fmt::Display for EpochCost {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let share = |s: f64| 100.0 * s / self.steps;
        write!(
            f,
            "{} epochs, steps {:.1} s; beyond them {:.1} % (validation {:.1} %, readbacks {:.1} %, files {:.1} %)",
            self.epochs,
            self.steps,
            100.0 * self.overhead(),
            share(self.validation),
            share(self.readbacks),
            share(self.files)
        )
    }
}

/// How often `iastgcn train` writes its epoch files while a stage runs: after the first
/// epoch, after each epoch that ends at least this long after the last write, and after
/// the stage's last epoch. Writing them (synced to disk) takes a few milliseconds: 1–2 %
/// of a demo IASTGCN epoch, half of a dense baseline's. A run killed between writes
/// resumes from the last one and, training being deterministic, ends the same.
pub const EPOCH_FILES_EVERY: std::time::Duration = std::time::Duration::from_secs(2);

/// When a stage's epoch files are due ([`EPOCH_FILES_EVERY`]).
#[derive(Debug, Default)]
pub struct EpochFiles {
    /// When they were last written.
    last: Option<std::time::Instant>,
    /// Whether the validation loss improved since then.
    improved: bool,
}

impl EpochFiles {
    /// After an epoch (`improved`: its validation loss improved): `Some(whether the best
    /// weights changed since the last write)` when the files are due, else `None`.
    pub fn due(&mut self, trainer: &Trainer, improved: bool) -> Option<bool> {
        self.improved |= improved;
        let elapsed = self.last.is_none_or(|t| t.elapsed() >= EPOCH_FILES_EVERY);
        (trainer.finished() || elapsed).then(|| {
            self.last = Some(std::time::Instant::now());
            std::mem::take(&mut self.improved)
        })
    }
}

/// What `iastgcn train` writes after an epoch when they are due ([`EpochFiles`]): the
/// checkpoint `out` when the validation loss improved since the last write (`improved`),
/// and always the resumable training state, the log CSV and the loss PNG beside it
/// (`<stem>.state.safetensors`, `<stem>.log.csv`, `<stem>.loss.png`). All of them are
/// written in full before any replaces its older version ([`crate::atomic::Batch`]): a
/// failure leaves the previous set.
pub fn write_epoch_files(
    trainer: &Trainer,
    config: &RunConfig,
    graph: &Graph,
    data: &Dataset,
    out: &Path,
    improved: bool,
) -> Result<()> {
    let mut batch = crate::atomic::Batch::new();
    if improved {
        checkpoint(&config.model, graph, &trainer.best, &data.normalization)
            .stage(&mut batch, out)?;
    }
    let state_path = sibling(out, ".state.safetensors");
    let state = TrainState {
        run: config.clone(),
        normalization: normalization(&data.normalization),
        snapshot: trainer.snapshot().clone(),
    }
    .to_bytes(&state_path)?;
    batch
        .add(&state_path, &state)
        .map_err(|e| Error::io(&state_path, e))?;
    let history = &trainer.progress.history;
    let log_path = sibling(out, ".log.csv");
    batch
        .add(&log_path, log::history_csv(history).as_bytes())
        .map_err(|e| Error::io(&log_path, e))?;
    let name = config.model.variant.name().to_string();
    batch.add_with(&sibling(out, ".loss.png"), |tmp| {
        log::plot_losses(tmp, &[(name, history.clone())])
    })?;
    batch.commit().map_err(|e| Error::io(out, e))?;
    Ok(())
}

/// Every setting that must match for a resumed run (the epoch limit and patience may
/// change, and so may where the steps run: both paths read and write the same state).
fn resumable(a: &RunConfig, b: &RunConfig) -> bool {
    let strip = |c: &RunConfig| {
        let mut c = c.clone();
        c.train.max_epochs = 0;
        c.train.patience = 0;
        c.train.backend.clear();
        c.train.threads = 0;
        c.refine = Default::default();
        c
    };
    strip(a) == strip(b)
}

/// How a core training run ended.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Trained {
    /// The best validation loss (the data term of eq. 39, standardised label space).
    pub best_val: f64,
    /// The epoch it was reached in.
    pub best_epoch: usize,
    /// Epochs run.
    pub epochs: usize,
    /// Why training stopped, in words ([`Trainer::stopped`]).
    pub stopped: String,
    /// One record per epoch.
    pub history: Vec<super::EpochRecord>,
    /// Test-split metrics of the best weights, per recording.
    pub test: Vec<TestMetrics>,
    /// Validation-split metrics of the best weights, per recording.
    pub validation: Vec<TestMetrics>,
}

/// The core stage of `config` on `data` (a fresh seeded start, or the state file
/// `resume`), written as it goes: the best checkpoint to `out` (atomically, whenever the
/// validation loss improves), and beside it `<stem>.state.safetensors` (to resume),
/// `<stem>.log.csv` and `<stem>.loss.png`. When training diverges, `out` keeps the best
/// weights, or the last good ones when no epoch finished, and the error says which.
pub fn train(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    config: &RunConfig,
    out: &Path,
    resume: Option<&Path>,
    reporter: &mut dyn Reporter,
) -> Result<Trained> {
    config.validate().map_err(Error::Invalid)?;
    let init = match resume {
        // The state's weights replace the start.
        Some(_) => Parameters::init(&config.model, config.train.seed),
        None => initial_parameters(device, data, graph, config, reporter)?,
    };
    let mut trainer = Trainer::new(
        device,
        data,
        graph,
        &config.model,
        &config.train,
        core_stage(config),
        &init,
    )?;
    let stats = normalization(&data.normalization);
    if let Some(p) = resume {
        let state = TrainState::load(p)?;
        if !resumable(&state.run, config) {
            return Err(Error::Invalid(format!(
                "{}: the state was written by a run with another config or variant (only train.max_epochs and train.patience may change)",
                p.display()
            )));
        }
        if state.normalization != stats {
            return Err(Error::Invalid(format!(
                "{}: the state was trained on other data (its normalisation statistics differ from these recordings')",
                p.display()
            )));
        }
        trainer.restore(&state.snapshot)?;
        trainer.set_limits(config.train.max_epochs, config.train.patience);
        let p2 = &trainer.progress;
        reporter.note(&format!(
            "resumed {} at epoch {} (step {}, best validation loss {:.5} at epoch {})",
            p.display(),
            p2.epoch,
            p2.step,
            p2.best_val,
            p2.best_epoch
        ));
        if let Some(why) = trainer.stopped() {
            reporter.note(&format!(
                "nothing more to train: {why}; to continue, set {}",
                trainer.to_continue()
            ));
        }
    }
    if !trainer.finished() {
        reporter.note(&format!(
            "training {} on {}: {} windows per step, {} steps per epoch",
            config.model.variant,
            trainer.trained_on(),
            trainer.batch(),
            trainer.steps_per_epoch()
        ));
    }
    if trainer.batch() < config.train.batch {
        // Documented (docs/robustness.md): a batch beyond the split is the whole split.
        reporter.note(&format!(
            "warning: train.batch = {} is more than the {} training windows: each step takes all of them",
            config.train.batch,
            trainer.batch()
        ));
    }
    let name = config.model.variant.name();
    let mut files = EpochFiles::default();
    let result = run_stage(&mut trainer, name, reporter, |t, improved| {
        match files.due(t, improved) {
            Some(improved) => write_epoch_files(t, config, graph, data, out, improved),
            None => Ok(()),
        }
    });
    if let Err(e) = result {
        return Err(diverged(e, &trainer, config, graph, data, out));
    }
    let p = &trainer.progress;
    Ok(Trained {
        best_val: p.best_val,
        best_epoch: p.best_epoch,
        epochs: p.epoch,
        stopped: trainer.stopped().unwrap_or_default(),
        history: p.history.clone(),
        test: test_metrics(&trainer, data)?,
        validation: validation_metrics(&trainer, data)?,
    })
}

/// The starting weights of a core stage: the He initialisation of `[train] seed`, or for
/// `ann-bfpa` the pick of its flower-pollination search (docs/model.md "Baselines").
pub fn initial_parameters(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    config: &RunConfig,
    reporter: &mut dyn Reporter,
) -> Result<Parameters> {
    if config.model.variant != Variant::AnnBfpa {
        return Ok(Parameters::init(&config.model, config.train.seed));
    }
    let search = Pollination::default();
    let s = pollinate(
        device,
        data,
        graph,
        &config.model,
        &config.train,
        &search,
        reporter,
    )?;
    reporter.note(&format!(
        "ann-bfpa: flower-pollination search, {} candidates × {} generations ({} losses on {} training windows): loss {:.4} at the He initialisation, {:.4} at the pick",
        search.population,
        search.generations,
        s.evaluations,
        search.windows.min(data.splits.train.len()),
        s.start_loss,
        s.best_loss
    ));
    Ok(s.params)
}

/// On divergence: keep the best checkpoint, or write the last good weights when no epoch
/// finished; say where they are.
fn diverged(
    e: Error,
    trainer: &Trainer,
    config: &RunConfig,
    graph: &Graph,
    data: &Dataset,
    out: &Path,
) -> Error {
    let Some(TrainError::Diverged { last_good, .. }) = e.find::<TrainError>() else {
        return e;
    };
    // The best weights so far (the epoch files may not have been written since they
    // improved), or the last good ones when no epoch improved.
    let epoch = trainer.progress.best_epoch;
    let (weights, what) = if epoch > 0 {
        (&trainer.best, format!("the best weights (epoch {epoch})"))
    } else {
        (
            &**last_good,
            "the last good weights (before the bad step)".to_string(),
        )
    };
    match checkpoint(&config.model, graph, weights, &data.normalization).save(out) {
        Ok(()) => e.context(format!("stopped; {} keeps {what}", out.display())),
        Err(w) => e.context(format!("stopped, and {what} could not be saved: {w}")),
    }
}
