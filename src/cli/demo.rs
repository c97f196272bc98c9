//! `iastgcn demo`: the main job end to end on the embedded twin — simulate the
//! calibration set and the three polishing recordings, calibrate (EKF), build the
//! dataset, train IASTGCN and its three ablations, refine IASTGCN, measure Table III on
//! the held-out split, compensate held-out runs in the twin (Table V) and write the
//! report folder. `iastgcn evaluate` is the last two steps for models you trained.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use clap::Args;

use super::calibrate::{self, CalibrateArgs};
use super::compensate::{print_table_v, tick_bar};
use super::simulate::{self, SimulateArgs};
use super::train::{
    build_dataset, fit, print_accumulated, read_run_config, refine_params, DataArgs,
};
use crate::calibrate::file;
use crate::compensate::budget::{error_budget, markdown as budget_markdown};
use crate::compensate::evaluate::{
    predictors, table_iii, table_v, warm_up, HeldOut, IDLE_BETWEEN_RUNS,
};
use crate::compensate::online::Online;
use crate::compensate::report::{self, Report, TableIIIRow, Timing};
use crate::data::Dataset;
use crate::gpu::Gpu;
use crate::graph::Graph;
use crate::model::{Checkpoint, Parameters, Variant};
use crate::robot::{Geometry, Robot};
use crate::train::{self, core_stage, log, RunConfig, Trainer};
use crate::twin::{draw_machine, PathKind, PathParams, RunInfo};

#[derive(Args)]
pub struct DemoArgs {
    /// Report folder.
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    /// Run config; the embedded assets/demo.toml when absent (assets/paper.toml runs the
    /// paper's sizes, for a real GPU).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Length of each training recording, minutes.
    #[arg(long, default_value_t = 2.0)]
    pub minutes: f64,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}

#[derive(Args, Clone)]
pub struct HeldOutArgs {
    /// Length of each held-out compensation run, minutes.
    #[arg(long, default_value_t = 0.5)]
    pub held_out_minutes: f64,
    /// Seed of the first held-out run; the next paths take the following seeds (the
    /// demo's training recordings use 201–203, its calibration set 101).
    #[arg(long, default_value_t = 301)]
    pub held_out_seed: u64,
    /// Minutes of polishing that warm the machine before the held-out session's first
    /// scored run (0: it starts cold).
    #[arg(long, default_value_t = 2.0)]
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks during compensation.
    #[arg(long, default_value_t = 5)]
    pub every: usize,
}

#[derive(Args)]
pub struct EvaluateArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// Checkpoints to compare (named by file stem; a `<stem>.log.csv` beside one gives its
    /// training time per epoch).
    #[arg(long, num_args = 1.., required = true)]
    pub models: Vec<PathBuf>,
    /// Run config (its [data] table windows the recordings for Table III).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Report folder.
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}

/// Seeds of the demo's runs: every run has its own (written in its `.run.toml`).
const CALIBRATION_SEED: u64 = 101;
const TRAINING_SEED: u64 = 201;

