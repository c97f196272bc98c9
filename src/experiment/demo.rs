//! The demo protocol end to end on the embedded twin: the calibration set on a cold
//! machine, the EKF calibration, the training sessions under the calibrated controller
//! (cold-start days at spread placements, the second half recorded again with a round-0
//! IASTGCN compensating), the dataset, IASTGCN, its three ablations and the dense
//! baselines trained and refined the same way, then Tables III and V on held-out
//! sessions, the mirror polished with the recommended model (docs/polishing.md) and the
//! report folder.

use std::path::PathBuf;
use std::time::Instant;

use super::evaluate::{
    add_graph_mixing, evaluate_models, predictors, report_evaluation, tables, Evaluated,
    HeldOutConfig, NamedModel,
};
use super::forecast;
use super::jobs::{training_table, JobRecord};
use super::polish;
pub use super::polish::PolishSpec;
use super::protocol::{
    check_closed_loop_sessions, check_seeds, record_closed_loop, record_data, sessions_setting,
    ClosedLoopRound, ModelFiles, MACHINE_SEED,
};
pub use super::protocol::{CALIBRATION_SEED, TRAINING_SEED};
use super::recommend::recommend;
use super::report::seeds::seeded_name;
use super::report::{self, Report, TableVRow};
use super::side_by_side::{fit_side_by_side, FitJob};
use crate::calibrate::file;
use crate::compensate::held_out::IDLE_BETWEEN_RUNS;
use crate::data::DataSources;
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::Variant;
use crate::polish::{Polisher, Setup, StartingPoint};
use crate::progress::Reporter;
use crate::robot::{Geometry, Robot};
use crate::train::{build_dataset, RunConfig};
use crate::twin::{draw_machine, PathKind, PathOrder, Placement, Recipe};

/// Length of each of the demo's training recordings, minutes: the most data with which
/// three seeds of its eight models fitted `make demo`'s time on 2 CPU cores when it was
/// chosen (docs/results.md "Why 8 minutes per path and L = 2"; the demo's times now:
/// "How long it takes").
pub const DEMO_MINUTES: f64 = 8.0;

/// What the demo runs.
#[derive(Clone, Debug, PartialEq)]
pub struct DemoConfig {
    /// The run config of every model (the embedded assets/demo.toml by default).
    pub run: RunConfig,
    /// Where `run` came from, for the report.
    pub run_source: String,
    /// Length of each training recording, minutes.
    pub minutes: f64,
    /// The held-out session.
    pub held_out: HeldOutConfig,
    /// Training seeds (`[train] seed`): every model is trained with each, and Tables III
    /// and V report mean ± SD over them with IASTGCN compared seed by seed. With one seed
    /// the models keep their plain names; with more they are `<model>.seed<k>`.
    pub seeds: Vec<u64>,
    /// Also train and evaluate the spatio-temporal baselines of Table III (ConvLSTM, T-GCN,
    /// EAT-GCN, ST-GAT) at the same budget; they take longer than the demo's 10 minutes on
    /// 2 CPU cores (docs/usage.md "demo", `--all-models`), so they are off by default.
    pub all_models: bool,
    /// How the training set is recorded (docs/twin.md "Sessions").
    pub recipe: Recipe,
    /// The mirror (docs/polishing.md): the recommended model polishing a surface against
    /// the other controllers, into `polish/` and a report section; `None` leaves it out.
    pub mirror: Option<PolishSpec>,
    /// Closed-loop training data ([`ClosedLoopRound`]): a round-0 IASTGCN (the first
    /// seed, core stage) trained on the first half of the recipe's sessions compensates
    /// the other half, at the held-out session's prediction rate, as they are recorded
    /// again; every model trains on the first half open loop and the rest closed loop.
    /// Needs 2 sessions or more.
    pub closed_loop: bool,
}

/// The demo's mirror: one surface, two iterations on the raster (about a minute and a
/// half on 2 cores; `iastgcn polish` runs more).
pub fn demo_mirror() -> PolishSpec {
    PolishSpec {
        iterations: 2,
        surface_seeds: vec![1],
        seed: 501,
        warm_up_minutes: 2.0,
        every: DEMO_HELD_OUT.every,
        start: StartingPoint::default(),
        split_nominal: false,
    }
}

