//! `iastgcn reproduce`: the paper's protocol on the twin, at any size, over several
//! training seeds. The work splits into independent jobs, one per model and seed; each
//! job trains (resuming from its state file after an interruption) and refines one model
//! and then writes a job record. Jobs can be spread over processes or machines with
//! `--shard k/n`; a final run without a shard finds every job done and writes the
//! report (Tables III and V per seed, and over seeds with the paired comparisons).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::demo::finish;
use super::evaluate::{HeldOutConfig, NamedModel};
use super::protocol::{
    existing_data, fit_model, record_data, ModelFiles, CALIBRATION_SEED, MACHINE_SEED,
    TRAINING_SEED,
};
use super::report::seeds::{seeded_name, Spread};
use super::report::Report;
use crate::error::{write_file, Error, Result};
use crate::gpu::Gpu;
use crate::model::{Checkpoint, Variant};
use crate::progress::Reporter;
use crate::train::{build_dataset, RunConfig};

/// What `iastgcn reproduce` runs: the run config of every model, the length of the
/// training recordings, the training seeds and the models.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Protocol {
    /// Length of each training recording, minutes.
    pub minutes: f64,
    /// Training seeds (`[train] seed` of each job).
    pub seeds: Vec<u64>,
    /// Models by name (docs/model.md), in the report's order.
    pub models: Vec<String>,
    /// The run config every model trains with (its variant and seed set per job).
    pub run: RunConfig,
}

impl Protocol {
    /// The paper's protocol: its model and training sizes (the default run config), three
    /// 135-minute training recordings (about 42k windows of 100 steps at stride 20, the
    /// paper's count), every model, seeds 1–3.
    pub fn paper() -> Protocol {
        Protocol {
            minutes: 135.0,
            seeds: vec![1, 2, 3],
            models: Variant::ALL.iter().map(|v| v.name().to_string()).collect(),
            run: RunConfig::default(),
        }
    }

