//! `iastgcn reproduce`: the paper's protocol on the twin, at any size, over several
//! training seeds. The work splits into independent jobs, one per model and seed; each
//! job trains (resuming from its state file after an interruption) and refines one model
//! and then writes a job record. Jobs can be spread over processes or machines with
//! `--shard k/n`; a final run without a shard finds every job done and writes the
//! report (Tables III and V per seed, and over seeds with the paired comparisons).

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::evaluate::{tables, HeldOutConfig, NamedModel};
use super::jobs::{clock, pin_toml, training_table, write_toml, JobRecord, Shard};
use super::protocol::{
    check_closed_loop_sessions, check_seeds, existing_data, fit_model, record_closed_loop,
    record_data, sessions_setting, train_core, ClosedLoopRound, ModelFiles, CALIBRATION_SEED,
    MACHINE_SEED, TRAINING_SEED,
};
use super::report::curve::CurvePoint;
use super::report::seeds::{seeded_name, Spread};
use super::report::{self, Report};
use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Checkpoint, Variant};
use crate::progress::Reporter;
use crate::train::{build_dataset, RunConfig};
use crate::twin::Recipe;

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
    /// Shares of the training windows (each in (0, 1)) at which the learning curve's
    /// models are trained again, core stage only, for every seed.
    #[serde(default)]
    pub fractions: Vec<f64>,
    /// The learning curve's models.
    #[serde(default)]
    pub curve_models: Vec<String>,
    /// The twin machine (seed of its geometric and non-geometric errors) the data and
    /// the held-out session come from. One folder holds one machine; spread over
    /// machines comes from several folders merged (`reproduce --merge`).
    #[serde(default = "default_machine")]
    pub machine_seed: u64,
    /// How the training set is recorded: the minutes per path in one session, or split
    /// over several (docs/twin.md "Sessions").
    #[serde(default)]
    pub recipe: Recipe,
    /// Closed-loop training data (docs/usage.md "`reproduce`"): in the data stage a
    /// round-0 IASTGCN (the first seed, core stage) trained on the first half of the
    /// recipe's sessions compensates the other half as they are recorded again, at the
    /// held-out sessions' prediction rate, and every job trains on the first half open
    /// loop and the rest closed loop. Needs 2 sessions or more.
    #[serde(default)]
    pub closed_loop: bool,
}

fn default_machine() -> u64 {
    MACHINE_SEED
}

impl Protocol {
    /// The paper's protocol: its model and training sizes (the default run config), three
    /// 135-minute training recordings (about 42k windows of 100 steps at stride 20, the
    /// paper's count), every model, seeds 1–3; the learning curve of IASTGCN and T-GCN
    /// (the best baseline on the twin so far, docs/results.md) at 25 % and 50 %.
    pub fn paper() -> Protocol {
        Protocol {
            minutes: 135.0,
            seeds: vec![1, 2, 3],
            models: Variant::ALL.iter().map(|v| v.name().to_string()).collect(),
            run: RunConfig::default(),
            fractions: vec![0.25, 0.5],
            curve_models: vec!["iastgcn".into(), "tgcn".into()],
            machine_seed: MACHINE_SEED,
            recipe: Recipe::SINGLE,
            closed_loop: false,
        }
    }

    /// The jobs: the models of the tables seed by seed (every model of the first seed
    /// before the second seed's), then the learning curve's, share by share.
    pub fn jobs(&self) -> Result<Vec<Job>> {
        let parse = |names: &[String]| {
            names
                .iter()
                .map(|m| {
                    Variant::parse(m).ok_or_else(|| {
                        Error::Invalid(format!("unknown model {m:?} ({})", Variant::names()))
                    })
                })
                .collect::<Result<Vec<_>>>()
        };
        let (variants, curve) = (parse(&self.models)?, parse(&self.curve_models)?);
        let mut jobs: Vec<Job> = Vec::new();
        for &seed in &self.seeds {
            jobs.extend(variants.iter().map(|&variant| Job {
                variant,
                seed,
                fraction: 1.0,
            }));
        }
        for &fraction in &self.fractions {
            for &seed in &self.seeds {
                jobs.extend(curve.iter().map(|&variant| Job {
                    variant,
                    seed,
                    fraction,
                }));
            }
        }
        Ok(jobs)
    }

