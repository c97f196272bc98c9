//! `iastgcn scale`: the scaling study (docs/results.md "Scaling study"). How much does
//! each model gain from more training data, and where does that stop? One training
//! session of three recordings is recorded at the largest size M; a job trains one model
//! with one seed (core stage, to early stopping) on the first `m / M` of each
//! recording's training block and stops early on the first `m / M` of its validation
//! block, so it sees what an `m`-minute session would have given it, while the test
//! blocks stay those of the M-minute recordings: every size is scored on the same test
//! windows (`0.1·M` minutes per path) and on the same held-out session in the twin,
//! against hidden truth. Jobs are resumable and shardable
//! as `reproduce`'s; the summary (`scale.csv`, `scale_summary.csv`, `scale.md`,
//! `scale.png`) is rewritten from every finished job after each one, so a study stopped
//! early still reports what it has. With a validation session (`Study::validation`)
//! every job is scored on one more held-out session, kept out of those tables, on which
//! `experiment::recommend`'s rule names the model to use at each size (`scale.md`
//! "Recommended model", `scale_validation.csv`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::evaluate::{
    ensemble, held_out_session, predictors, table_iii, HeldOutConfig, LoopModel, SessionOptions,
    MAX_HELD_OUT_SESSIONS,
};
use super::jobs::{clock, pin_toml, read_toml, write_toml, Shard};
use super::protocol::{
    check_seeds, epoch_seconds, existing_data, record_closed_loop, record_data, train_core,
    ClosedLoopRound, ModelFiles, MACHINE_SEED,
};
use super::recommend::{recommend_runs, validation_session, Recommendation, ValidationRun};
use super::report::seeds::{seeded_name, Spread};
use super::report::TableVRow;
use crate::data::{DataSources, Dataset};
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Checkpoint, Variant};
use crate::plot::{self, Panel, Series};
use crate::progress::Reporter;
use crate::train::log::csv_text;
use crate::train::{build_dataset, by_path, recording_path, refine, RunConfig, TestMetrics};
use crate::twin::{PathKind, Recipe};

/// The paper's Table V on its Hilbert run (its only compensated path): the share of the
/// calibrated error its IASTGCN removed, position and attitude, % (0.1393 → 0.0591 mm,
/// 0.0811 → 0.0183°).
pub const PAPER_HILBERT_REMOVED: [f64; 2] = [57.6, 77.4];

/// What `iastgcn scale` runs. A folder holds one setup (the recordings' length, the run
/// config, the machine and the held-out session, pinned in `study.toml`); sizes, seeds
/// and models may grow from one call to the next, since each job stands alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Study {
    /// Length of each training recording, minutes: the largest size there can be.
    pub recording_minutes: f64,
    /// Training data per path, minutes of recording, ascending, each at most
    /// `recording_minutes`.
    pub sizes: Vec<f64>,
    /// Training seeds.
    pub seeds: Vec<u64>,
    /// Models by name.
    pub models: Vec<String>,
    /// The run config every model trains with (its variant, seed and training share set
    /// per job).
    pub run: RunConfig,
    /// The twin machine of the data and the held-out session.
    pub machine_seed: u64,
    /// Length of each held-out run, minutes.
    pub held_out_minutes: f64,
    /// Seed of the first held-out run.
    pub held_out_seed: u64,
    /// Minutes of polishing before the held-out session's first scored run.
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks during compensation.
    pub every: usize,
    /// How the training set is recorded (docs/twin.md "Sessions"); a study's sizes are
    /// the first m/M of each recording, of every session.
    #[serde(default)]
    pub recipe: Recipe,
    /// Held-out sessions every job is scored on ([`HeldOutConfig::session`]); studies
    /// pinned before there were several have one.
    #[serde(default = "one_session")]
    pub held_out_sessions: usize,
    /// Refine every job after its core stage (the paper's Algorithm 2, as `demo` does:
    /// the refined weights are kept only where they lower the per-window validation
    /// loss) and score the result.
    #[serde(default)]
    pub refine: bool,
    /// The sensor graph every model reads (the embedded assets/graph.toml when absent;
    /// `[model] nodes` of the run config must match it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub graph: Option<PathBuf>,
    /// Also score each model and size whose seeds have all finished as an ensemble: the
    /// controller averages the seeds' predictions (record `<model>.min<m>.ensemble`,
    /// model `<model>-ensemble`). May change between calls of one folder.
    #[serde(default)]
    pub ensemble: bool,
    /// Closed-loop data (docs/usage.md "scale", `--closed-loop`): each job first trains a
    /// round-0 model on the first half of the recipe's sessions, records the other
    /// sessions again (the same days, placements and seeds) with it compensating, and
    /// trains on the first half plus those: the same minutes as the open-loop recipe.
    /// Needs 2 or more sessions; a folder keeps this choice.
    #[serde(default)]
    pub closed_loop: bool,
    /// Also score every job on a validation session (the next held-out session,
    /// [`validation_session`], never in the tables) and name the model recommended at
    /// each size there by `experiment::recommend`'s rule, as `evaluate` does. A folder
    /// keeps this choice.
    #[serde(default)]
    pub validation: bool,
}

fn one_session() -> usize {
    1
}

impl Study {
    /// The study of issue 39 at the demo's model and training settings: 2, 8, 32 and 128
    /// minutes per path, IASTGCN, its Chebyshev ablation, T-GCN and the MLP, seeds 1–3,
    /// a held-out session of 2-minute runs.
    pub fn demo_shape() -> Study {
        let held = HeldOutConfig::default();
        Study {
            recording_minutes: 128.0,
            sizes: vec![2.0, 8.0, 32.0, 128.0],
            seeds: vec![1, 2, 3],
            models: ["iastgcn", "iastgcn-s", "tgcn", "mlp"]
                .map(String::from)
                .to_vec(),
            run: RunConfig::demo(),
            machine_seed: MACHINE_SEED,
            held_out_minutes: 2.0,
            held_out_seed: held.seed,
            warm_up_minutes: held.warm_up_minutes,
            every: held.every,
            recipe: Recipe::SINGLE,
            held_out_sessions: 3,
            refine: false,
            graph: None,
            ensemble: false,
            closed_loop: false,
            validation: false,
        }
    }

    /// The held-out sessions every job is scored on: the test sessions, then the
    /// validation session when there is one.
    pub fn scored_sessions(&self) -> usize {
        self.held_out_sessions + usize::from(self.validation)
    }

    /// The validation session's index, if the study has one.
    pub fn validation_index(&self) -> Option<usize> {
        self.validation
            .then(|| validation_session(self.held_out_sessions))
    }