    /// The jobs, seed by seed (every model of the first seed before the second seed's).
    pub fn jobs(&self) -> Result<Vec<Job>> {
        let variants = self
            .models
            .iter()
            .map(|m| {
                Variant::parse(m).ok_or_else(|| {
                    Error::Invalid(format!("unknown model {m:?} ({})", Variant::names()))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(self
            .seeds
            .iter()
            .flat_map(|&seed| variants.iter().map(move |&variant| Job { variant, seed }))
            .collect())
    }

    /// Checks sizes, seeds, models and the run config.
    pub fn validate(&self) -> Result<()> {
        if !(self.minutes.is_finite() && self.minutes > 0.0) {
            return Err(Error::Invalid(format!(
                "minutes: the training recordings must last a positive time, got {}",
                self.minutes
            )));
        }
        if self.seeds.is_empty() || self.models.is_empty() {
            return Err(Error::Invalid(
                "reproduce needs at least one seed and one model".into(),
            ));
        }
        for (i, s) in self.seeds.iter().enumerate() {
            if self.seeds[..i].contains(s) {
                return Err(Error::Invalid(format!("seeds: {s} is listed twice")));
            }
        }
        for (i, m) in self.models.iter().enumerate() {
            if self.models[..i].contains(m) {
                return Err(Error::Invalid(format!("models: {m} is listed twice")));
            }
        }
        self.jobs()?;
        self.run.validate().map_err(Error::Invalid)
    }

    /// The protocol with what may change between runs of one output folder cleared:
    /// where and on how many threads the steps run.
    fn comparable(&self) -> Protocol {
        let mut p = self.clone();
        p.run.train.backend.clear();
        p.run.train.threads = 0;
        p
    }
}

/// One model trained with one seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Job {
    /// The model.
    pub variant: Variant,
    /// Its `[train] seed`.
    pub seed: u64,
}

impl Job {
    /// `<model>.seed<k>`: the name of its files and of its rows in the tables.
    pub fn name(&self) -> String {
        seeded_name(self.variant.name(), self.seed)
    }

    /// Its files in the output folder `out`.
    pub fn files(&self, out: &Path) -> ModelFiles {
        let dir = out.join("models");
        ModelFiles {
            core: dir.join(format!("{}.core.safetensors", self.name())),
            refined: dir.join(format!("{}.safetensors", self.name())),
            resume: true,
        }
    }

    /// The record written when the job has finished.
    pub fn record_path(&self, out: &Path) -> PathBuf {
        out.join("models").join(format!("{}.job.toml", self.name()))
    }
}

/// One job of several processes: jobs `k − 1`, `k − 1 + n`, … of the list (1 ≤ k ≤ n).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shard {
    /// 1-based.
    pub index: usize,
    /// How many shards share the jobs.
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Shard, String> {
        let bad = || format!("--shard: expected k/n with 1 ≤ k ≤ n (e.g. 2/8), got {s:?}");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) = (
            k.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl Shard {
    /// Whether job number `i` (0-based) belongs to this shard.
    pub fn owns(&self, i: usize) -> bool {
        i % self.count == self.index - 1
    }
}

/// What a finished job left: read back by the final run to build the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    /// `<model>.seed<k>`.
    pub name: String,
    /// The model.
    pub model: String,
    /// The training seed.
    pub seed: u64,
    /// Best validation loss of the core stage (standardised).
    pub best_val: f64,
    /// Its epoch.
    pub best_epoch: usize,
    /// Core epochs run (over every resumption).
    pub epochs: usize,
    /// Mean core epoch time, s.
    pub epoch_seconds: f64,
    /// Where the core stage trained.
    pub trained_on: String,
    /// What refinement did.
    pub refinement: String,
    /// Wall time of the job in the run that finished it, s.
    pub wall_seconds: f64,
}

impl JobRecord {
    fn load(path: &Path) -> Result<JobRecord> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        toml::from_str(&text).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
    }
}

/// What one call did.
pub enum Outcome {
    /// Every job is done and the report is written.
    Report(Box<Report>),
    /// This call's share is done (or only the data was asked for); `done` of `total`
    /// jobs have finished so far.
    Partial {
        /// Jobs with a record.
        done: usize,
        /// Jobs in the protocol.
        total: usize,
    },
}

/// Writes `out/protocol.toml`, or checks that an earlier run of the folder used the same
/// protocol (only where the steps run may differ).
fn pin_protocol(protocol: &Protocol, out: &Path) -> Result<()> {
    let path = out.join("protocol.toml");
    if path.exists() {
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let earlier: Protocol = toml::from_str(&text)
            .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        if earlier.comparable() != protocol.comparable() {
            return Err(Error::Invalid(format!(
                "{}: this folder holds a run of another protocol (minutes, seeds, models or \
                 run config differ); use another --out, or the same options",
                path.display()
            )));
        }
        return Ok(());
    }
    let text = toml::to_string(protocol)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    write_file(&path, text.as_bytes())
}

fn clock(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// Runs the protocol into the folder `out` (`protocol.toml`, `data/`, `models/`, and the
/// report files once every job is done). With `shard`, runs only that shard's jobs and
/// stops; with `data_only`, stops once the data exist. Jobs with a record are skipped,
/// an interrupted job resumes from its state file.
pub fn reproduce(
    gpu: Arc<Gpu>,
    protocol: &Protocol,
    held_out: &HeldOutConfig,
    shard: Option<Shard>,
    data_only: bool,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<Outcome> {
    let began = Instant::now();
    protocol.validate()?;
    let jobs = protocol.jobs()?;
    std::fs::create_dir_all(out.join("models")).map_err(|e| Error::io(out, e))?;
    pin_protocol(protocol, out)?;
    reporter.note(&format!(
        "reproduce on {} → {}: {} models × {} seeds = {} jobs{}",
        gpu.info().name,
        out.display(),
        protocol.models.len(),
        protocol.seeds.len(),
        jobs.len(),
        shard.map_or(String::new(), |s| format!(
            ", shard {}/{} ({} jobs)",
            s.index,
            s.count,
            (0..jobs.len()).filter(|&i| s.owns(i)).count()
        ))
    ));

    let data_dir = out.join("data");
    let sources = match existing_data(&data_dir, protocol.minutes)? {
        Some(s) => {
            reporter.note(&format!(
                "using the data of an earlier run in {}",
                data_dir.display()
            ));
            s
        }
        None => record_data(&data_dir, protocol.minutes, reporter)?,
    };
    let done = |jobs: &[Job]| jobs.iter().filter(|j| j.record_path(out).exists()).count();
    if data_only {
        return Ok(Outcome::Partial {
            done: done(&jobs),
            total: jobs.len(),
        });
    }
    let (graph, data) = build_dataset(&sources, &protocol.run, None)?;
    for line in data.summary().lines() {
        reporter.note(line);
    }

    let mine: Vec<(usize, Job)> = jobs
        .iter()
        .copied()
        .enumerate()
        .filter(|(i, _)| shard.is_none_or(|s| s.owns(*i)))
        .collect();
    let todo: Vec<&(usize, Job)> = mine
        .iter()
        .filter(|(_, j)| !j.record_path(out).exists())
        .collect();
    reporter.note(&format!(
        "{} of this run's {} jobs already done",
        mine.len() - todo.len(),
        mine.len()
    ));
    let mut spent = Vec::new();
    for (n, (i, job)) in todo.iter().enumerate() {
        let eta = if spent.is_empty() {
            "unknown until a job finishes".to_string()
        } else {
            let mean = spent.iter().sum::<f64>() / spent.len() as f64;
            clock(mean * (todo.len() - n) as f64)
        };
        reporter.note(&format!(
            "== job {}/{} ({} of this run): {} seed {}; elapsed {}, ETA {eta}",
            i + 1,
            jobs.len(),
            n + 1,
            job.variant,
            job.seed,
            clock(began.elapsed().as_secs_f64())
        ));
        let started = Instant::now();
        let mut config = protocol.run.clone();
        config.model.variant = job.variant;
        config.train.seed = job.seed;
        let name = job.name();
        let fitted = fit_model(
            &gpu,
            &data,
            &graph,
            &config,
            &name,
            &job.files(out),
            reporter,
        )?;
        let wall = started.elapsed().as_secs_f64();
        let record = JobRecord {
            name: name.clone(),
            model: job.variant.name().into(),
            seed: job.seed,
            best_val: fitted.best_val,
            best_epoch: fitted.best_epoch,
            epochs: fitted.core.len(),
            epoch_seconds: fitted.model.epoch_seconds,
            trained_on: fitted.model.trained_on.clone(),
            refinement: fitted.verdict.clone(),
            wall_seconds: wall,
        };
        let text = toml::to_string(&record)
            .map_err(|e| Error::Invalid(format!("{name}: job record: {e}")))?;
        write_file(&job.record_path(out), text.as_bytes())?;
        spent.push(wall);
    }
    let finished = done(&jobs);
    if shard.is_some() || finished < jobs.len() {
        reporter.note(&format!(
            "{finished} of {} jobs done; once every shard has finished, `iastgcn reproduce` \
             with the same options and no --shard writes the report",
            jobs.len()
        ));
        return Ok(Outcome::Partial {
            done: finished,
            total: jobs.len(),
        });
    }
    report(
        gpu, protocol, &jobs, held_out, &sources, began, out, reporter,
    )
    .map(|r| Outcome::Report(Box::new(r)))
}

/// The report of a protocol whose jobs are all done.
#[allow(clippy::too_many_arguments)]
fn report(
    gpu: Arc<Gpu>,
    protocol: &Protocol,
    jobs: &[Job],
    held_out: &HeldOutConfig,
    sources: &crate::data::DataSources,
    began: Instant,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<Report> {
    reporter.note("== every job done: Tables III and V, report");
    let mut records = Vec::new();
    let mut models = Vec::new();
    let mut histories = Vec::new();
    for job in jobs {
        let record = JobRecord::load(&job.record_path(out))?;
        let files = job.files(out);
        models.push(NamedModel {
            name: record.name.clone(),
            checkpoint: Checkpoint::load(&files.refined)?,
            epoch_seconds: record.epoch_seconds,
            trained_on: record.trained_on.clone(),
        });
        // The learning curves of the first seed (one panel per model).
        if job.seed == protocol.seeds[0] {
            let log = crate::train::sibling(&files.core, ".log.csv");
            histories.push((record.name.clone(), crate::train::log::read_csv(&log)?));
        }
        records.push(record);
    }
    let run = &protocol.run;
    let seeds: Vec<String> = protocol.seeds.iter().map(u64::to_string).collect();
    let setup = vec![
        format!(
            "protocol: {} (T = {}, C = {}, L = {}, batch {}, at most {} epochs, patience {}); \
             models {}; training seeds {}",
            out.join("protocol.toml").display(),
            run.model.window,
            run.model.channels,
            run.model.blocks,
            run.train.batch,
            run.train.max_epochs,
            run.train.patience,
            protocol.models.join(", "),
            seeds.join(", ")
        ),
        format!(
            "data: machine {MACHINE_SEED}; calibration set at rest on a cold machine (seed \
             {CALIBRATION_SEED}); one training session under the calibrated controller: grid, \
             fermat, hilbert, {} min each, seeds {TRAINING_SEED}–{}; a separate held-out session: \
             {} min of warm-up, then every path turned or reversed on the part, plus the \
             rosette, {} min each, seeds from {}; prediction every {} ticks",
            protocol.minutes,
            TRAINING_SEED + 2,
            held_out.warm_up_minutes,
            held_out.minutes,
            held_out.seed,
            held_out.every
        ),
        "split: contiguous 70/20/10 blocks per recording (leakage-free); every seed sees the same split".into(),
        format!(
            "wall time of the jobs (summed over the runs that finished them): {}",
            clock(records.iter().map(|r| r.wall_seconds).sum())
        ),
    ];
    let report = Report {
        title: "IASTGCN on the digital twin — reproduction of the paper's protocol".into(),
        adapter: gpu.info().name.clone(),
        setup,
        histories,
        sections: vec![(
            "Core training over seeds".into(),
            training_table(protocol, &records),
        )],
        ..Report::default()
    };
    finish(
        &gpu, report, &models, sources, run, held_out, began, out, reporter,
    )
}

/// Best validation loss, its epoch and the epochs run per model, over seeds.
fn training_table(protocol: &Protocol, records: &[JobRecord]) -> String {
    let mut out = String::from(
        "Core stage per model over its seeds (mean ± sample SD): the best validation loss \
         (standardised, eq. 39's data term), the epoch it was reached in, the epochs run \
         (early stopping), and the mean epoch time.\n\n\
         | Model | Seeds | Best validation loss | Best epoch | Epochs | s / epoch |\n\
         |---|---:|---:|---:|---:|---:|\n",
    );
    for model in &protocol.models {
        let of: Vec<&JobRecord> = records.iter().filter(|r| &r.model == model).collect();
        let spread = |pick: fn(&JobRecord) -> f64| {
            let s = Spread::of(&of.iter().map(|r| pick(r)).collect::<Vec<_>>());
            (s.mean, s.sd)
        };
        let (v, vs) = spread(|r| r.best_val);
        let (b, bs) = spread(|r| r.best_epoch as f64);
        let (e, es) = spread(|r| r.epochs as f64);
        let (t, _) = spread(|r| r.epoch_seconds);
        out.push_str(&format!(
            "| {model} | {} | {v:.4} ± {vs:.4} | {b:.1} ± {bs:.1} | {e:.1} ± {es:.1} | {t:.3} |\n",
            of.len()
        ));
    }
    out
}