    /// Checks sizes, seeds, models and the run config.
    pub fn validate(&self) -> Result<()> {
        let seconds = self.minutes * 60.0;
        if !(seconds.is_finite() && seconds > 0.0 && seconds <= crate::data::MAX_RUN_SECONDS) {
            return Err(Error::Invalid(format!(
                "minutes: a training recording lasts more than 0 and at most {} min, got {}",
                crate::data::MAX_RUN_SECONDS / 60.0,
                self.minutes
            )));
        }
        self.recipe
            .validate(self.minutes)
            .map_err(sessions_setting)?;
        if self.closed_loop {
            check_closed_loop_sessions(self.recipe.sessions, "")?;
        }
        check_seeds(&self.seeds)?;
        if self.models.is_empty() {
            return Err(Error::Invalid("reproduce needs at least one model".into()));
        }
        for (field, list) in [
            ("models", &self.models),
            ("curve models", &self.curve_models),
        ] {
            for (i, m) in list.iter().enumerate() {
                if list[..i].contains(m) {
                    return Err(Error::Invalid(format!("{field}: {m} is listed twice")));
                }
            }
        }
        for (i, f) in self.fractions.iter().enumerate() {
            if !(*f > 0.0 && *f < 1.0) || self.fractions[..i].contains(f) {
                return Err(Error::Invalid(format!(
                    "fractions: {f} must be in (0, 1) and listed once (the full set is \
                     the tables' models)"
                )));
            }
        }
        if !self.fractions.is_empty() && self.curve_models.is_empty() {
            return Err(Error::Invalid(
                "fractions given but no curve models to train at them".into(),
            ));
        }
        self.jobs()?;
        self.run.validate().map_err(Error::Invalid)
    }

    /// Whether `other` is this protocol on another twin machine (or the same): every
    /// setting but the machine and where the steps run agrees.
    pub fn same_but_machine(&self, other: &Protocol) -> bool {
        let (mut a, mut b) = (self.comparable(), other.comparable());
        a.machine_seed = 0;
        b.machine_seed = 0;
        a == b
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

/// One model trained with one seed on a share of the training windows: the whole set
/// for the tables' models (trained, refined, evaluated), less for the learning curve's
/// (core stage only, scored on the validation and test splits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Job {
    /// The model.
    pub variant: Variant,
    /// Its `[train] seed`.
    pub seed: u64,
    /// Share of the training windows (1 for the tables' models).
    pub fraction: f64,
}

impl Job {
    /// Whether it is one of the learning curve's jobs.
    pub fn is_curve(&self) -> bool {
        self.fraction < 1.0
    }

    /// `<model>.seed<k>` (the name of its files and of its rows in the tables), with
    /// `.train<percent>` for the learning curve's jobs.
    pub fn name(&self) -> String {
        let name = seeded_name(self.variant.name(), self.seed);
        if self.is_curve() {
            format!("{name}.train{}", (100.0 * self.fraction).round())
        } else {
            name
        }
    }

    fn dir(&self, out: &Path) -> PathBuf {
        if self.is_curve() {
            out.join("models").join("curve")
        } else {
            out.join("models")
        }
    }

    /// Its files in the output folder `out` (the learning curve's in `models/curve/`).
    pub fn files(&self, out: &Path) -> ModelFiles {
        ModelFiles::named(&self.dir(out), &self.name(), true)
    }