/// How the demo records its training set: each path's minutes in 4 sessions on days of
/// their own, at spread placements. Chosen on the evidence of docs/results.md "Training
/// on what use looks like": at the demo's 8 minutes, 4 sessions beat 1 in 4 of 8
/// closed-loop cells and lost none; at 32 minutes in 5 of 8, and 16 sessions gained
/// nothing over 4; spread placements beat the quarter turns on Hilbert at 8 and 32
/// minutes (+3.8 / +3.4 and +3.9 / +4.7 points) and lost no cell; rotating the paths'
/// order changed nothing.
pub const DEMO_RECIPE: Recipe = Recipe {
    sessions: 4,
    placement: Placement::Spread,
    path_order: PathOrder::Fixed,
};

/// The demo's held-out sessions: three, of 0.5 min runs from seed 301, the first after
/// 2 min of warm-up, and **a prediction every tick**: with closed-loop training data
/// recorded at that rate the models use the faster loop (docs/results.md "Training on
/// what use looks like": +4.5 points on Hilbert at 32 minutes per path against every 5
/// ticks, which open-loop-trained models do not gain).
pub const DEMO_HELD_OUT: HeldOutConfig = HeldOutConfig {
    minutes: 0.5,
    seed: 301,
    warm_up_minutes: 2.0,
    every: 1,
    sessions: 3,
};

impl Default for DemoConfig {
    fn default() -> DemoConfig {
        DemoConfig {
            run: RunConfig::demo(),
            run_source: "assets/demo.toml (embedded)".into(),
            minutes: DEMO_MINUTES,
            held_out: DEMO_HELD_OUT,
            seeds: vec![1, 2, 3],
            all_models: false,
            recipe: DEMO_RECIPE,
            mirror: Some(demo_mirror()),
            closed_loop: true,
        }
    }
}

/// The report's table of what each channel's instrument is (docs/twin.md "Sensors" has
/// the figures and their sources).
fn sensor_table() -> String {
    let s = crate::twin::SensorSpecs::default();
    let mut out = String::from(
        "Every channel is the instrument a real machine would carry, with its own span, \
         resolution, lag and drift; none is a term of the truth model plus white noise \
         (docs/twin.md \"Sensors\").\n\n| Channel | Instrument |\n|---|---|\n",
    );
    for (name, what) in crate::twin::CHANNEL_UNITS {
        out.push_str(&format!("| {name} | {what} |\n"));
    }
    out.push_str(&format!(
        "\nScales: pitch error ±{} µm over {} mm, glass {} ppm/K, noise {} µm. Load encoders: \
         {:.3} mdeg quantum, ±{} mdeg eccentricity. Inclinometer: {} s lag, {} mdeg noise, \
         {} mdeg/K, bias walk {} mdeg/√s, mounting offset σ {} mdeg. Gyro: angle random walk \
         {:.3} °/√h, bias σ {:.3} °/h. Force from pressure: seal friction σ {} N, lag {} s. \
         Tracker: {} µm, {:.1} mdeg per axis.\n",
        s.scale_pitch_error,
        s.scale_pitch_wavelength,
        s.scale_expansion * 1e6,
        s.scale_noise,
        s.load_encoder_quantum,
        s.load_encoder_eccentricity,
        s.tilt_lag,
        s.tilt_noise,
        s.tilt_tempco,
        s.tilt_bias_walk,
        s.tilt_mounting,
        s.gyro_angle_walk * 60.0,
        s.gyro_bias * 3600.0,
        s.force_seal_friction,
        s.force_lag,
        s.tracker_position * 1e3,
        s.tracker_attitude.to_degrees() * 1e3,
    ));
    out
}