    /// The held-out session every job is scored on.
    pub fn held_out(&self) -> HeldOutConfig {
        HeldOutConfig {
            minutes: self.held_out_minutes,
            seed: self.held_out_seed,
            warm_up_minutes: self.warm_up_minutes,
            every: self.every,
            sessions: self.held_out_sessions,
        }
    }

    /// The jobs, seed by seed, then size by size (smallest first), then model by model:
    /// a study stopped early has whole curves of its first seeds.
    pub fn jobs(&self) -> Result<Vec<ScaleJob>> {
        let variants = self
            .models
            .iter()
            .map(|m| {
                Variant::parse(m).ok_or_else(|| {
                    Error::Invalid(format!("unknown model {m:?} ({})", Variant::names()))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut jobs = Vec::new();
        for &seed in &self.seeds {
            for &minutes in &self.sizes {
                jobs.extend(variants.iter().map(|&variant| ScaleJob {
                    variant,
                    seed,
                    minutes,
                }));
            }
        }
        Ok(jobs)
    }

    /// Checks sizes, seeds, models, the run config and the held-out session.
    pub fn validate(&self) -> Result<()> {
        let longest = crate::data::MAX_RUN_SECONDS / 60.0;
        let max = self.recording_minutes;
        if !(max.is_finite() && max > 0.0 && max <= longest) {
            return Err(Error::Invalid(format!(
                "recording minutes: more than 0 and at most {longest} min, got {max}"
            )));
        }
        if self.sizes.is_empty() {
            return Err(Error::Invalid("sizes: give at least one size".into()));
        }
        for (i, &m) in self.sizes.iter().enumerate() {
            if !(m.is_finite() && m > 0.0 && m <= max) || (i > 0 && m <= self.sizes[i - 1]) {
                return Err(Error::Invalid(format!(
                    "sizes: each size is more than 0 and at most the recordings' {max} min, in \
                     ascending order and listed once; got {:?}",
                    self.sizes
                )));
            }
        }
        self.recipe.validate(max).map_err(Error::Invalid)?;
        if self.closed_loop && self.recipe.sessions < 2 {
            return Err(Error::Invalid(format!(
                "--closed-loop records the second half of the sessions with a model trained \
                 on the first: give --sessions 2 or more, got {}",
                self.recipe.sessions
            )));
        }
        if !(1..=MAX_HELD_OUT_SESSIONS).contains(&self.held_out_sessions) {
            return Err(Error::Invalid(format!(
                "--held-out-sessions: 1 to {MAX_HELD_OUT_SESSIONS} held-out sessions, got {}",
                self.held_out_sessions
            )));
        }
        if let Some(path) = &self.graph {
            let graph = Graph::load(path)?;
            if graph.nodes.len() != self.run.model.nodes {
                return Err(Error::Invalid(format!(
                    "--graph {}: the graph has {} nodes, but the run config's [model] nodes \
                     is {}; give a --config with nodes = {}",
                    path.display(),
                    graph.nodes.len(),
                    self.run.model.nodes,
                    graph.nodes.len()
                )));
            }
        }
        check_seeds(&self.seeds)?;
        if self.models.is_empty() {
            return Err(Error::Invalid("the study needs at least one model".into()));
        }
        for (i, m) in self.models.iter().enumerate() {
            if self.models[..i].contains(m) {
                return Err(Error::Invalid(format!("models: {m} is listed twice")));
            }
        }
        self.jobs()?;
        self.run.validate().map_err(Error::Invalid)?;
        self.held_out().validate()
    }

    /// The study with what may change between runs of one folder cleared: its sizes,
    /// seeds and models, and where and on how many threads the steps run.
    fn setup(&self) -> Study {
        let mut s = self.clone();
        s.sizes.clear();
        s.seeds.clear();
        s.models.clear();
        s.run.train.backend.clear();
        s.run.train.threads = 0;
        s.ensemble = false;
        s
    }
}

/// One model trained with one seed on `minutes` of training data per path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleJob {
    /// The model.
    pub variant: Variant,
    /// Its `[train] seed`.
    pub seed: u64,
    /// Training data per path, minutes.
    pub minutes: f64,
}

impl ScaleJob {
    /// `<model>.min<m>.seed<k>`: grouped by `<model>.min<m>` over the seeds.
    pub fn name(&self) -> String {
        seeded_name(
            &format!("{}.min{}", self.variant.name(), self.minutes),
            self.seed,
        )
    }

    /// Its files in the one naming scheme (docs/usage.md "Checkpoint names"): the core
    /// stage's weights are `<name>.core.safetensors` (state, log and loss plot beside);
    /// only a study that refines writes the refined model, `<name>.safetensors`.
    pub fn files(&self, out: &Path) -> ModelFiles {
        ModelFiles::named(&out.join("models"), &self.name(), true)
    }

    /// The record written when the job has finished.
    pub fn record_path(&self, out: &Path) -> PathBuf {
        out.join("models").join(format!("{}.job.toml", self.name()))
    }
}

/// One path's scores of a job: the test split (the three training paths) and the
/// held-out run, against hidden truth, position µm and attitude mdeg.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PathScore {
    /// `grid`, `fermat`, `hilbert` or `rosette`.
    pub path: String,
    /// The held-out session of the run, from 0 ([`HeldOutConfig::session`]).
    #[serde(default)]
    pub session: usize,
    /// Test windows of the path's recording (0 for the rosette, never recorded).
    pub test_windows: usize,
    /// The model's test MAE (NaN for the rosette).
    pub test_mae: [f64; 2],
    /// Mean true pose error of the held-out run: nominal controller, calibrated, the
    /// true residual fed back (oracle), compensated by the model.
    pub initial: [f64; 2],
    /// Calibrated controller.
    pub calibrated: [f64; 2],
    /// The oracle.
    pub oracle: [f64; 2],
    /// Compensated by the model.
    pub compensated: [f64; 2],
    /// The model's open-loop prediction error along the uncompensated run: the mean
    /// distance of its predictions from the true residual (NaN in records written before
    /// it was measured).
    #[serde(default = "unmeasured")]
    pub open_loop: [f64; 2],
    /// Mean true error of the held-out run with the open-loop predictions fed forward as
    /// corrections, without their feedback (NaN in records written before it was
    /// measured).
    #[serde(default = "unmeasured")]
    pub replayed: [f64; 2],
}

fn unmeasured() -> [f64; 2] {
    [f64::NAN; 2]
}

impl PathScore {
    /// Share of the calibrated error that compensation (or the oracle) removed, %.
    pub fn removed(&self, by: [f64; 2]) -> [f64; 2] {
        [0, 1].map(|i| 100.0 * (self.calibrated[i] - by[i]) / self.calibrated[i])
    }
}

/// What a finished job left.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleRecord {
    /// `<model>.min<m>.seed<k>`.
    pub name: String,
    /// The model.
    pub model: String,
    /// The training seed.
    pub seed: u64,
    /// Training data per path, minutes.
    pub minutes: f64,
    /// Training windows it trained on.
    pub train_windows: usize,
    /// Best validation loss (standardised) and its epoch, epochs run.
    pub best_val: f64,
    /// Its epoch.
    pub best_epoch: usize,
    /// Core epochs run.
    pub epochs: usize,
    /// Mean epoch time, s.
    pub epoch_seconds: f64,
    /// Where it trained.
    pub trained_on: String,
    /// Wall time of the job in the run that finished it, s.
    pub wall_seconds: f64,
    /// What refinement did, in a study that refines (empty otherwise).
    #[serde(default)]
    pub refinement: String,
    /// How its closed-loop data were made, in a closed-loop study (empty otherwise).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub closed_loop: String,
    /// Scores per path: grid, fermat, hilbert, rosette.
    pub paths: Vec<PathScore>,
}

impl ScaleRecord {
    fn load(path: &Path) -> Result<ScaleRecord> {
        read_toml(path)
    }
}

/// How far a call got: jobs with a record, of all.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    /// Jobs with a record.
    pub done: usize,
    /// Jobs in the study.
    pub total: usize,
}

