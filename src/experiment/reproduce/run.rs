//! The protocol's run: its data (and closed-loop round), then its jobs through the
//! experiments' runner, then, once every job of every shard is done, the report.

use std::path::Path;
use std::time::Instant;

use super::protocol::{Job, Protocol};
use super::report::report;
use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::experiment::evaluate::HeldOutConfig;
use crate::experiment::jobs::{pin_toml, JobRecord, Shard};
use crate::experiment::protocol::{
    existing_data, fit_model, record_closed_loop, record_data, train_core, ClosedLoopRound,
    ModelFiles,
};
use crate::experiment::report::seeds::seeded_name;
use crate::experiment::report::Report;
use crate::experiment::runner::{Cached, Progress, Runner};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::Variant;
use crate::progress::Reporter;
use crate::train::{build_dataset, RunConfig};

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
    let runner = Runner::new(&jobs, shard, out, began);
    if data_only {
        let Progress { done, total } = runner.progress();
        return Ok(Outcome::Partial { done, total });
    }
    reporter.note(&format!(
        "{} of this run's {} jobs already done",
        runner.mine().len() - runner.pending().len(),
        runner.mine().len()
    ));
    // The dataset of the current job's share (the jobs come share by share).
    let mut current: Cached<f64, (Graph, Dataset)> = Cached::default();
    runner.run_each(
        reporter,
        |job, reporter| {
            let mut config = protocol.run.clone();
            config.model.variant = job.variant;
            config.train.seed = job.seed;
            config.data.train_fraction = job.fraction;
            let (graph, data) = current.get(job.fraction, || {
                let (graph, data) = build_dataset(&sources, &config, None)?;
                for line in data.summary().lines() {
                    reporter.note(line);
                }
                Ok((graph, data))
            })?;
            run_job(&device, &config, job, graph, data, out, reporter)
        },
        |_| Ok(()),
    )?;
    let Progress {
        done: finished,
        total,
    } = runner.progress();
    if shard.is_some() || finished < total {
        reporter.note(&format!(
            "{finished} of {total} jobs done; once every shard has finished, a run with the \
             same options and no shard writes the report"
        ));
        return Ok(Outcome::Partial {
            done: finished,
            total,
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
