//! The study's runner: the data, then every job (train, refine, score on the test
//! split and the held-out sessions), resumable and shardable, the summary rewritten
//! after each.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::records::{unmeasured, PathScore, ScaleRecord};
use super::study::{ScaleJob, Study};
use super::summary::write_summary;
use crate::data::{DataSources, Dataset};
use crate::error::{Error, Result};
use crate::experiment::evaluate::{
    ensemble, held_out_session, predictors, table_iii, LoopModel, SessionOptions,
};
use crate::experiment::jobs::{pin_toml, write_toml, Shard};
use crate::experiment::protocol::{
    epoch_seconds, existing_data, record_closed_loop, record_data, train_core, ClosedLoopRound,
    ModelFiles,
};
use crate::experiment::report::TableVRow;
use crate::experiment::runner::Progress;
use crate::experiment::runner::{Cached, Runner};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Checkpoint, Variant};
use crate::progress::Reporter;
use crate::train::{build_dataset, by_path, recording_path, refine, RunConfig, TestMetrics};
use crate::twin::PathKind;

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
         config, the machine or the held-out sessions differ); use another output folder, or \
         the same options (a study pinned before there were several held-out sessions has \
         one: held_out.sessions 1)",
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
    let runner = Runner::new(&jobs, shard, out, began);
    if data_only {
        return Ok(runner.progress());
    }
    let nothing_to_do = runner.pending().is_empty();
    let mut current: Cached<f64, (Graph, Dataset)> = Cached::default();
    runner.run_each(
        reporter,
        |job, reporter| {
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
            let (graph, data) = current.get(job.minutes, || {
                let (graph, data) = build_dataset(job_sources, &config, None)?;
                for line in data.summary().lines() {
                    reporter.note(line);
                }
                Ok((graph, data))
            })?;
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
            if let Some((_, how)) = closed {
                record.closed_loop = how;
                current.clear();
            }
            Ok(record)
        },
        |reporter| write_summary(study, out, reporter),
    )?;
    // A shard scores no ensemble: its seeds may be another shard's, still training.
    if study.ensemble && shard.is_none() {
        score_ensembles(&device, study, &sources, out, reporter)?;
    }
    // Once more with nothing to do: a finished folder gets this build's summary.
    if nothing_to_do {
        write_summary(study, out, reporter)?;
    }
    Ok(runner.progress())
}

impl crate::experiment::runner::Job for ScaleJob {
    type Record = ScaleRecord;

    fn record_path(&self, out: &Path) -> PathBuf {
        ScaleJob::record_path(self, out)
    }

    fn describe(&self) -> String {
        format!(
            "{} seed {} on {} min per path",
            self.variant, self.seed, self.minutes
        )
    }

    fn set_wall_seconds(record: &mut ScaleRecord, seconds: f64) {
        record.wall_seconds = seconds;
    }
}

/// The core stage of one job, then its scores: the test split per path from the best
/// weights, and the held-out session with the model in the loop.
#[allow(clippy::too_many_arguments)]
pub(super) fn run_job(
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
pub(super) fn closed_loop_sources(
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
pub(super) fn held_out_scores(
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
pub(super) fn ensemble_record_path(out: &Path, model: Variant, minutes: f64) -> PathBuf {
    out.join("models")
        .join(format!("{}.min{minutes}.ensemble.job.toml", model.name()))
}

/// Scores the seed ensemble of every model and size whose seeds (two or more) have all
/// finished and that has no ensemble record yet: the controller averages the seeds' predictions (the
/// refined weights in a study that refines). Its test block is not scored (NaN).
pub(super) fn score_ensembles(
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
pub(super) fn path_score(
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