fn banner(text: &str) {
    println!("\n== {text}");
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

/// The mean core-stage epoch time of a history.
fn epoch_seconds(history: &[train::EpochRecord]) -> f64 {
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

/// Table III and Table V for `models`, written with everything else in `report`.
#[allow(clippy::too_many_arguments)]
fn evaluate_into(
    gpu: &Arc<Gpu>,
    report: &mut Report,
    models: &[(String, Checkpoint)],
    epoch_secs: &[f64],
    data_args: &DataArgs,
    config: &RunConfig,
    held: &HeldOutArgs,
    out: &Path,
) -> anyhow::Result<()> {
    banner("Table III: prediction accuracy on the held-out split");
    let mut rows: Vec<TableIIIRow> = Vec::new();
    for (i, (name, ck)) in models.iter().enumerate() {
        let mut c = config.clone();
        c.model = ck.config.clone();
        let fixed = train::data_normalization(&ck.normalization)
            .context("the checkpoint's normalisation is not N×3 features and 6 labels")?;
        let (_, data): (Graph, Dataset) = build_dataset(data_args, &c, Some(&fixed))?;
        let names: Vec<String> = data
            .recordings
            .iter()
            .map(|r| {
                Path::new(r)
                    .file_stem()
                    .map_or(r.clone(), |s| s.to_string_lossy().into_owned())
            })
            .collect();
        rows.extend(table_iii(gpu, name, ck, &data, &names, i == 0)?);
    }
    for r in &rows {
        let m = &r.metrics;
        println!(
            "  {:<10} {:<20} MAE {:>7.2} µm / {:>6.2} mdeg  RMSE {:>7.2} / {:>6.2}  MAPE {:>6.1}% / {:>6.1}%",
            r.trajectory, r.model, m.pos_mae, m.att_mae, m.pos_rmse, m.att_rmse, m.pos_mape, m.att_mape
        );
    }
    report.table_iii = rows;

    banner("Table V: compensation of held-out runs in the twin");
    let geometry = match &data_args.robot {
        Some(p) => Geometry::load(p)?,
        None => Geometry::default_asset(),
    };
    let cal = file::load(&data_args.calibration)?;
    let machine = draw_machine(geometry.clone(), 1);
    let nominal = Robot::nominal(geometry.clone());
    let calibrated = Robot::new(geometry, cal.errors);
    let graph = models[0].1.graph.clone();
    let window = models[0].1.config.window;
    let mut preds = predictors(gpu, models)?;
    let seconds = held.held_out_minutes * 60.0;
    anyhow::ensure!(seconds > 0.0, "--held-out-minutes must be positive");
    let mut latency = vec![(0.0, 0usize); models.len()];
    // One held-out session: the machine warms up, then every path runs in turn; each
    // stage of a path starts from the same state, and the session carries on from the
    // calibrated run's end.
    let mut state = warm_up(
        &machine,
        &calibrated,
        held.warm_up_minutes * 60.0,
        held.held_out_seed.wrapping_add(1000),
    )?;
    for (i, path) in PathKind::ALL.into_iter().enumerate() {
        let run = HeldOut {
            path,
            params: PathParams::held_out(path),
            seconds,
            seed: held.held_out_seed + i as u64,
            start: state.clone(),
        };
        // One budget (the Hilbert run's) keeps the demo in its time; `iastgcn budget`
        // gives any other.
        if path == PathKind::Hilbert {
            let budget = error_budget(&machine, &calibrated, &run.config(), &run.start)?;
            report.sections.push((
                format!("Error budget: {} (held-out run)", path.name()),
                format!(
                    "The hidden tool-pose error of this run split by source (RMS over every tick, \
                 against the path target; `iastgcn budget` gives it for any run):\n\n{}",
                    budget_markdown(&budget)
                ),
            ));
        }
        let bar = tick_bar(
            run.config().steps() * (3 + preds.len()),
            &format!("compensating {}", path.name()),
        );
        let result = table_v(
            &machine,
            &nominal,
            &calibrated,
            &graph,
            window,
            &mut preds,
            &run,
            Online { every: held.every },
            |_| bar.inc(1),
        )?;
        bar.finish_and_clear();
        print_table_v(&result.rows);
        report.table_v.extend(result.rows);
        state = result.end;
        state.idle(IDLE_BETWEEN_RUNS);
        // Fig. 11 shows before/after: calibration only, and the main model.
        let main = models
            .iter()
            .find(|(n, _)| n == "iastgcn")
            .unwrap_or(&models[0])
            .0
            .clone();
        let keep = format!("compensated ({main})");
        report.traces.extend(
            result
                .traces
                .into_iter()
                .filter(|t| t.label == "calibrated" || t.label == keep),
        );
        for (slot, (_, ms)) in latency.iter_mut().zip(result.latency) {
            slot.0 += ms;
            slot.1 += 1;
        }
    }
    report.timings = models
        .iter()
        .zip(&latency)
        .zip(epoch_secs)
        .map(|(((name, _), (ms, n)), secs)| Timing {
            model: name.clone(),
            epoch_seconds: *secs,
            infer_ms: ms / (*n).max(1) as f64,
            adapter: gpu.info().name.clone(),
        })
        .collect();
    let files = report::write(out, report)?;
    println!(
        "\nreport: {} ({} files)",
        out.join("report.md").display(),
        files.len()
    );
    Ok(())
}

/// Checkpoints named by file stem.
type Named = Vec<(String, Checkpoint)>;

/// Named checkpoints and their mean training time per epoch (from the log beside each).
fn models_from(paths: &[PathBuf]) -> anyhow::Result<(Named, Vec<f64>)> {
    let mut models = Vec::new();
    let mut secs = Vec::new();
    for p in paths {
        let name = p
            .file_stem()
            .map_or("model".into(), |s| s.to_string_lossy().into_owned());
        models.push((name, Checkpoint::load(p)?));
        let log = super::train::sibling(p, ".log.csv");
        secs.push(read_epoch_seconds(&log).unwrap_or(f64::NAN));
    }
    Ok((models, secs))
}

/// Mean `seconds` of the core epochs in a training log (of every epoch when it has no
/// core stage), if it exists.
fn read_epoch_seconds(log: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(log).ok()?;
    let seconds = |core: bool| -> Vec<f64> {
        text.lines()
            .skip(1)
            .filter(|l| !core || l.starts_with("core,"))
            .filter_map(|l| l.split(',').nth(6)?.parse().ok())
            .collect()
    };
    // A refined model's log has only refinement epochs.
    let v = Some(seconds(true))
        .filter(|v| !v.is_empty())
        .unwrap_or_else(|| seconds(false));
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

pub fn evaluate(gpu: Gpu, args: &EvaluateArgs) -> anyhow::Result<()> {
    let began = Instant::now();
    let gpu = Arc::new(gpu);
    let config = read_run_config(args.config.as_deref(), None)?;
    let (models, secs) = models_from(&args.models)?;
    let mut report = Report {
        title: "IASTGCN evaluation".into(),
        adapter: gpu.info().name.clone(),
        setup: vec![
            format!(
                "models: {}",
                args.models
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            format!(
                "recordings: {}",
                args.data
                    .data
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
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
                args.held_out.held_out_minutes, args.held_out.held_out_seed, args.held_out.every
            ),
        ],
        ..Report::default()
    };
    evaluate_into(
        &gpu,
        &mut report,
        &models,
        &secs,
        &args.data,
        &config,
        &args.held_out,
        &args.out,
    )?;
    report.wall_seconds = began.elapsed().as_secs_f64();
    report::write(&args.out, &report)?;
    Ok(())
}

pub fn demo(gpu: Gpu, args: &DemoArgs) -> anyhow::Result<()> {
    let began = Instant::now();
    let gpu = Arc::new(gpu);
    let config = match &args.config {
        Some(p) => read_run_config(Some(p), None)?,
        None => RunConfig::demo(),
    };
    let out = &args.out;
    let data_dir = out.join("data");
    let model_dir = out.join("models");
    std::fs::create_dir_all(&data_dir).with_context(|| data_dir.display().to_string())?;
    std::fs::create_dir_all(&model_dir).with_context(|| model_dir.display().to_string())?;
    println!("demo on {} → {}", gpu.info().name, out.display());

    banner("1/6 twin: calibration measurements (a cold machine at rest)");
    let set = data_dir.join("calibration_set.csv");
    simulate::run(&SimulateArgs {
        trajectory: "calibration".into(),
        rotation: 0.0,
        reverse: false,
        calibration: None,
        minutes: 1.0,
        seed: CALIBRATION_SEED,
        machine_seed: 1,
        robot: None,
        poses: 80,
        out: set.clone(),
        plot: None,
    })?;

    banner("2/6 geometric calibration (EKF)");
    let calibration = data_dir.join("calibration.toml");
    calibrate::run(&CalibrateArgs {
        measurements: set,
        out: calibration.clone(),
        robot: None,
        hold_out_every: 5,
        recordings: Vec::new(),
    })?;

    banner("3/6 training session: three recordings under the calibrated controller");
    let geometry = Geometry::default_asset();
    let machine = draw_machine(geometry.clone(), 1);
    let controller = Robot::new(geometry, file::load(&calibration)?.errors);
    let mut recordings = Vec::new();
    let mut state = machine.cold();
    for (i, kind) in PathKind::TRAINING.into_iter().enumerate() {
        let path = data_dir.join(format!("{}.csv", kind.name()));
        let mut info = RunInfo::polishing(
            kind,
            &PathParams::default(),
            args.minutes * 60.0,
            TRAINING_SEED + i as u64,
        );
        info.controller = calibration.display().to_string();
        state = simulate::record_run(&machine, &controller, info, state, &path, None)?;
        state.idle(IDLE_BETWEEN_RUNS);
        recordings.push(path);
    }

    banner("4/6 dataset");
    let data_args = DataArgs {
        data: recordings,
        calibration,
        graph: None,
        robot: None,
    };
    let (graph, data) = build_dataset(&data_args, &config, None)?;
    print!("{}", data.summary());

    banner("5/6 training and refining IASTGCN and its ablations (the same treatment for each)");
    let mut models: Vec<(String, Checkpoint)> = Vec::new();
    let mut secs = Vec::new();
    let mut histories = Vec::new();
    let mut accumulated = None;
    let mut refinement = Vec::new();
    for variant in [
        Variant::Iastgcn,
        Variant::NoAttention,
        Variant::PlainTemporal,
        Variant::Chebyshev,
    ] {
        let mut c = config.clone();
        c.model.variant = variant;
        let name = variant.name();
        let path = model_dir.join(format!("{name}.safetensors"));
        let init = Parameters::init(&c.model, c.train.seed);
        let mut trainer = Trainer::new(
            &gpu,
            &data,
            &graph,
            &c.model,
            &c.train,
            core_stage(&c),
            &init,
        )?;
        fit(&mut trainer, name, |_, _| Ok(()))?;
        let ck = train::checkpoint(&c.model, &graph, &trainer.best, &data.normalization);
        ck.save(&path)?;
        log::write_csv(
            &super::train::sibling(&path, ".log.csv"),
            &trainer.progress.history,
        )?;
        println!(
            "{}: best validation loss {:.4} at epoch {} of {}",
            variant, trainer.progress.best_val, trainer.progress.best_epoch, trainer.progress.epoch
        );
        secs.push(epoch_seconds(&trainer.progress.history));
        histories.push((name.to_string(), trainer.progress.history.clone()));
        drop(trainer);
        let r = refine_params(&gpu, &data, &graph, &c, &ck.parameters)?;
        let verdict = if r.kept_core {
            "kept the core model"
        } else {
            "kept the refined model"
        };
        println!(
            "{name}: refinement {verdict} (per-window validation loss {:.4} core, {:.4} refined)",
            r.core_val, r.refined_val
        );
        refinement.push(format!(
            "{name}: per-window validation loss {:.4} before refinement, {:.4} after; {verdict}",
            r.core_val, r.refined_val
        ));
        if variant == Variant::Iastgcn {
            print_accumulated(&r.before, &r.after);
            accumulated = Some((r.before.clone(), r.after.clone()));
        }
        let refined = Checkpoint {
            parameters: r.params.clone(),
            ..ck
        };
        let refined_path = model_dir.join(format!("{name}-refined.safetensors"));
        refined.save(&refined_path)?;
        log::write_csv(
            &super::train::sibling(&refined_path, ".log.csv"),
            &r.history,
        )?;
        histories.push((format!("{name}-refined"), r.history.clone()));
        models.push((name.to_string(), refined));
    }

    banner("6/6 evaluation: Tables III and V, report");
    let mut setup = vec![
        format!(
            "config: {} (T = {}, C = {}, L = {}, at most {} epochs, patience {})",
            args.config.as_ref().map_or("assets/demo.toml (embedded)".into(), |p| p.display().to_string()),
            config.model.window,
            config.model.channels,
            config.model.blocks,
            config.train.max_epochs,
            config.train.patience
        ),
        format!(
            "protocol: machine 1; calibration set at rest on a cold machine (seed {CALIBRATION_SEED}); \
             one training session under the calibrated controller, starting cold: grid, fermat, \
             hilbert at their training placement, {} min each, seeds {}–{}, {IDLE_BETWEEN_RUNS} s idle \
             between runs (the machine stays warm); a separate held-out session under the same \
             controller: {} min of warm-up, then every path turned or reversed on the part so that \
             no window retraces a training recording, plus the rosette that training never saw, \
             {} min each, seeds from {}, every stage of a path starting from the same machine \
             state; prediction every {} ticks. Table V scores against the hidden truth and as \
             the tracker measures; Table III scores the test split of the training recordings \
             against the tracker-derived labels",
            args.minutes,
            TRAINING_SEED,
            TRAINING_SEED + 2,
            args.held_out.warm_up_minutes,
            args.held_out.held_out_minutes,
            args.held_out.held_out_seed,
            args.held_out.every
        ),
        "split: contiguous 70/20/10 blocks per recording (leakage-free)".into(),
        "every model is refined the same way and keeps its core weights unless refinement lowers its per-window validation loss".into(),
    ];
    setup.extend(refinement);
    let mut report = Report {
        title: "IASTGCN on the digital twin — demo report".into(),
        adapter: gpu.info().name.clone(),
        setup,
        histories,
        accumulated,
        sections: vec![("Sensor models".into(), sensor_table())],
        ..Report::default()
    };
    let (table_models, table_secs) = (models, secs);
    evaluate_into(
        &gpu,
        &mut report,
        &table_models,
        &table_secs,
        &data_args,
        &config,
        &args.held_out,
        out,
    )?;
    report.wall_seconds = began.elapsed().as_secs_f64();
    report::write(out, &report)?;
    println!("demo finished in {:.0} s", report.wall_seconds);
    Ok(())
}