/// What the demo will do, stage by stage, and about how long it will take here
/// ([`forecast`]: on the native CPU path only, where training takes most of the time).
fn plan(demo: &DemoConfig, device: &Device, out: &std::path::Path) -> Result<Vec<String>> {
    let models = Variant::IASTGCN.len()
        + Variant::DENSE.len()
        + if demo.all_models {
            Variant::SPATIO_TEMPORAL.len()
        } else {
            0
        };
    let seeds = demo.seeds.len();
    let mut lines = vec![
        "== the plan".to_string(),
        format!(
            "1. the twin: a calibration set on a cold machine and its EKF calibration; training recordings, {}",
            demo.recipe.describe(demo.minutes, TRAINING_SEED)
        ),
        if demo.closed_loop {
            "2. closed-loop recordings: a round-0 IASTGCN compensates the second half of the sessions as they are recorded again".into()
        } else {
            "2. (no closed-loop recordings: open-loop data only)".into()
        },
        format!(
            "3. the dataset (T = {}, stride {}, contiguous 70/20/10 blocks per recording)",
            demo.run.model.window, demo.run.data.stride
        ),
        format!(
            "4. for each of {seeds} training seed(s): {models} models trained and refined, then evaluated (Table III, Table V on {} held-out session(s), a validation session that picks the model to use){}",
            demo.held_out.sessions,
            if seeds > 1 {
                "; the first seed's result is on screen and in report.md as soon as it is ready"
            } else {
                ""
            }
        ),
        format!("5. the report: {}", out.join("report.md").display()),
    ];
    if let Some(mirror) = &demo.mirror {
        lines.push(format!(
            "6. the mirror: the recommended model polishing against the other controllers, {} iteration(s) on {} surface(s)",
            mirror.iterations,
            mirror.surface_seeds.len()
        ));
    }
    // The reference ran the default demo: the forecast holds for its settings (any
    // seeds) on the native CPU path.
    let defaults = DemoConfig {
        seeds: demo.seeds.clone(),
        run_source: demo.run_source.clone(),
        ..DemoConfig::default()
    };
    lines.push(if !device.prefers_native() {
        format!(
            "time: no forecast on {} (it is scaled from the native CPU path)",
            device.name()
        )
    } else if *demo != defaults {
        "time: no forecast for these settings (it is scaled from a run of the default demo)"
            .into()
    } else {
        let step_ms = forecast::probe(&demo.run)?;
        let (first, all) = forecast::forecast(step_ms);
        // The reference ran three seeds: the rest scales with them.
        let all = first + (all - first) * seeds as f64 / 3.0;
        format!(
            "time: {} here{}, if nothing else runs beside it (an IASTGCN training step takes {step_ms:.1} ms here, {:.1} ms on the reference machine, where the demo took {:.0} s: {})",
            forecast::minutes(all),
            if seeds > 1 {
                format!(", the first result in {}", forecast::minutes(first))
            } else {
                String::new()
            },
            forecast::REFERENCE.step_ms,
            forecast::REFERENCE.demo_s,
            forecast::REFERENCE.measured
        )
    });
    Ok(lines)
}

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

    reporter.note("== 1/6 … 3/6 twin data: calibration set, EKF calibration, training sessions");
    let mut sources = record_data(
        &data_dir,
        demo.minutes,
        MACHINE_SEED,
        &demo.recipe,
        reporter,
    )?;
    let seeded = demo.seeds.len() > 1;
    let closed_loop = if demo.closed_loop {
        reporter.note(
            "== 3/6 closed-loop data: a round-0 IASTGCN compensating the second half of the sessions as they are recorded again",
        );
        let mut c = config.clone();
        c.model.variant = Variant::Iastgcn;
        c.train.seed = demo.seeds[0];
        let name = if seeded {
            format!(
                "{}.round0",
                seeded_name(Variant::Iastgcn.name(), c.train.seed)
            )
        } else {
            format!("{}.round0", Variant::Iastgcn.name())
        };
        let round = ClosedLoopRound {
            recipe: &demo.recipe,
            minutes: demo.minutes,
            machine_seed: MACHINE_SEED,
            every: demo.held_out.every,
            files: ModelFiles::named(&model_dir, &name, false),
            name,
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

    // The spatio-temporal baselines (Variant::SPATIO_TEMPORAL) run only with
    // `all_models`: the demo already takes most of its 10 minutes on 2 cores, and they cost
    // 2–4 IASTGCN epochs each per epoch (the baselines run of 2026-11-25, indexed in
    // docs/runs/README.md).
    let spatio_temporal: &[Variant] = if demo.all_models {
        &Variant::SPATIO_TEMPORAL
    } else {
        &[]
    };
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
    let variants: Vec<Variant> = Variant::IASTGCN
        .into_iter()
        .chain(Variant::DENSE)
        .chain(spatio_temporal.iter().copied())
        .collect();
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
        let jobs: Vec<FitJob> = variants
            .iter()
            .map(|&variant| {
                let mut c = config.clone();
                c.model.variant = variant;
                c.train.seed = seed;
                let name = if seeded {
                    seeded_name(variant.name(), seed)
                } else {
                    variant.name().to_string()
                };
                let files = ModelFiles::named(&model_dir, &name, false);
                FitJob {
                    config: c,
                    name,
                    files,
                }
            })
            .collect();
        let all = fit_side_by_side(
            &device,
            &data,
            &graph,
            jobs,
            &format!("training seed {seed}"),
            reporter,
        )?;
        let mut trained = Vec::new();
        for (&variant, fitted) in variants.iter().zip(all) {
            let name = fitted.model.name.clone();
            refinement.push(format!("{name}: {}", fitted.verdict));
            records.push(JobRecord::of_fitted(
                &name,
                variant.name(),
                seed,
                data.splits.train.len(),
                &fitted,
            ));
            // The loss curves and Fig. 9b of the first seed.
            if s == 0 {
                if variant == Variant::Iastgcn {
                    accumulated = Some(fitted.accumulated.clone());
                }
                histories.push((name.clone(), fitted.core));
                histories.push((format!("{name}-refined"), fitted.refinement));
            }
            trained.push(fitted.model);
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
    let setup = vec![
        format!(
            "config: {} (T = {}, C = {}, L = {}, at most {} epochs, patience {}); training \
             seeds {}",
            demo.run_source,
            config.model.window,
            config.model.channels,
            config.model.blocks,
            config.train.max_epochs,
            config.train.patience,
            demo.seeds
                .iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        format!(
            "protocol: machine 1; calibration set at rest on a cold machine (seed \
             {CALIBRATION_SEED}); training recordings under the calibrated controller: {}, \
             {IDLE_BETWEEN_RUNS} s idle between runs; held-out runs under the same \
             controller, every path turned or reversed on the part so that no window \
             retraces a training recording, plus the rosette that training never saw, {} min \
             each, every stage of a path starting from the same machine state, in {}; \
             prediction every {} ticks. Table V scores against the hidden truth and as the \
             tracker measures; Table III scores the test split of the training recordings \
             against the tracker-derived labels",
            demo.recipe.describe(demo.minutes, TRAINING_SEED),
            held_out.minutes,
            held_out.describe_sessions(),
            held_out.every
        ),
        closed_loop.unwrap_or_else(|| {
            "open-loop data: every training session recorded under the calibrated controller alone"
                .into()
        }),
        "split: contiguous 70/20/10 blocks per recording (leakage-free)".into(),
        if demo.all_models {
            "models: IASTGCN, its ablations and every baseline, all at the same budget".into()
        } else {
            "models: IASTGCN, its ablations and the dense baselines; the spatio-temporal baselines of Table III (ConvLSTM, T-GCN, EAT-GCN, ST-GAT) are left out to keep the demo within its time (demo.all_models trains them too)".into()
        },
        "every model is refined the same way and keeps its core weights unless refinement lowers its per-window validation loss".into(),
    ];
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
    report::finish(report, began, out, reporter)
}

/// The first seed's result, while the other seeds train: its recommendation and
/// headline on screen, and `out/report.md` saying so, marked as partial (the full report
/// replaces it).
fn first_result(
    e: &Evaluated,
    seed: u64,
    seeds: usize,
    began: Instant,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let rows: Vec<TableVRow> = e.sessions.iter().flat_map(|s| s.rows.clone()).collect();
    let recommendation = recommend(&e.validation.rows);
    let headline = recommendation.headline(&rows).unwrap_or_else(|| {
        "No model removed error on the validation session: none is recommended.".into()
    });
    let minutes = began.elapsed().as_secs_f64() / 60.0;
    reporter.note(&format!(
        "first result, after {minutes:.1} min (training seed {seed} only; {} more seed(s) to come): {headline}",
        seeds - 1
    ));
    let text = format!(
        "# IASTGCN on the digital twin — demo report (partial)\n\n\
         **Partial: only training seed {seed}'s models are trained and evaluated so far \
         ({minutes:.1} min into the demo). The demo is still running; this file is replaced \
         by the full report, over all {seeds} seeds, when it ends.**\n\n\
         {headline}\n\n{}\n",
        recommendation.sentence()
    );
    crate::error::write_file(&out.join("report.md"), text.as_bytes())
}

/// The mirror with the model `name` of `models` compensating (none: only the other
/// controllers; docs/polishing.md), into `out/polish/`; returns the report's section.
fn mirror_section(
    device: &Device,
    models: &[NamedModel],
    name: Option<&str>,
    sources: &DataSources,
    spec: &PolishSpec,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<String> {
    let model = match name {
        Some(name) => Some(models.iter().find(|m| m.name == name).ok_or_else(|| {
            Error::Invalid(format!(
                "the recommended model {name} is not among the demo's"
            ))
        })?),
        None => None,
    };
    let checkpoints: Vec<(String, _)> = model
        .iter()
        .map(|m| (m.name.clone(), m.checkpoint.clone()))
        .collect();
    let mut loop_models = predictors(device, &checkpoints)?;
    // The oracle stands in for a model of the demo's window.
    let window = models.first().map_or(48, |m| m.checkpoint.config.window);
    let geometry = Geometry::load_or_default(None)?;
    let machine = draw_machine(geometry.clone(), MACHINE_SEED);
    let nominal = Robot::nominal(geometry.clone());
    let calibrated = file::calibrated_robot(geometry, &sources.calibration)?;
    let mut polisher = Polisher::new(Setup::new(PathKind::Grid))?;
    polisher.run_on(device)?;
    let result = polish::run(
        &mut polisher,
        spec,
        &machine,
        &nominal,
        &calibrated,
        &mut loop_models,
        window,
        reporter,
    )?;
    let dir = out.join("polish");
    polish::write(&dir, spec, &polisher, &result)?;
    let table = polish::report(spec, &polisher, &result);
    // The study's own heading goes; the rest is the section.
    let body: String = table.lines().skip(2).collect::<Vec<_>>().join("\n");
    let who = match name {
        Some(name) => format!("The recommended model ({name}) in the loop"),
        None => "No model was recommended (none removed error on the validation session), so none is in the loop: the other controllers".into(),
    };
    Ok(format!(
        "{who} while the twin polishes a mirror, against the other controllers, from the same starting surface with the same seeds (docs/polishing.md; `iastgcn polish` runs more surfaces and iterations). Files: `polish/polish.md`, `polish/polish.csv`, `polish/convergence.png` (Fig. 13), `polish/maps.png` (Fig. 14).\n\n{body}\n"
    ))
}

/// The report of `iastgcn evaluate`: Tables III and V for `models` on `sources`, written
/// into the folder `out`.
pub fn evaluation_report(
    device: Device,
    models: &[PathBuf],
    sources: &DataSources,
    config: &RunConfig,
    held_out: &HeldOutConfig,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<Report> {
    let began = Instant::now();
    let named = models
        .iter()
        .map(|p| NamedModel::load(p))
        .collect::<Result<Vec<_>>>()?;
    for (i, m) in named.iter().enumerate() {
        if let Some(j) = named[..i].iter().position(|o| o.name == m.name) {
            return Err(Error::Invalid(format!(
                "evaluate.models: {} and {} are both the model {}; give each model once (in a demo \
                 folder written before the naming of docs/usage.md \"Checkpoint names\", \
                 <model>.seed<k>.safetensors is the core stage of \
                 <model>.seed<k>-refined.safetensors)",
                models[j].display(),
                models[i].display(),
                m.name
            )));
        }
    }
    let list = |paths: &[PathBuf]| {
        paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut report = Report {
        title: "IASTGCN evaluation".into(),
        headline: None,
        adapter: device.name(),
        setup: vec![
            format!("models: {}", list(models)),
            format!("recordings: {}", list(&sources.recordings)),
            format!(
                "split: {}",
                if config.data.split == "random" {
                    "random (the paper's protocol: windows leak between splits)"
                } else {
                    "contiguous blocks per recording (leakage-free)"
                }
            ),
            format!(
                "held-out runs: {} min each, seed {}, prediction every {} ticks",
                held_out.minutes, held_out.seed, held_out.every
            ),
        ],
        ..Report::default()
    };
    tables(
        &device,
        &mut report,
        &named,
        sources,
        config,
        held_out,
        reporter,
    )?;
    report::finish(report, began, out, reporter)
}
