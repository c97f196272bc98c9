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
use crate::compensate::evaluate::{predictors, table_iii, table_v, HeldOut};
use crate::compensate::online::Online;
use crate::compensate::report::{self, Report, TableIIIRow, Timing};
use crate::data::Dataset;
use crate::gpu::Gpu;
use crate::graph::Graph;
use crate::model::{Checkpoint, Parameters, Variant};
use crate::robot::{Geometry, Robot};
use crate::train::{self, core_stage, log, RunConfig, Trainer};
use crate::twin::{draw_machine, PathKind, SimConfig};

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
    #[arg(long, default_value_t = 0.75)]
    pub held_out_minutes: f64,
    /// Seed of the held-out runs (the training recordings use 11).
    #[arg(long, default_value_t = 12)]
    pub held_out_seed: u64,
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

fn banner(text: &str) {
    println!("\n== {text}");
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
    let mut preds = predictors(gpu, models)?;
    let seconds = held.held_out_minutes * 60.0;
    anyhow::ensure!(seconds > 0.0, "--held-out-minutes must be positive");
    let mut latency = vec![(0.0, 0usize); models.len()];
    for path in PathKind::ALL {
        let run = HeldOut {
            path,
            seconds,
            seed: held.held_out_seed,
        };
        let ticks = SimConfig::new(path, seconds, run.seed).steps();
        let bar = tick_bar(
            ticks * (2 + preds.len()),
            &format!("compensating {}", path.name()),
        );
        let (rows, traces, lat) = table_v(
            &machine,
            &nominal,
            &calibrated,
            &graph,
            &mut preds,
            run,
            Online { every: held.every },
            |_| bar.inc(1),
        )?;
        bar.finish_and_clear();
        print_table_v(&rows);
        report.table_v.extend(rows);
        // Fig. 11 shows before/after: calibration only, and the main model.
        let main = models
            .iter()
            .find(|(n, _)| n == "iastgcn")
            .unwrap_or(&models[0])
            .0
            .clone();
        let keep = format!("compensated ({main})");
        report.traces.extend(
            traces
                .into_iter()
                .filter(|t| t.label == "calibrated" || t.label == keep),
        );
        for (slot, (_, ms)) in latency.iter_mut().zip(lat) {
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

    banner("1/6 twin: calibration measurements and polishing recordings");
    let set = data_dir.join("calibration_set.csv");
    let sim = |trajectory: &str, minutes: f64, out: PathBuf| SimulateArgs {
        trajectory: trajectory.into(),
        minutes,
        seed: 11,
        machine_seed: 1,
        robot: None,
        poses: 80,
        out,
        plot: None,
    };
    simulate::run(&sim("calibration", 1.0, set.clone()))?;
    let recordings: Vec<PathBuf> = PathKind::ALL
        .iter()
        .map(|p| data_dir.join(format!("{}.csv", p.name())))
        .collect();
    for (p, path) in PathKind::ALL.iter().zip(&recordings) {
        simulate::run(&sim(p.name(), args.minutes, path.clone()))?;
    }

    banner("2/6 geometric calibration (EKF)");
    let calibration = data_dir.join("calibration.toml");
    calibrate::run(&CalibrateArgs {
        measurements: set,
        out: calibration.clone(),
        robot: None,
        hold_out_every: 5,
        recordings: recordings.clone(),
    })?;

    banner("3/6 dataset");
    let data_args = DataArgs {
        data: recordings,
        calibration,
        graph: None,
        robot: None,
    };
    let (graph, data) = build_dataset(&data_args, &config, None)?;
    print!("{}", data.summary());

    banner("4/6 training IASTGCN and its ablations");
    let mut models: Vec<(String, Checkpoint)> = Vec::new();
    let mut secs = Vec::new();
    let mut histories = Vec::new();
    let mut core_iastgcn = None;
    for variant in [
        Variant::Iastgcn,
        Variant::NoAttention,
        Variant::PlainTemporal,
        Variant::Chebyshev,
    ] {
        let mut c = config.clone();
        c.model.variant = variant;
        let path = model_dir.join(format!("{}.safetensors", variant.name()));
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
        fit(&mut trainer, variant.name(), |_, _| Ok(()))?;
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
        histories.push((variant.name().to_string(), trainer.progress.history.clone()));
        if variant == Variant::Iastgcn {
            core_iastgcn = Some(ck.clone());
        }
        models.push((variant.name().to_string(), ck));
    }

    banner("5/6 refinement of IASTGCN (sample ensembles, warm start)");
    let core = core_iastgcn.expect("IASTGCN is trained first");
    let r = refine_params(&gpu, &data, &graph, &config, &core.parameters)?;
    print_accumulated(&r.before, &r.after);
    let refined = Checkpoint {
        parameters: r.params.clone(),
        ..core
    };
    let refined_path = model_dir.join("iastgcn-refined.safetensors");
    refined.save(&refined_path)?;
    log::write_csv(
        &super::train::sibling(&refined_path, ".log.csv"),
        &r.history,
    )?;
    histories.push(("iastgcn-refined".into(), r.history.clone()));
    // Table III compares the core models and the refined one; Table V compensates with
    // the refined IASTGCN and the ablations.
    let (mut table_models, mut table_secs) = (models.clone(), secs.clone());
    table_models[0].0 = "iastgcn (core)".into();
    table_models.push(("iastgcn".into(), refined));
    table_secs.push(secs[0]);

    banner("6/6 evaluation: Tables III and V, report");
    let mut report = Report {
        title: "IASTGCN on the digital twin — demo report".into(),
        adapter: gpu.info().name.clone(),
        setup: vec![
            format!(
                "config: {} (T = {}, C = {}, L = {}, at most {} epochs, patience {})",
                args.config.as_ref().map_or("assets/demo.toml (embedded)".into(), |p| p.display().to_string()),
                config.model.window,
                config.model.channels,
                config.model.blocks,
                config.train.max_epochs,
                config.train.patience
            ),
            format!("training recordings: grid, fermat, hilbert, {} min each at 50 Hz, seed 11, machine 1", args.minutes),
            "split: contiguous 70/20/10 blocks per recording (leakage-free)".into(),
            format!(
                "held-out compensation runs: {} min of each path, seed {}, prediction every {} ticks",
                args.held_out.held_out_minutes, args.held_out.held_out_seed, args.held_out.every
            ),
            "\"iastgcn\" is the refined model; \"iastgcn (core)\" the same network before refinement".into(),
        ],
        histories,
        accumulated: Some((r.before.clone(), r.after.clone())),
        ..Report::default()
    };
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