    /// The record written when the job has finished.
    pub fn record_path(&self, out: &Path) -> PathBuf {
        self.dir(out).join(format!("{}.job.toml", self.name()))
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
    pin_toml(
        protocol,
        &out.join("protocol.toml"),
        |a, b| a.comparable() == b.comparable(),
        "this folder holds a run of another protocol (minutes, seeds, models or run config \
         differ); use another output folder, or the same options",
    )
}

/// Runs the protocol into the folder `out` (`protocol.toml`, `data/`, `models/`, and the
/// report files once every job is done). With `shard`, runs only that shard's jobs and
/// stops; with `data_only`, stops once the data exist. Jobs with a record are skipped,
/// an interrupted job resumes from its state file.
pub fn reproduce(
    device: Device,
    protocol: &Protocol,
    held_out: &HeldOutConfig,
    shard: Option<Shard>,
    data_only: bool,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<Outcome> {
    let began = Instant::now();
    protocol.validate()?;
    held_out.validate()?;
    let jobs = protocol.jobs()?;
    std::fs::create_dir_all(out.join("models")).map_err(|e| Error::io(out, e))?;
    pin_protocol(protocol, out)?;
    reporter.note(&format!(
        "reproduce on {} → {}: twin machine {}, {} models × {} seeds = {} jobs{}",
        device.name(),
        out.display(),
        protocol.machine_seed,
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
    let sources = match existing_data(
        &data_dir,
        protocol.minutes,
        protocol.machine_seed,
        &protocol.recipe,
    )? {
        Some(s) => {
            reporter.note(&format!(
                "using the data of an earlier run in {}",
                data_dir.display()
            ));
            s
        }
        None => record_data(
            &data_dir,
            protocol.minutes,
            protocol.machine_seed,
            &protocol.recipe,
            reporter,
        )?,
    };
    // Closed-loop data belong to the data stage: every later call (a shard, the final
    // report) finds the round-0 model finished and its recordings complete.
    let (sources, closed_loop) = if protocol.closed_loop {
        let seed = protocol.seeds[0];
        let mut c = protocol.run.clone();
        c.model.variant = Variant::Iastgcn;
        c.train.seed = seed;
        let name = format!("{}.round0", seeded_name(Variant::Iastgcn.name(), seed));
        let round = ClosedLoopRound {
            recipe: &protocol.recipe,
            minutes: protocol.minutes,
            machine_seed: protocol.machine_seed,
            every: held_out.every,
            files: ModelFiles::named(&out.join("models"), &name, true),
            name,
            dir: data_dir.join("closed-loop"),
        };
        let (union, how) = record_closed_loop(&device, &round, &c, &sources, reporter)?;
        let how = format!(
            "closed-loop data: {how}; {}",
            round.training_set("every job")
        );
        reporter.note(&how);
        (union, Some(how))
    } else {
        (sources, None)
    };
    let done = |jobs: &[Job]| jobs.iter().filter(|j| j.record_path(out).exists()).count();
    if data_only {
        return Ok(Outcome::Partial {
            done: done(&jobs),
            total: jobs.len(),
        });
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
    // The dataset of the current job's share (the jobs come share by share).
    let mut current: Option<(f64, Graph, Dataset)> = None;
    let mut spent = Vec::new();
    for (n, (i, job)) in todo.iter().enumerate() {
        let eta = if spent.is_empty() {
            "unknown until a job finishes".to_string()
        } else {
            let mean = spent.iter().sum::<f64>() / spent.len() as f64;
            clock(mean * (todo.len() - n) as f64)
        };
        reporter.note(&format!(
            "== job {}/{} ({} of this run): {} seed {}{}; elapsed {}, ETA {eta}",
            i + 1,
            jobs.len(),
            n + 1,
            job.variant,
            job.seed,
            if job.is_curve() {
                format!(" on {:.0} % of the training windows", 100.0 * job.fraction)
            } else {
                String::new()
            },
            clock(began.elapsed().as_secs_f64())
        ));
        let started = Instant::now();
        let mut config = protocol.run.clone();
        config.model.variant = job.variant;
        config.train.seed = job.seed;
        config.data.train_fraction = job.fraction;
        let share = match current.take() {
            Some(c) if c.0 == job.fraction => c,
            old => {
                drop(old); // free the previous share's dataset first
                let (graph, data) = build_dataset(&sources, &config, None)?;
                for line in data.summary().lines() {
                    reporter.note(line);
                }
                (job.fraction, graph, data)
            }
        };
        let (_, graph, data) = current.insert(share);
        let mut record = run_job(&device, &config, job, graph, data, out, reporter)?;
        record.wall_seconds = started.elapsed().as_secs_f64();
        write_toml(&record, &job.record_path(out))?;
        spent.push(record.wall_seconds);
    }
    let finished = done(&jobs);
    if shard.is_some() || finished < jobs.len() {
        reporter.note(&format!(
            "{finished} of {} jobs done; once every shard has finished, a run with the \
             same options and no shard writes the report",
            jobs.len()
        ));
        return Ok(Outcome::Partial {
            done: finished,
            total: jobs.len(),
        });
    }
    report(
        device,
        protocol,
        &jobs,
        held_out,
        (&sources, closed_loop),
        began,
        out,
        reporter,
    )
    .map(|r| Outcome::Report(Box::new(r)))
}

/// Trains one job (a table model: core stage and refinement; a learning-curve model: the
/// core stage only) and returns its record (wall time left for the caller).
fn run_job(
    device: &Device,
    config: &RunConfig,
    job: &Job,
    graph: &Graph,
    data: &Dataset,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<JobRecord> {
    let name = job.name();
    let files = job.files(out);
    let dir = job.dir(out);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let model = job.variant.name();
    let windows = data.splits.train.len();
    if job.is_curve() {
        let t = train_core(device, data, graph, config, &name, &files, reporter)?;
        return Ok(JobRecord::new(
            &name,
            model,
            job.seed,
            job.fraction,
            windows,
            (t.best_val, t.best_epoch),
            &t.history,
            (&t.validation, &t.test),
        ));
    }
    let f = fit_model(device, data, graph, config, &name, &files, reporter)?;
    Ok(JobRecord::of_fitted(&name, model, job.seed, windows, &f))
}

/// The report of a protocol whose jobs are all done.
#[allow(clippy::too_many_arguments)]
fn report(
    device: Device,
    protocol: &Protocol,
    jobs: &[Job],
    held_out: &HeldOutConfig,
    (sources, closed_loop): (&crate::data::DataSources, Option<String>),
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
        if job.is_curve() {
            records.push(record);
            continue;
        }
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
            "data: twin machine {}; calibration set at rest on a cold machine (seed \
             {CALIBRATION_SEED}); training recordings under the calibrated controller: {}; \
             held-out runs: every path turned or reversed on the part, plus the rosette, {} \
             min each, in {}; prediction every {} ticks",
            protocol.machine_seed,
            protocol.recipe.describe(protocol.minutes, TRAINING_SEED),
            held_out.minutes,
            held_out.describe_sessions(),
            held_out.every
        ),
        closed_loop.unwrap_or_else(|| {
            "open-loop data: every training session recorded under the calibrated controller alone"
                .into()
        }),
        "split: contiguous 70/20/10 blocks per recording (leakage-free); every seed sees the same split".into(),
        format!(
            "wall time of the jobs (summed over the runs that finished them): {}",
            clock(records.iter().map(|r| r.wall_seconds).sum())
        ),
    ];
    let mut report = Report {
        title: "IASTGCN on the digital twin — reproduction of the paper's protocol".into(),
        headline: None,
        adapter: device.name(),
        setup,
        histories,
        sections: vec![(
            "Core training over seeds".into(),
            training_table(&protocol.models, &records),
        )],
        curve: learning_curve(protocol, &records),
        ..Report::default()
    };
    tables(
        &device,
        &mut report,
        &models,
        sources,
        run,
        held_out,
        reporter,
    )?;
    report::finish(report, began, out, reporter)
}

/// The learning curve's points: each curve model at each share (and at the full set when
/// it is one of the tables' models too), over its seeds.
fn learning_curve(protocol: &Protocol, records: &[JobRecord]) -> Vec<CurvePoint> {
    let mut points = Vec::new();
    for model in &protocol.curve_models {
        let mut shares = protocol.fractions.clone();
        if protocol.models.contains(model) {
            shares.push(1.0);
        }
        shares.sort_by(f64::total_cmp);
        for fraction in shares {
            let of: Vec<&JobRecord> = records
                .iter()
                .filter(|r| &r.model == model && r.fraction == fraction)
                .collect();
            let Some(first) = of.first() else {
                continue;
            };
            let spread = |pick: fn(&JobRecord) -> f64| {
                Spread::of(&of.iter().map(|r| pick(r)).collect::<Vec<_>>())
            };
            points.push(CurvePoint {
                model: model.clone(),
                fraction,
                windows: first.train_windows,
                val_pos: spread(|r| r.val_mae[0]),
                val_att: spread(|r| r.val_mae[1]),
                test_pos: spread(|r| r.test_mae[0]),
                test_att: spread(|r| r.test_mae[1]),
            });
        }
    }
    points
}
