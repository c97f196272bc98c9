//! The demo's run: the twin's data, the closed-loop round, the dataset, every model
//! trained seed by seed (resumable: each model leaves a job record) and evaluated, the
//! report and the mirror.

use std::time::Instant;

use super::jobs::{DemoJob, Setup};
use super::plan::plan;
use super::report::{first_result, mirror_section, sensor_table, setup_lines};
use super::DemoConfig;
use crate::error::{Error, Result};
use crate::experiment::confidence;
use crate::experiment::evaluate::{
    add_graph_mixing, evaluate_models, report_evaluation, Evaluated, NamedModel,
};
use crate::experiment::jobs::{training_table, JobRecord};
use crate::experiment::protocol::{
    check_closed_loop_sessions, check_seeds, existing_data, record_closed_loop, record_data,
    sessions_setting, ClosedLoopRound, Fitted, ModelFiles, MACHINE_SEED,
};
use crate::experiment::report::seeds::{seeded_name, split_name};
use crate::experiment::report::{self, Report};
use crate::experiment::runner::{Job, Runner};
use crate::experiment::side_by_side::{fit_side_by_side, FitJob};
use crate::gpu::Device;
use crate::model::Variant;
use crate::progress::Reporter;
use crate::train::build_dataset;

/// Runs the demo into the folder `out` (`data/`, `models/` and the report files; the
/// report's entry point is `report.md`). Returns the report as written.
pub fn demo(
    device: Device,
    demo: &DemoConfig,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<Report> {
    let began = Instant::now();
    let config = &demo.run;
    config.validate().map_err(Error::Invalid)?;
    demo.held_out.validate()?;
    demo.recipe
        .validate(demo.minutes)
        .map_err(sessions_setting)?;
    check_seeds(&demo.seeds)?;
    if demo.closed_loop {
        check_closed_loop_sessions(demo.recipe.sessions, " (or closed_loop = false)")?;
    }
    let data_dir = out.join("data");
    let model_dir = out.join("models");
    for dir in [&data_dir, &model_dir] {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    reporter.note(&format!("demo on {} → {}", device.name(), out.display()));
    for line in plan(demo, &device, out)? {
        reporter.note(&line);
    }
    // The spatio-temporal baselines (Variant::SPATIO_TEMPORAL) run only with
    // `all_models`: the demo already takes most of its 10 minutes on 2 cores, and they cost
    // 2–4 IASTGCN epochs each per epoch (the baselines run of 2026-11-25, indexed in
    // docs/runs/README.md).
    let spatio_temporal: &[Variant] = if demo.all_models {
        &Variant::SPATIO_TEMPORAL
    } else {
        &[]
    };
    let variants: Vec<Variant> = Variant::IASTGCN
        .into_iter()
        .chain(Variant::DENSE)
        .chain(spatio_temporal.iter().copied())
        .collect();
    let jobs = DemoJob::all(&variants, &demo.seeds);
    let seeded = demo.seeds.len() > 1;
    let round0 = if seeded {
        format!(
            "{}.round0",
            seeded_name(Variant::Iastgcn.name(), demo.seeds[0])
        )
    } else {
        format!("{}.round0", Variant::Iastgcn.name())
    };
    let pinned = Setup::of(demo);
    let continued = pinned.continue_or_start(out, &jobs, &round0)?;
    let runner = Runner::new(&jobs, None, out, began);
    if continued {
        let done = runner.progress();
        reporter.note(&format!(
            "continuing the unfinished demo in {} (same settings): {} of {} models already \
             trained; the data and models it left are used as they are",
            out.display(),
            done.done,
            done.total
        ));
    }

    reporter.note("== 1/6 … 3/6 twin data: calibration set, EKF calibration, training sessions");
    let earlier = if continued {
        existing_data(&data_dir, demo.minutes, MACHINE_SEED, &demo.recipe)?
    } else {
        None
    };
    let mut sources = match earlier {
        Some(sources) => {
            reporter.note(&format!(
                "using the data of the unfinished run in {}",
                data_dir.display()
            ));
            sources
        }
        None => record_data(
            &data_dir,
            demo.minutes,
            MACHINE_SEED,
            &demo.recipe,
            reporter,
        )?,
    };
    let closed_loop = if demo.closed_loop {
        reporter.note(
            "== 3/6 closed-loop data: a round-0 IASTGCN compensating the second half of the sessions as they are recorded again",
        );
        let mut c = config.clone();
        c.model.variant = Variant::Iastgcn;
        c.train.seed = demo.seeds[0];
        let round = ClosedLoopRound {
            recipe: &demo.recipe,
            minutes: demo.minutes,
            machine_seed: MACHINE_SEED,
            every: demo.held_out.every,
            files: ModelFiles::named(&model_dir, &round0, true),
            name: round0.clone(),
            dir: data_dir.join("closed-loop"),
        };
        let (union, how) = record_closed_loop(&device, &round, &c, &sources, reporter)?;
        sources = union;
        Some(format!(
            "closed-loop data: {how}; {} (one round-0 model for all, so that every model \
             trains and is tested on the same data)",
            round.training_set("every model")
        ))
    } else {
        None
    };

    reporter.note("== 4/6 dataset");
    let (graph, data) = build_dataset(&sources, config, None)?;
    for line in data.summary().lines() {
        reporter.note(line);
    }

    reporter.note(if demo.all_models {
        "== 5/6 training and refining IASTGCN, its ablations and every baseline (the same treatment for each)"
    } else {
        "== 5/6 training and refining IASTGCN, its ablations and the dense baselines (the same treatment for each; demo.all_models adds the spatio-temporal ones)"
    });
    let mut models: Vec<NamedModel> = Vec::new();
    let mut records = Vec::new();
    let mut histories = Vec::new();
    let mut accumulated = None;
    let mut refinement = Vec::new();
    // Each seed's models are evaluated as soon as they are trained (the later seeds'
    // from the states the first seed's runs started from: nothing runs twice), so the
    // first seed's result is on screen and in report.md while the others train.
    let held_out = &demo.held_out;
    let mut evaluated: Vec<Evaluated> = Vec::new();
    for (s, &seed) in demo.seeds.iter().enumerate() {
        if seeded {
            reporter.note(&format!(
                "== training seed {seed} ({} of {})",
                s + 1,
                demo.seeds.len()
            ));
        }
        let of_seed: Vec<&DemoJob> = jobs.iter().filter(|j| j.seed == seed).collect();
        let pending: Vec<&DemoJob> = of_seed
            .iter()
            .copied()
            .filter(|j| !runner.is_done(j))
            .collect();
        if pending.len() < of_seed.len() {
            reporter.note(&format!(
                "{} of seed {seed}'s {} models trained by the unfinished run: their job records and weights are used",
                of_seed.len() - pending.len(),
                of_seed.len()
            ));
        }
        runner.run_batch(&pending, |batch, record| {
            let fits: Vec<FitJob> = batch
                .iter()
                .map(|job| {
                    let mut c = config.clone();
                    c.model.variant = job.variant;
                    c.train.seed = job.seed;
                    FitJob {
                        config: c,
                        name: job.name.clone(),
                        files: job.files(&model_dir),
                    }
                })
                .collect();
            let windows = data.splits.train.len();
            // Each model's record as soon as it is fitted: a demo cut short keeps it.
            let fitted = |i: usize, fitted: &Fitted, seconds: f64| {
                let job = batch.get(i).ok_or_else(|| {
                    Error::Invalid(format!("no model {i} in seed {seed}'s batch"))
                })?;
                let r = JobRecord::of_fitted(&job.name, job.variant.name(), seed, windows, fitted);
                record(i, r, seconds)
            };
            fit_side_by_side(
                &device,
                &data,
                &graph,
                fits,
                &format!("training seed {seed}"),
                &fitted,
                reporter,
            )
        })?;
        // Every model of the seed as its job record and files have it, whichever run
        // trained it.
        let mut trained = Vec::new();
        for job in of_seed {
            let record = JobRecord::load(&job.record_path(out))?;
            refinement.push(format!("{}: {}", job.name, record.refinement));
            // The loss curves and Fig. 9b of the first seed.
            if s == 0 {
                let (core, refined) = job.histories(&model_dir)?;
                histories.push((job.name.clone(), core));
                histories.push((format!("{}-refined", job.name), refined));
                if job.variant == Variant::Iastgcn {
                    accumulated = Some(job.accumulated(&model_dir)?);
                }
            }
            trained.push(job.model(&model_dir, &record)?);
            records.push(record);
        }
        reporter.note(&format!(
            "== 6/6 evaluation{}: Table III, Table V on {} held-out session(s), the validation session",
            if seeded {
                format!(" of seed {seed}'s models")
            } else {
                String::new()
            },
            held_out.sessions
        ));
        let e = evaluate_models(
            &device,
            &trained,
            &sources,
            config,
            held_out,
            evaluated.first(),
            reporter,
        )?;
        if s == 0 && demo.seeds.len() > 1 {
            first_result(&e, seed, demo.seeds.len(), began, out, reporter)?;
        }
        evaluated.push(e);
        models.extend(trained);
    }

    reporter.note("== report");
    let setup = setup_lines(demo, closed_loop);
    let mut sections = vec![("Sensor models".into(), sensor_table())];
    if seeded {
        let names: Vec<String> = variants.iter().map(|v| v.name().to_string()).collect();
        sections.push((
            "Core training over seeds".into(),
            training_table(&names, &records),
        ));
    }
    let mut report = Report {
        title: "IASTGCN on the digital twin — demo report".into(),
        headline: None,
        adapter: device.name(),
        setup,
        histories,
        accumulated,
        sections,
        // Each model's refinement verdict is the run's log: at the end, not the top.
        notes: refinement,
        ..Report::default()
    };
    report_evaluation(
        &mut report,
        &models,
        Evaluated::merge(evaluated)?,
        held_out,
        reporter,
    )?;
    add_graph_mixing(&mut report, &models);
    if let (true, Some(best)) = (seeded, report.recommended.clone()) {
        let group = split_name(&best).0.to_string();
        reporter.note(&format!(
            "== confidence: {group}'s {} seeds as one ensemble, a {:.0} % interval calibrated on the validation session (docs/results.md \"Confidence\")",
            demo.seeds.len(),
            100.0 * confidence::LEVEL
        ));
        let members: Vec<_> = models
            .iter()
            .filter(|m| split_name(&m.name).0 == group)
            .map(|m| {
                let files = ModelFiles::named(&model_dir, &m.name, true);
                (files.refined, m.checkpoint.clone())
            })
            .collect();
        let section = confidence::ensemble_section(
            &device,
            &group,
            &members,
            &sources,
            held_out,
            confidence::LEVEL,
            &model_dir,
            reporter,
        )?;
        report.sections.push(("Confidence".into(), section));
    }
    if let Some(spec) = &demo.mirror {
        let name = report.recommended.clone();
        reporter.note(&match &name {
            Some(name) => format!(
                "== the mirror: {name} polishing against the other controllers (docs/polishing.md)"
            ),
            None => "== the mirror: no model was recommended, so none compensates; the other controllers polish (docs/polishing.md)".into(),
        });
        let section = mirror_section(
            &device,
            &models,
            name.as_deref(),
            &sources,
            spec,
            out,
            reporter,
        )?;
        report
            .sections
            .push(("The mirror (Table VI)".into(), section));
    }
    let report = report::finish(report, began, out, reporter)?;
    pinned.finish(out)?;
    Ok(report)
}