/// Runs the study into `out` (`study.toml`, `data/`, `models/`, the summary files).
/// With `shard`, only that shard's jobs; with `data_only`, stops once the data exist.
/// Jobs with a record are skipped; an interrupted job resumes from its state file.
pub fn scale(
    device: Device,
    study: &Study,
    shard: Option<Shard>,
    data_only: bool,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<Progress> {
    let began = Instant::now();
    study.validate()?;
    let jobs = study.jobs()?;
    std::fs::create_dir_all(out.join("models")).map_err(|e| Error::io(out, e))?;
    pin_toml(
        study,
        &out.join("study.toml"),
        |a: &Study, b| a.setup() == b.setup(),
        "this folder holds another study (the recordings' length or sessions, the run \
         config, the machine or the held-out sessions differ); use another --out, or the same \
         options (a study pinned before there were several held-out sessions has one: \
         --held-out-sessions 1)",
    )?;
    let minutes = study.recording_minutes;
    reporter.note(&format!(
        "scaling study on {} → {}: {} sizes × {} seeds × {} models = {} jobs; recordings of \
         {minutes} min per path, twin machine {}",
        device.name(),
        out.display(),
        study.sizes.len(),
        study.seeds.len(),
        study.models.len(),
        jobs.len(),
        study.machine_seed
    ));
    let data_dir = out.join("data");
    let mut sources = match existing_data(&data_dir, minutes, study.machine_seed, &study.recipe)? {
        Some(s) => s,
        None => record_data(
            &data_dir,
            minutes,
            study.machine_seed,
            &study.recipe,
            reporter,
        )?,
    };
    sources.graph = study.graph.clone();
    let done = |jobs: &[ScaleJob]| jobs.iter().filter(|j| j.record_path(out).exists()).count();
    if data_only {
        return Ok(Progress {
            done: done(&jobs),
            total: jobs.len(),
        });
    }
    let todo: Vec<(usize, ScaleJob)> = jobs
        .iter()
        .copied()
        .enumerate()
        .filter(|(i, j)| shard.is_none_or(|s| s.owns(*i)) && !j.record_path(out).exists())
        .collect();
    let mut current: Option<(f64, Graph, Dataset)> = None;
    let mut spent = Vec::new();
    for (n, (i, job)) in todo.iter().enumerate() {
        let eta = match spent.len() {
            0 => "unknown until a job finishes".to_string(),
            k => clock(spent.iter().sum::<f64>() / k as f64 * (todo.len() - n) as f64),
        };
        reporter.note(&format!(
            "== job {}/{} ({} of this run): {} seed {} on {} min per path; elapsed {}, ETA {eta}",
            i + 1,
            jobs.len(),
            n + 1,
            job.variant,
            job.seed,
            job.minutes,
            clock(began.elapsed().as_secs_f64())
        ));
        let started = Instant::now();
        let mut config = study.run.clone();
        config.model.variant = job.variant;
        config.train.seed = job.seed;
        config.data.train_fraction = job.minutes / minutes;
        config.data.validation_fraction = job.minutes / minutes;
        // A closed-loop job trains on data of its own (and leaves no dataset cached).
        let closed = if study.closed_loop {
            Some(closed_loop_sources(
                &device, study, &config, job, &sources, out, reporter,
            )?)
        } else {
            None
        };
        let job_sources = closed.as_ref().map_or(&sources, |c| &c.0);
        let size = match current.take() {
            Some(c) if c.0 == job.minutes => c,
            old => {
                drop(old); // free the previous size's dataset first
                let (graph, data) = build_dataset(job_sources, &config, None)?;
                for line in data.summary().lines() {
                    reporter.note(line);
                }
                (job.minutes, graph, data)
            }
        };
        let (_, graph, data) = current.insert(size);
        let mut record = run_job(
            &device,
            study,
            &config,
            job,
            (graph, data),
            &sources,
            out,
            reporter,
        )?;
        record.wall_seconds = started.elapsed().as_secs_f64();
        if let Some((_, how)) = closed {
            record.closed_loop = how;
            current = None;
        }
        write_toml(&record, &job.record_path(out))?;
        spent.push(record.wall_seconds);
        write_summary(study, out, reporter)?;
    }
    // A shard scores no ensemble: its seeds may be another shard's, still training.
    if study.ensemble && shard.is_none() {
        score_ensembles(&device, study, &sources, out, reporter)?;
    }
    // Once more with nothing to do: a finished folder gets this build's summary.
    if todo.is_empty() {
        write_summary(study, out, reporter)?;
    }
    Ok(Progress {
        done: done(&jobs),
        total: jobs.len(),
    })
}

/// The core stage of one job, then its scores: the test split per path from the best
/// weights, and the held-out session with the model in the loop.
#[allow(clippy::too_many_arguments)]
fn run_job(
    device: &Device,
    study: &Study,
    config: &RunConfig,
    job: &ScaleJob,
    (graph, data): (&Graph, &Dataset),
    sources: &DataSources,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<ScaleRecord> {
    let name = job.name();
    let files = job.files(out);
    let trained = train_core(device, data, graph, config, &name, &files, reporter)?;
    let core = Checkpoint::load(&files.core)?;
    let (checkpoint, test, refinement) = if study.refine {
        let r = refine(device, data, graph, config, &core.parameters, reporter)?;
        let verdict = r.verdict();
        reporter.note(&format!("{name}: refinement {verdict}"));
        let refined = r.save(&core, &files.refined)?;
        let test = table_iii(device, &name, &refined, data, true)?
            .chunks(2)
            .map(|pair| TestMetrics {
                recording: pair[0].trajectory.clone(),
                model: pair[0].metrics,
                training_mean: pair[1].metrics,
            })
            .collect();
        (refined, test, verdict)
    } else {
        (core, by_path(&trained.test), String::new())
    };
    let mut in_loop = predictors(device, &[(name.clone(), checkpoint)])?;
    let paths = held_out_scores(device, study, &mut in_loop[0], &test, sources, reporter)?;
    Ok(ScaleRecord {
        name: name.clone(),
        model: job.variant.name().into(),
        seed: job.seed,
        minutes: job.minutes,
        train_windows: data.splits.train.len(),
        best_val: trained.best_val,
        best_epoch: trained.best_epoch,
        epochs: trained.epochs,
        epoch_seconds: epoch_seconds(&trained.history),
        trained_on: crate::train::log::trained_on(
            trained.history.iter().map(|r| r.trained_on.as_str()),
        ),
        wall_seconds: 0.0,
        refinement,
        closed_loop: String::new(),
        paths,
    })
}

/// Closed-loop data for `job` (docs/usage.md "scale", `--closed-loop`): the job's own
/// round-0 model (`<name>.round0`, the job's config) compensates the second half of the
/// recipe's sessions as they are recorded again (into `models/<name>.closed/`, kept when
/// complete; [`record_closed_loop`]). Returns the training set and what happened in
/// words.
fn closed_loop_sources(
    device: &Device,
    study: &Study,
    config: &RunConfig,
    job: &ScaleJob,
    sources: &DataSources,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<(DataSources, String)> {
    let name = format!("{}.round0", job.name());
    let round = ClosedLoopRound {
        recipe: &study.recipe,
        minutes: study.recording_minutes,
        machine_seed: study.machine_seed,
        every: study.every,
        files: ModelFiles::named(&out.join("models"), &name, true),
        name,
        dir: out.join("models").join(format!("{}.closed", job.name())),
    };
    let (union, how) = record_closed_loop(device, &round, config, sources, reporter)?;
    Ok((union, format!("{how}; {}", round.training_set("the job"))))
}

/// Every held-out session of the study with `model` in the loop: each path's scores
/// (`test`: the model's test metrics, pooled per path; empty where not measured), with
/// the open-loop diagnosis.
fn held_out_scores(
    device: &Device,
    study: &Study,
    model: &mut LoopModel,
    test: &[TestMetrics],
    sources: &DataSources,
    reporter: &mut dyn Reporter,
) -> Result<Vec<PathScore>> {
    let name = model.name.clone();
    let mut paths = Vec::new();
    for k in 0..study.scored_sessions() {
        let options = SessionOptions {
            open_loop: true,
            ..SessionOptions::rows(k)
        };
        let session = held_out_session(
            device,
            std::slice::from_mut(model),
            sources,
            &study.held_out(),
            options,
            reporter,
        )?;
        for p in PathKind::ALL {
            let mut score = path_score(p.name(), test, &session.rows, &name)?;
            score.session = k;
            if let Some(o) = session.open_loop.iter().find(|o| o.path == p.name()) {
                score.open_loop = [o.miss.position.mean, o.miss.attitude.mean];
                score.replayed = [o.replayed.position.mean, o.replayed.attitude.mean];
            }
            paths.push(score);
        }
    }
    Ok(paths)
}

/// The record of `model`'s seed ensemble at `minutes` per path.
fn ensemble_record_path(out: &Path, model: Variant, minutes: f64) -> PathBuf {
    out.join("models")
        .join(format!("{}.min{minutes}.ensemble.job.toml", model.name()))
}

/// Scores the seed ensemble of every model and size whose seeds (two or more) have all
/// finished and that has no ensemble record yet: the controller averages the seeds' predictions (the
/// refined weights in a study that refines). Its test block is not scored (NaN).
fn score_ensembles(
    device: &Device,
    study: &Study,
    sources: &DataSources,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let jobs = study.jobs()?;
    for (variant, minutes) in study
        .models
        .iter()
        .filter_map(|m| Variant::parse(m))
        .flat_map(|v| study.sizes.iter().map(move |&m| (v, m)))
    {
        let record = ensemble_record_path(out, variant, minutes);
        let members: Vec<&ScaleJob> = jobs
            .iter()
            .filter(|j| j.variant == variant && j.minutes == minutes)
            .collect();
        // One seed is no ensemble; a call with fewer seeds than the folder will have
        // leaves it to the call with all of them.
        if members.len() < 2
            || record.exists()
            || members.iter().any(|j| !j.record_path(out).exists())
        {
            continue;
        }
        let started = Instant::now();
        let model = format!("{}-ensemble", variant.name());
        let seeds: Vec<String> = members.iter().map(|j| j.seed.to_string()).collect();
        reporter.note(&format!(
            "== {model} on {minutes} min per path: the mean of seeds {}",
            seeds.join(", ")
        ));
        let checkpoints = members
            .iter()
            .map(|j| {
                let files = j.files(out);
                Checkpoint::load(if study.refine {
                    &files.refined
                } else {
                    &files.core
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let first = ScaleRecord::load(&members[0].record_path(out))?;
        let mut in_loop = ensemble(device, &model, &checkpoints)?;
        let paths = held_out_scores(device, study, &mut in_loop, &[], sources, reporter)?;
        let name = format!("{}.min{minutes}.ensemble", variant.name());
        let done = ScaleRecord {
            name,
            model,
            seed: 0,
            minutes,
            train_windows: first.train_windows,
            best_val: f64::NAN,
            best_epoch: 0,
            epochs: 0,
            epoch_seconds: f64::NAN,
            trained_on: format!("the mean of seeds {}", seeds.join(", ")),
            wall_seconds: started.elapsed().as_secs_f64(),
            refinement: String::new(),
            closed_loop: String::new(),
            paths,
        };
        write_toml(&done, &record)?;
        write_summary(study, out, reporter)?;
    }
    Ok(())
}

/// One path's scores from the test metrics (pooled per path, [`by_path`]) and the
/// session's Table V rows.
fn path_score(
    path: &str,
    test: &[TestMetrics],
    rows: &[TableVRow],
    model: &str,
) -> Result<PathScore> {
    let truth = |stage: &str, who: Option<&str>| -> Result<[f64; 2]> {
        rows.iter()
            .find(|r| r.trajectory == path && r.stage == stage && who.is_none_or(|m| r.model == m))
            .map(|r| [r.truth.position.mean, r.truth.attitude.mean])
            .ok_or_else(|| Error::Invalid(format!("no {stage} row for {path} in the session")))
    };
    let recorded = test.iter().find(|t| recording_path(&t.recording) == path);
    Ok(PathScore {
        path: path.into(),
        session: 0,
        test_windows: recorded.map_or(0, |t| t.model.count),
        test_mae: recorded.map_or([f64::NAN; 2], |t| [t.model.pos_mae, t.model.att_mae]),
        initial: truth("initial", None)?,
        calibrated: truth("calibrated", None)?,
        oracle: truth("oracle", None)?,
        compensated: truth("compensated", Some(model))?,
        open_loop: unmeasured(),
        replayed: unmeasured(),
    })
}

/// The records of every job finished in the folder (by this study or an earlier call
/// with other sizes, seeds or models), by size, seed and name.
fn records(out: &Path) -> Result<Vec<ScaleRecord>> {
    let dir = out.join("models");
    let mut records = Vec::new();
    for entry in std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))? {
        let path = entry.map_err(|e| Error::io(&dir, e))?.path();
        if path.to_string_lossy().ends_with(".job.toml") {
            records.push(ScaleRecord::load(&path)?);
        }
    }
    records.sort_by(|a, b| {
        (a.minutes, a.seed, &a.name)
            .partial_cmp(&(b.minutes, b.seed, &b.name))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    Ok(records)
}

/// One point of the summary: a model at a size on a path, over its seeds.
struct Point {
    model: String,
    minutes: f64,
    path: String,
    train_windows: usize,
    seeds: usize,
    sessions: usize,
    pos_removed: Spread,
    att_removed: Spread,
    test_pos: Spread,
    test_att: Spread,
    oracle_removed: [f64; 2],
    /// Mean true error left by compensation, position µm and attitude mdeg.
    compensated: [Spread; 2],
    /// Open-loop prediction error along the uncompensated runs (NaN where unmeasured).
    open_loop: [Spread; 2],
    /// Mean true error with the open-loop predictions fed forward (NaN where unmeasured).
    replayed: [Spread; 2],
    /// Mean true error under the calibrated controller and the oracle.
    calibrated: [f64; 2],
    oracle: [f64; 2],
}

/// The summary's points, model by model (those of `order` first, in its order), each by
/// size.
fn points(records: &[ScaleRecord], order: &[String]) -> Vec<Point> {
    let mut keys: Vec<(String, f64)> = Vec::new();
    for r in records {
        if !keys.iter().any(|k| k.0 == r.model && k.1 == r.minutes) {
            keys.push((r.model.clone(), r.minutes));
        }
    }
    let first = |m: &str| order.iter().position(|o| o == m).unwrap_or(order.len());
    keys.sort_by(|a, b| {
        (first(&a.0), &a.0, a.1)
            .partial_cmp(&(first(&b.0), &b.0, b.1))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut out = Vec::new();
    for (model, minutes) in keys {
        let group: Vec<&ScaleRecord> = records
            .iter()
            .filter(|r| r.model == model && r.minutes == minutes)
            .collect();
        for path in PathKind::ALL.map(PathKind::name) {
            // Every held-out session of every seed; the test block once per seed.
            let scores: Vec<&PathScore> = group
                .iter()
                .flat_map(|r| r.paths.iter().filter(|p| p.path == path))
                .collect();
            let tests: Vec<&PathScore> = group
                .iter()
                .filter_map(|r| r.paths.iter().find(|p| p.path == path))
                .collect();
            let each = |of: &[&PathScore], f: &dyn Fn(&PathScore) -> f64| {
                Spread::of(&of.iter().map(|s| f(s)).collect::<Vec<_>>())
            };
            let sessions = {
                let mut k: Vec<usize> = scores.iter().map(|s| s.session).collect();
                k.sort_unstable();
                k.dedup();
                k.len()
            };
            out.push(Point {
                model: model.clone(),
                minutes,
                path: path.into(),
                train_windows: group[0].train_windows,
                seeds: group.len(),
                sessions,
                pos_removed: each(&scores, &|s| s.removed(s.compensated)[0]),
                att_removed: each(&scores, &|s| s.removed(s.compensated)[1]),
                test_pos: each(&tests, &|s| s.test_mae[0]),
                test_att: each(&tests, &|s| s.test_mae[1]),
                oracle_removed: [0, 1].map(|i| each(&scores, &|s| s.removed(s.oracle)[i]).mean),
                compensated: [0, 1].map(|i| each(&scores, &|s| s.compensated[i])),
                open_loop: [0, 1].map(|i| each(&scores, &|s| s.open_loop[i])),
                replayed: [0, 1].map(|i| each(&scores, &|s| s.replayed[i])),
                calibrated: [0, 1].map(|i| each(&scores, &|s| s.calibrated[i]).mean),
                oracle: [0, 1].map(|i| each(&scores, &|s| s.oracle[i]).mean),
            });
        }
    }
    out
}

/// `scale.csv` (a row per job, session and path), `scale_summary.csv` (mean and SD over
/// seeds and test sessions per model, size and path), `scale.md`, `scale.png` and, with a
/// validation session, `scale_validation.csv`, from every finished job.
pub fn write_summary(study: &Study, out: &Path, reporter: &mut dyn Reporter) -> Result<()> {
    let all = records(out)?;
    if all.is_empty() {
        return Ok(());
    }
    let validation = study.validation_index();
    // The tables and the plot score the test sessions only.
    let records: Vec<ScaleRecord> = all
        .iter()
        .map(|r| {
            let mut r = r.clone();
            r.paths.retain(|p| Some(p.session) != validation);
            r
        })
        .collect();
    let recommended = recommendations(&all, validation);
    let f = |v: f64| format!("{v:.3}");
    let rows: Vec<Vec<String>> = all
        .iter()
        .flat_map(|r| {
            r.paths.iter().map(move |p| {
                let [pr, ar] = p.removed(p.compensated);
                vec![
                    r.model.clone(),
                    r.minutes.to_string(),
                    r.seed.to_string(),
                    r.train_windows.to_string(),
                    r.epochs.to_string(),
                    p.path.clone(),
                    p.session.to_string(),
                    p.test_windows.to_string(),
                    f(p.test_mae[0]),
                    f(p.test_mae[1]),
                    f(p.calibrated[0]),
                    f(p.oracle[0]),
                    f(p.compensated[0]),
                    f(p.calibrated[1]),
                    f(p.oracle[1]),
                    f(p.compensated[1]),
                    f(pr),
                    f(ar),
                    f(p.open_loop[0]),
                    f(p.open_loop[1]),
                    f(p.replayed[0]),
                    f(p.replayed[1]),
                    if Some(p.session) == validation {
                        "validation"
                    } else {
                        "test"
                    }
                    .into(),
                ]
            })
        })
        .collect();
    let jobs_csv = csv_text(
        "model,minutes,seed,train_windows,epochs,path,held_out_session,test_windows,test_pos_mae_um,\
         test_att_mae_mdeg,calibrated_pos_um,oracle_pos_um,compensated_pos_um,\
         calibrated_att_mdeg,oracle_att_mdeg,compensated_att_mdeg,pos_removed_pct,\
         att_removed_pct,open_loop_pos_um,open_loop_att_mdeg,replayed_pos_um,\
         replayed_att_mdeg,session_role",
        rows,
    );
    let points = points(&records, &study.models);
    let sd = |s: &Spread| [f(s.mean), f(s.sd)];
    let summary_rows = points
        .iter()
        .map(|p| {
            let mut row = vec![
                p.model.clone(),
                p.minutes.to_string(),
                p.train_windows.to_string(),
                p.seeds.to_string(),
                p.sessions.to_string(),
                p.path.clone(),
            ];
            for s in [&p.pos_removed, &p.att_removed, &p.test_pos, &p.test_att] {
                row.extend(sd(s));
            }
            row.extend(p.oracle_removed.map(f));
            for s in p.compensated.iter().chain(&p.open_loop) {
                row.extend(sd(s));
            }
            row
        })
        .collect();
    let summary_csv = csv_text(
        "model,minutes,train_windows,seeds,held_out_sessions,path,pos_removed_mean_pct,\
         pos_removed_sd_pct,\
         att_removed_mean_pct,att_removed_sd_pct,test_pos_mae_mean_um,test_pos_mae_sd_um,\
         test_att_mae_mean_mdeg,test_att_mae_sd_mdeg,oracle_pos_removed_pct,\
         oracle_att_removed_pct,compensated_pos_mean_um,compensated_pos_sd_um,\
         compensated_att_mean_mdeg,compensated_att_sd_mdeg,open_loop_pos_mean_um,\
         open_loop_pos_sd_um,open_loop_att_mean_mdeg,open_loop_att_sd_mdeg",
        summary_rows,
    );
    let mut batch = crate::atomic::Batch::new();
    let io = |p: &Path, e: std::io::Error| Error::io(p, e);
    let mut texts = vec![
        ("scale.csv", jobs_csv),
        ("scale_summary.csv", summary_csv),
        (
            "scale.md",
            markdown(study, (&records, &all), &points, &recommended),
        ),
    ];
    if validation.is_some() {
        texts.push(("scale_validation.csv", validation_csv(&recommended)));
    }
    for (name, text) in texts {
        let path = out.join(name);
        batch
            .add(&path, text.as_bytes())
            .map_err(|e| io(&path, e))?;
    }
    let png = out.join("scale.png");
    batch.add_with(&png, |tmp| {
        plot::draw(tmp, &panels(&points), 2, 3, (1500, 900))
    })?;
    batch.commit().map_err(|e| io(out, e))?;
    for (minutes, r) in &recommended {
        reporter.note(&format!("at {minutes} min per path: {}", r.sentence()));
    }
    reporter.note(&format!(
        "summary of {} finished jobs: {}",
        records.len(),
        out.join("scale.md").display()
    ));
    Ok(())
}

/// The recommendation at each size from the validation session's scores of every record
/// (each seed a run of its model; a seed ensemble a model of its own), by size; empty
/// without a validation session.
fn recommendations(
    records: &[ScaleRecord],
    validation: Option<usize>,
) -> Vec<(f64, Recommendation)> {
    let Some(k) = validation else {
        return Vec::new();
    };
    let mut sizes: Vec<f64> = records.iter().map(|r| r.minutes).collect();
    sizes.sort_by(f64::total_cmp);
    sizes.dedup();
    sizes
        .into_iter()
        .map(|minutes| {
            let runs: Vec<ValidationRun> = records
                .iter()
                .filter(|r| r.minutes == minutes)
                .map(|r| ValidationRun {
                    model: r.model.clone(),
                    run: r.name.clone(),
                    shares: r
                        .paths
                        .iter()
                        .filter(|p| p.session == k)
                        .map(|p| p.removed(p.compensated))
                        .collect(),
                })
                .collect();
            (minutes, recommend_runs(&runs))
        })
        .collect()
}

/// `scale_validation.csv`: every model's score on the validation session, by size.
fn validation_csv(recommended: &[(f64, Recommendation)]) -> String {
    let f = |v: f64| format!("{v:.3}");
    let rows = recommended
        .iter()
        .flat_map(|(minutes, r)| {
            r.scores.iter().enumerate().map(move |(i, v)| {
                vec![
                    minutes.to_string(),
                    v.model.clone(),
                    v.seeds.to_string(),
                    f(v.position),
                    f(v.attitude),
                    f(v.score()),
                    (Some(i) == r.best).to_string(),
                    v.best_seed.clone(),
                ]
            })
        })
        .collect();
    csv_text(
        "minutes,model,seeds,pos_removed_pct,att_removed_pct,score,recommended,best_run",
        rows,
    )
}

/// The plot: position error removed on each held-out path, Hilbert's attitude, and the
/// test MAE over the three training paths, against training windows (log axis); the
/// calibration (0 %), the oracle and on Hilbert the paper's figure as lines.
fn panels(points: &[Point]) -> Vec<Panel> {
    let mut models: Vec<&str> = Vec::new();
    for p in points {
        if !models.contains(&p.model.as_str()) {
            models.push(&p.model);
        }
    }
    let span = points
        .iter()
        .map(|p| p.train_windows as f64)
        .fold((f64::MAX, 0f64), |(a, b), w| (a.min(w), b.max(w)));
    let level = |name: &str, y: f64| Series::new(name, vec![(span.0, y), (span.1, y)]);
    let removed = |path: &str, att: bool| {
        let at = |p: &&Point| p.path == path;
        let mut series: Vec<Series> = models
            .iter()
            .map(|&m| {
                let pts = points
                    .iter()
                    .filter(|p| at(p) && p.model == m)
                    .map(|p| {
                        let s = if att { &p.att_removed } else { &p.pos_removed };
                        (p.train_windows as f64, s.mean)
                    })
                    .collect();
                Series::new(m, pts)
            })
            .collect();
        let oracle = points
            .iter()
            .filter(at)
            .map(|p| p.oracle_removed[usize::from(att)]);
        let n = points.iter().filter(at).count().max(1) as f64;
        series.push(level("oracle", oracle.sum::<f64>() / n));
        series.push(level("calibration", 0.0));
        if path == PathKind::Hilbert.name() {
            series.push(level("paper", PAPER_HILBERT_REMOVED[usize::from(att)]));
        }
        Panel {
            title: format!(
                "{path}: {} error removed",
                if att { "attitude" } else { "position" }
            ),
            x_label: "training windows".into(),
            y_label: "% of calibrated error".into(),
            series,
            log_x: true,
            ..Panel::default()
        }
    };
    let mut out: Vec<Panel> = PathKind::ALL
        .iter()
        .map(|p| removed(p.name(), false))
        .collect();
    out.push(removed(PathKind::Hilbert.name(), true));
    let test = models
        .iter()
        .map(|&m| {
            let mut by_size: Vec<(f64, f64, usize)> = Vec::new();
            for p in points
                .iter()
                .filter(|p| p.model == m && p.test_pos.mean.is_finite())
            {
                match by_size.iter_mut().find(|s| s.0 == p.train_windows as f64) {
                    Some(s) => (s.1, s.2) = (s.1 + p.test_pos.mean, s.2 + 1),
                    None => by_size.push((p.train_windows as f64, p.test_pos.mean, 1)),
                }
            }
            Series::new(m, by_size.iter().map(|s| (s.0, s.1 / s.2 as f64)).collect())
        })
        .collect();
    out.push(Panel {
        title: "test split: position MAE (mean of 3 paths)".into(),
        x_label: "training windows".into(),
        y_label: "µm".into(),
        series: test,
        log_x: true,
        ..Panel::default()
    });
    out
}

/// `scale.md`: what ran, then per path a table of error removed and test MAE per model
/// and size, and the held-out sessions one by one.
fn markdown(
    study: &Study,
    (records, all): (&[ScaleRecord], &[ScaleRecord]),
    points: &[Point],
    recommended: &[(f64, Recommendation)],
) -> String {
    let minutes = study.recording_minutes;
    let ensembles = records
        .iter()
        .filter(|r| r.name.ends_with(".ensemble"))
        .count();
    let recipe = &study.recipe;
    let recorded = if recipe.sessions == 1 {
        format!("Recordings of {minutes} min per path in one session")
    } else {
        format!(
            "Recordings of {minutes} min per path in {} sessions of {} min (each a day of its \
             own starting cold, placements {}{}; docs/twin.md \"Sessions\")",
            recipe.sessions,
            minutes / recipe.sessions as f64,
            recipe.placement.name(),
            recipe.path_order.phrase()
        )
    };
    let held = study.held_out();
    let stage = if study.refine {
        "Core stage to early stopping, then refinement (Algorithm 2; the refined weights \
         kept where they lower the per-window validation loss); scored with the weights kept"
    } else {
        "Core stage to early stopping (no refinement)"
    };
    let sessions: Vec<String> = (0..study.scored_sessions())
        .map(|k| {
            let role = if Some(k) == study.validation_index() {
                " (**validation**: the model is chosen here; not in the tables)"
            } else {
                ""
            };
            format!(
                "  - session {}{role}: {}",
                k + 1,
                held.session(k).describe()
            )
        })
        .collect();
    let mut s = format!(
        "# Scaling study\n\n- {recorded}; a size of m minutes \
         trains on the first m/{minutes} of each recording's training block and stops early \
         on the first m/{minutes} of its validation block; every size is scored on the same \
         test blocks, those of the {minutes}-minute recordings\n- {stage}\n- Held-out sessions: {}, \
         {} min runs each, a prediction every {} ticks, scored against hidden truth:\n{}\n- Jobs \
         finished in this folder: {} (the last call's study: sizes {:?}, seeds {:?}, models \
         {}){}\n\nMean ± SD over seeds and held-out sessions. Removed: share of the calibrated \
         controller's mean true error removed by compensation; Left: the mean true error it \
         leaves. Open-loop: the mean distance of the model's predictions from the true \
         residual along the same held-out runs played uncompensated (the oracle's \
         correction; docs/shift/README.md \"Where the error goes\"). Test MAE: the model's on \
         the path's test block (µm / mdeg), over seeds. The paper's Table V (Hilbert): {} % / \
         {} %.\n",
        study.held_out_sessions,
        study.held_out_minutes,
        study.every,
        sessions.join("\n"),
        records.len() - ensembles,
        study.sizes,
        study.seeds,
        study.models.join(", "),
        if ensembles > 0 {
            format!(
                "\n- Seed ensembles scored: {ensembles} (`<model>-ensemble`: the controller \
                 averages the predictions of the model's seeds; mean ± SD over held-out \
                 sessions; its test block is not scored)"
            )
        } else {
            String::new()
        },
        PAPER_HILBERT_REMOVED[0],
        PAPER_HILBERT_REMOVED[1],
    );
    for path in PathKind::ALL.map(PathKind::name) {
        s.push_str(&format!(
            "\n## {path}\n\n| Model | Min/path | Train windows | Seeds × sessions | Pos. removed (%) | \
             Att. removed (%) | Test MAE pos (µm) | Test MAE att (mdeg) | Left pos (µm) | \
             Left att (mdeg) | Open-loop pos (µm) | Open-loop att (mdeg) |\n\
             |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
        ));
        let mut oracle = None;
        for p in points.iter().filter(|p| p.path == path) {
            s.push_str(&format!(
                "| {} | {} | {} | {} × {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                p.model,
                p.minutes,
                p.train_windows,
                p.seeds,
                p.sessions,
                p.pos_removed.text(1),
                p.att_removed.text(1),
                p.test_pos.text(2),
                p.test_att.text(2),
                p.compensated[0].text(1),
                p.compensated[1].text(1),
                p.open_loop[0].text(1),
                p.open_loop[1].text(1)
            ));
            oracle = Some(p.oracle_removed);
        }
        if let Some([pos, att]) = oracle {
            s.push_str(&format!(
                "| oracle (true residual) | | | | {pos:.1} | {att:.1} | | | | | | |\n"
            ));
        }
    }
    s.push_str(&recommendation_section(recommended, points));
    s.push_str(&where_it_goes(points));
    s.push_str(&by_session(all, study.validation_index()));
    s
}

/// `scale.md`'s recommended model at each size: every model's score on the validation
/// session, the choice, and what the chosen model does on the test sessions' Hilbert runs.
fn recommendation_section(recommended: &[(f64, Recommendation)], points: &[Point]) -> String {
    if recommended.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Recommended model\n\nAt each size, every model scored on the validation \
         session (never in the tables above): the share of the calibrated controller's mean \
         true error removed, position and attitude, each the mean over the four paths and \
         the model's seeds; the highest mean of the two is recommended \
         (`experiment::recommend`, as `evaluate` chooses).\n",
    );
    for (minutes, r) in recommended {
        s.push_str(&format!(
            "\n### {minutes} min per path\n\n{}\n{}",
            r.table(),
            r.sentence()
        ));
        let hilbert = r.model().and_then(|v| {
            points
                .iter()
                .find(|p| p.model == v.model && p.minutes == *minutes && p.path == "hilbert")
        });
        if let Some(p) = hilbert {
            s.push_str(&format!(
                " On the test sessions' Hilbert runs it removes {} % of the position and {} % \
                 of the attitude error (mean ± SD over {} seed(s) × {} session(s)).",
                p.pos_removed.text(1),
                p.att_removed.text(1),
                p.seeds,
                p.sessions
            ));
        }
        s.push('\n');
    }
    s
}

/// `scale.md`'s diagnosis: what compensation leaves on each held-out path, split into
/// the loop's own floor (the oracle's residual: the true residual fed back at a model's
/// rate and latency), the model's part (its open-loop predictions fed forward, less the
/// floor) and the feedback (the closed loop less the fed-forward run: the model's
/// corrections acting on its own inputs), mean over seeds and held-out sessions.
fn where_it_goes(points: &[Point]) -> String {
    let measured: Vec<&Point> = points
        .iter()
        .filter(|p| p.replayed[0].mean.is_finite())
        .collect();
    if measured.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Where the error goes\n\nMean true error (position µm / attitude mdeg) of the \
         held-out runs: calibrated; compensated in closed loop (what is left); and that left \
         error split into the loop's floor (the oracle's), the model's part (its open-loop \
         predictions fed forward as corrections, less the floor) and the feedback (closed \
         loop less fed forward). Open-loop miss: the mean distance of the predictions from \
         the true residual along the uncompensated run. Mean over seeds and held-out \
         sessions.\n\n| Path | Model | Min/path | Calibrated | Left (closed loop) | Floor \
         (oracle) | Model part | Feedback part | Open-loop miss | Left / miss |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let pair = |v: [f64; 2]| format!("{:.1} / {:.1}", v[0], v[1]);
    for p in measured {
        let left = [p.compensated[0].mean, p.compensated[1].mean];
        let replayed = [p.replayed[0].mean, p.replayed[1].mean];
        let miss = [p.open_loop[0].mean, p.open_loop[1].mean];
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} / {:.2} |\n",
            p.path,
            p.model,
            p.minutes,
            pair(p.calibrated),
            pair(left),
            pair(p.oracle),
            pair([0, 1].map(|i| replayed[i] - p.oracle[i])),
            pair([0, 1].map(|i| left[i] - replayed[i])),
            pair(miss),
            left[0] / miss[0],
            left[1] / miss[1],
        ));
    }
    s
}

/// `scale.md`'s last section: per path and held-out session, the calibrated error, what
/// the oracle removes, and each model and size's share removed (mean over seeds).
fn by_session(records: &[ScaleRecord], validation: Option<usize>) -> String {
    let sessions = records
        .iter()
        .flat_map(|r| r.paths.iter().map(|p| p.session))
        .max()
        .map_or(0, |k| k + 1);
    if sessions < 2 {
        return String::new();
    }
    let mut groups: Vec<(String, f64)> = Vec::new();
    for r in records {
        if !groups.iter().any(|g| g.0 == r.model && g.1 == r.minutes) {
            groups.push((r.model.clone(), r.minutes));
        }
    }
    let mut s = String::from(
        "\n## By held-out session\n\nPosition / attitude: the calibrated controller's mean \
         true error (µm / mdeg), then the share removed (%), mean over seeds.\n",
    );
    for path in PathKind::ALL.map(PathKind::name) {
        s.push_str(&format!("\n### {path}\n\n| | "));
        s.push_str(
            &(0..sessions)
                .map(|k| match Some(k) == validation {
                    true => format!("session {} (validation)", k + 1),
                    false => format!("session {}", k + 1),
                })
                .collect::<Vec<_>>()
                .join(" | "),
        );
        s.push_str(" |\n|---|");
        s.push_str(&"---:|".repeat(sessions));
        s.push('\n');
        let scores = |model: Option<&(String, f64)>, k: usize| -> Vec<&PathScore> {
            records
                .iter()
                .filter(|r| model.is_none_or(|g| r.model == g.0 && r.minutes == g.1))
                .flat_map(|r| r.paths.iter())
                .filter(|p| p.path == path && p.session == k)
                .collect()
        };
        let mean = |v: &[&PathScore], f: &dyn Fn(&PathScore) -> [f64; 2]| -> [f64; 2] {
            let n = v.len().max(1) as f64;
            [0, 1].map(|i| v.iter().map(|p| f(p)[i]).sum::<f64>() / n)
        };
        let cells = |f: &dyn Fn(&[&PathScore]) -> String, model: Option<&(String, f64)>| {
            (0..sessions)
                .map(|k| f(&scores(model, k)))
                .collect::<Vec<_>>()
                .join(" | ")
        };
        let pair = |v: [f64; 2], digits: usize| format!("{:.digits$} / {:.digits$}", v[0], v[1]);
        s.push_str(&format!(
            "| calibrated (µm / mdeg) | {} |\n",
            cells(&|v| pair(mean(v, &|p| p.calibrated), 1), None)
        ));
        s.push_str(&format!(
            "| oracle removed (%) | {} |\n",
            cells(&|v| pair(mean(v, &|p| p.removed(p.oracle)), 1), None)
        ));
        for g in &groups {
            s.push_str(&format!(
                "| {} at {} min (%) | {} |\n",
                g.0,
                g.1,
                cells(
                    &|v| pair(mean(v, &|p| p.removed(p.compensated)), 1),
                    Some(g)
                )
            ));
        }
    }
    s
}
