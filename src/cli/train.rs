//! `iastgcn train`, `iastgcn refine` and `iastgcn predict`: the training stages with
//! progress bars, logs, plots, resumable states and atomic checkpoints, and prediction
//! on recordings with the metrics of Table IV.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::Args;
use indicatif::ProgressBar;

use crate::calibrate::file;
use crate::data::{
    expected_channels, prepare, split, window_ends, Dataset, FeatureConfig, Recording, SplitMode,
    Window, WindowConfig,
};
use crate::gpu::Gpu;
use crate::graph::Graph;
use crate::model::{Checkpoint, Parameters, Predictor, Variant};
use crate::plot::{self, Panel, Series};
use crate::robot::{Geometry, Robot};
use crate::train::{
    self, accumulated_error, consecutive_runs, core_stage, log, refine_stages, Metrics, RunConfig,
    TrainError, TrainState, Trainer,
};

/// Where the data comes from (shared by train, refine and predict).
#[derive(Args, Clone)]
pub struct DataArgs {
    /// Recordings (CSV, docs/twin.md "Recording format").
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Calibration file from `iastgcn calibrate` (labels are residuals under it).
    #[arg(long)]
    pub calibration: PathBuf,
    /// Sensor graph asset (default: the embedded assets/graph.toml).
    #[arg(long)]
    pub graph: Option<PathBuf>,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long)]
    pub robot: Option<PathBuf>,
}

#[derive(Args)]
pub struct TrainArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// Run config (TOML: [model], [data], [train], [refine]); the paper's values when absent.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the config's variant: iastgcn, iastgcn-a, iastgcn-t, iastgcn-s.
    #[arg(long)]
    pub variant: Option<String>,
    /// Override train.max_epochs (e.g. to continue a resumed run further).
    #[arg(long)]
    pub max_epochs: Option<usize>,
    /// Best checkpoint (written atomically whenever the validation loss improves). Beside
    /// it: `<stem>.state.safetensors` (resumable state), `<stem>.log.csv`, `<stem>.loss.png`.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from a training state written by an earlier run.
    #[arg(long)]
    pub resume: Option<PathBuf>,
}

#[derive(Args)]
pub struct RefineArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// Trained checkpoint to warm-start from.
    #[arg(long)]
    pub model: PathBuf,
    /// Run config ([refine] and [train] tables are used; [model] must match the checkpoint's shape).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Refined checkpoint; beside it `<stem>.log.csv`, `<stem>.loss.png`,
    /// `<stem>.accumulated.csv` and `<stem>.accumulated.png` (Fig. 9b).
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Args)]
pub struct PredictArgs {
    #[command(flatten)]
    pub data: DataArgs,
    #[arg(long)]
    pub model: PathBuf,
    /// Output CSV: one row per window end with the predicted and (where the tracker
    /// measured) the true residual; beside it a PNG of the position residual traces.
    #[arg(long)]
    pub out: PathBuf,
    /// Steps between window ends (window ends fall on rows the tracker measured when the
    /// recording has tracker data, so every window has a label).
    #[arg(long, default_value_t = 20)]
    pub stride: usize,
    /// Only windows of this contiguous split (70/20/10 of each recording): all, train,
    /// validation, test.
    #[arg(long, default_value = "all", value_parser = ["all", "train", "validation", "test"])]
    pub split: String,
    /// Windows per submit.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
}

/// The sibling of `out` with `suffix` in place of its extension (`m.safetensors` →
/// `m.state.safetensors`).
pub fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or("model".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}{suffix}"))
}

/// The sensor graph, the calibrated robot and the named recordings.
pub type Inputs = (Graph, Robot, Vec<(String, Recording)>);

/// Graph, calibrated robot and the recordings read with the graph's channels.
pub fn load_inputs(args: &DataArgs, window: usize) -> anyhow::Result<Inputs> {
    let graph = match &args.graph {
        Some(p) => Graph::load(p)?,
        None => Graph::default_asset(),
    };
    let geometry = match &args.robot {
        Some(p) => Geometry::load(p)?,
        None => Geometry::default_asset(),
    };
    let cal = file::load(&args.calibration)?;
    let robot = Robot::new(geometry, cal.errors);
    let channels = expected_channels(&graph.nodes);
    let channels: Vec<&str> = channels.iter().map(String::as_str).collect();
    let recordings = args
        .data
        .iter()
        .map(|p| {
            Ok((
                p.display().to_string(),
                Recording::read(p, &channels, window)?,
            ))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok((graph, robot, recordings))
}

/// The dataset of a run config (optionally standardised with a model's statistics).
pub fn build_dataset(
    args: &DataArgs,
    config: &RunConfig,
    fixed: Option<&crate::data::Normalization>,
) -> anyhow::Result<(Graph, Dataset)> {
    let (graph, robot, recordings) = load_inputs(args, config.model.window)?;
    let window = WindowConfig {
        length: config.model.window,
        stride: config.data.stride,
        ..WindowConfig::default()
    };
    let mode = if config.data.split == "random" {
        SplitMode::Random {
            seed: config.data.split_seed,
        }
    } else {
        SplitMode::Contiguous
    };
    let ds = Dataset::build_normalized(
        &recordings,
        &graph,
        &robot,
        &FeatureConfig::default(),
        &window,
        mode,
        fixed,
    )?;
    // The trainer and the checkpoints check the node count against the model.
    Ok((graph, ds))
}

fn epoch_bar(len: usize, what: &str) -> ProgressBar {
    super::progress_bar(
        len as u64,
        &format!("{what} epoch {{pos}}/{{len}} {{bar:30}} {{elapsed}} {{msg}}"),
    )
}

pub fn read_run_config(path: Option<&Path>, variant: Option<&str>) -> anyhow::Result<RunConfig> {
    let mut config = match path {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::default(),
    };
    if let Some(v) = variant {
        config.model.variant = Variant::parse(v).with_context(|| {
            format!("unknown variant {v:?} (iastgcn, iastgcn-a, iastgcn-t, iastgcn-s)")
        })?;
    }
    Ok(config)
}

/// Every setting that must match for a resumed run (the epoch limit and patience may change).
fn resumable(a: &RunConfig, b: &RunConfig) -> bool {
    let strip = |c: &RunConfig| {
        let mut c = c.clone();
        c.train.max_epochs = 0;
        c.train.patience = 0;
        c.refine = Default::default();
        c
    };
    strip(a) == strip(b)
}

/// Test-split metrics per recording: the model, and predicting the training mean.
pub fn test_metrics(
    trainer: &Trainer,
    data: &Dataset,
) -> Result<Vec<(String, Metrics, Metrics)>, TrainError> {
    let [_, _, test] = data.split_ranges();
    let positions: Vec<usize> = test.collect();
    let pred = train::to_physical(&trainer.predict(&positions)?, &data.normalization);
    Ok(data
        .recordings
        .iter()
        .zip(train::metrics::per_recording(data, &positions, &pred))
        .map(|(name, (model, mean))| (name.clone(), model, mean))
        .collect())
}

pub fn print_metrics(rows: &[(String, Metrics, Metrics)]) {
    println!("test split (per recording)          model MAE µm/mdeg   training-mean MAE µm/mdeg   windows");
    for (name, m, b) in rows {
        println!(
            "  {name:<34} {:>7.3} / {:<8.3}   {:>7.3} / {:<8.3}        {}",
            m.pos_mae, m.att_mae, b.pos_mae, b.att_mae, m.count
        );
    }
}

/// Runs one stage to its end with a bar, saving through `on_epoch`; restores the best weights.
pub fn fit(
    trainer: &mut Trainer,
    label: &str,
    mut on_epoch: impl FnMut(&Trainer, bool) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let bar = epoch_bar(trainer.stage.max_epochs, label);
    bar.set_position(trainer.progress.epoch as u64);
    while !trainer.finished() {
        let (r, improved) = trainer.run_epoch()?;
        bar.set_position(r.epoch as u64);
        bar.set_message(format!(
            "loss {:.4} val {:.4} lr {:.2e} {:.0} win/s{}",
            r.train_loss,
            r.val_loss,
            r.lr,
            r.windows_per_s,
            if improved { " *" } else { "" }
        ));
        on_epoch(trainer, improved)?;
    }
    bar.finish();
    trainer.restore_best()?;
    Ok(())
}

pub fn train(gpu: &Gpu, args: &TrainArgs) -> anyhow::Result<()> {
    let mut config = read_run_config(args.config.as_deref(), args.variant.as_deref())?;
    if let Some(n) = args.max_epochs {
        config.train.max_epochs = n;
    }
    config.validate().map_err(anyhow::Error::msg)?;
    let (graph, data) = build_dataset(&args.data, &config, None)?;
    print!("{}", data.summary());
    let state_path = sibling(&args.out, ".state.safetensors");
    let init = Parameters::init(&config.model, config.train.seed);
    let mut trainer = Trainer::new(
        gpu,
        &data,
        &graph,
        &config.model,
        &config.train,
        core_stage(&config),
        &init,
    )?;
    if let Some(p) = &args.resume {
        let state = TrainState::load(p)?;
        if !resumable(&state.run, &config) {
            bail!(
                "{}: the state was written by a run with another config or variant (only train.max_epochs and train.patience may change)",
                p.display()
            );
        }
        if state.normalization != train::normalization(&data.normalization) {
            bail!(
                "{}: the state was trained on other data (its normalisation statistics differ from these recordings')",
                p.display()
            );
        }
        trainer.restore(&state.snapshot)?;
        trainer.set_limits(config.train.max_epochs, config.train.patience);
        println!(
            "resumed {} at epoch {} (step {}, best validation loss {:.5} at epoch {})",
            p.display(),
            trainer.progress.epoch,
            trainer.progress.step,
            trainer.progress.best_val,
            trainer.progress.best_epoch
        );
    }
    println!(
        "training {} on {}: {} windows per step, {} steps per epoch",
        config.model.variant,
        gpu.info().name,
        trainer.batch(),
        trainer.steps_per_epoch()
    );
    let log_path = sibling(&args.out, ".log.csv");
    let png_path = sibling(&args.out, ".loss.png");
    let result = fit(&mut trainer, config.model.variant.name(), |t, improved| {
        if improved {
            train::checkpoint(&config.model, &graph, &t.best, &data.normalization)
                .save(&args.out)?;
        }
        TrainState {
            run: config.clone(),
            normalization: train::normalization(&data.normalization),
            snapshot: t.snapshot().clone(),
        }
        .save(&state_path)?;
        log::write_csv(&log_path, &t.progress.history)?;
        log::plot_losses(
            &png_path,
            &[(
                config.model.variant.name().to_string(),
                t.progress.history.clone(),
            )],
        )?;
        Ok(())
    });
    if let Err(e) = result {
        return Err(diverged(e, &trainer, &config, &graph, &data, &args.out));
    }
    let p = &trainer.progress;
    println!(
        "best validation loss {:.5} at epoch {} of {}; saved {}",
        p.best_val,
        p.best_epoch,
        p.epoch,
        args.out.display()
    );
    print_metrics(&test_metrics(&trainer, &data)?);
    Ok(())
}

/// On divergence: keep the best checkpoint, or write the last good weights when no epoch
/// finished; say where they are.
fn diverged(
    e: anyhow::Error,
    trainer: &Trainer,
    config: &RunConfig,
    graph: &Graph,
    data: &Dataset,
    out: &Path,
) -> anyhow::Error {
    let Some(TrainError::Diverged { last_good, .. }) = e.downcast_ref::<TrainError>() else {
        return e;
    };
    if trainer.progress.best_epoch > 0 {
        return e.context(format!(
            "stopped; {} keeps the best weights (epoch {})",
            out.display(),
            trainer.progress.best_epoch
        ));
    }
    match train::checkpoint(&config.model, graph, last_good, &data.normalization).save(out) {
        Ok(()) => e.context(format!(
            "stopped; the last good weights (before the bad step) are in {}",
            out.display()
        )),
        Err(w) => e.context(format!(
            "stopped, and the last good weights could not be saved: {w}"
        )),
    }
}

/// Accumulated error curve (Fig. 9b) of the held-out runs with the trainer's weights.
fn accumulated(
    trainer: &Trainer,
    data: &Dataset,
    horizon: usize,
) -> anyhow::Result<Vec<(usize, f64, f64)>> {
    let [_, _, test] = data.split_ranges();
    let runs = consecutive_runs(data, test);
    let positions: Vec<usize> = runs.iter().flatten().copied().collect();
    let pred = train::to_physical(&trainer.predict(&positions)?, &data.normalization);
    let mut i = 0;
    let pairs: Vec<Vec<([f64; 6], [f64; 6])>> = runs
        .iter()
        .map(|run| {
            run.iter()
                .map(|&p| {
                    i += 1;
                    (pred[i - 1], data.labels[p])
                })
                .collect()
        })
        .collect();
    Ok(accumulated_error(&pairs, horizon))
}

/// What a refinement produced.
pub struct Refined {
    pub params: Parameters,
    pub history: Vec<crate::train::EpochRecord>,
    /// Fig. 9b before and after: (k, position µm, attitude mdeg).
    pub before: Vec<(usize, f64, f64)>,
    pub after: Vec<(usize, f64, f64)>,
    pub metrics_before: Vec<(String, Metrics, Metrics)>,
    pub metrics_after: Vec<(String, Metrics, Metrics)>,
    /// Per-window validation loss (the core stage's) of the incoming and of the returned
    /// parameters; they are the incoming ones when refinement did not lower it.
    pub core_val: f64,
    pub refined_val: f64,
    pub kept_core: bool,
}

/// Runs the refinement stages of `config` from `init` (Algorithm 2).
pub fn refine_params(
    gpu: &Gpu,
    data: &Dataset,
    graph: &Graph,
    config: &RunConfig,
    init: &Parameters,
) -> anyhow::Result<Refined> {
    let horizon = config.refine.horizon;
    let mut params = init.clone();
    let mut history = Vec::new();
    let mut before = None;
    let mut last: Option<Trainer> = None;
    for stage in refine_stages(config) {
        let mut trainer = Trainer::new(
            gpu,
            data,
            graph,
            &config.model,
            &config.train,
            stage.clone(),
            &params,
        )?;
        if before.is_none() {
            before = Some((
                accumulated(&trainer, data, horizon)?,
                test_metrics(&trainer, data)?,
            ));
        }
        // A stage keeps what it was given unless its validation loss improves.
        trainer.keep_start_unless_improved()?;
        println!(
            "{}: ensembles of {} windows, {} per step, {} steps per epoch, lr0 {:.1e}",
            stage.name,
            stage.group,
            trainer.batch(),
            trainer.steps_per_epoch(),
            stage.lr0
        );
        fit(&mut trainer, &stage.name, |_, _| Ok(()))?;
        history.extend(trainer.progress.history.iter().cloned());
        params = trainer.best.clone();
        last = Some(trainer);
    }
    let Some(trainer) = last else {
        bail!("refine.magnifications is empty: nothing to refine");
    };
    let (before, metrics_before) = before.expect("set with the first stage");
    // The stages score ensembles; the model is used window by window, so it is kept only
    // if the per-window validation loss improves too.
    let judge = Trainer::new(
        gpu,
        data,
        graph,
        &config.model,
        &config.train,
        core_stage(config),
        init,
    )?;
    let core_val = judge.validation_loss_of(init)?;
    let refined_val = judge.validation_loss_of(&params)?;
    let kept_core = refined_val >= core_val;
    if kept_core {
        params = init.clone();
        trainer.load_parameters(init)?;
    }
    drop(judge);
    Ok(Refined {
        after: accumulated(&trainer, data, horizon)?,
        metrics_after: test_metrics(&trainer, data)?,
        params,
        history,
        before,
        metrics_before,
        core_val,
        refined_val: refined_val.min(core_val),
        kept_core,
    })
}

/// Prints the accumulated-error table of a refinement.
pub fn print_accumulated(before: &[(usize, f64, f64)], after: &[(usize, f64, f64)]) {
    println!("accumulated error over consecutive held-out windows |Σ(ŷ−y)|, position µm / attitude mdeg:");
    println!("  k    before              after");
    for ((k, pb, ab), (_, pa, aa)) in before.iter().zip(after) {
        println!("  {k:<4} {pb:>8.3} / {ab:<8.3}  {pa:>8.3} / {aa:<8.3}");
    }
}

pub fn refine(gpu: &Gpu, args: &RefineArgs) -> anyhow::Result<()> {
    let ck = Checkpoint::load(&args.model)?;
    let mut config = read_run_config(args.config.as_deref(), None)?;
    config.model = ck.config.clone();
    let fixed = train::data_normalization(&ck.normalization)
        .context("the checkpoint's normalisation is not N×3 features and 6 labels")?;
    let (graph, data) = build_dataset(&args.data, &config, Some(&fixed))?;
    let r = refine_params(gpu, &data, &graph, &config, &ck.parameters)?;
    Checkpoint {
        parameters: r.params.clone(),
        ..ck
    }
    .save(&args.out)?;
    log::write_csv(&sibling(&args.out, ".log.csv"), &r.history)?;
    log::plot_losses(
        &sibling(&args.out, ".loss.png"),
        &[("refine".to_string(), r.history.clone())],
    )?;
    write_accumulated(&args.out, &r.before, &r.after)?;
    print_accumulated(&r.before, &r.after);
    println!("before refinement:");
    print_metrics(&r.metrics_before);
    println!("after refinement:");
    print_metrics(&r.metrics_after);
    println!("saved {}", args.out.display());
    Ok(())
}

/// `<stem>.accumulated.csv` and `.png` (Fig. 9b) beside `out`.
fn write_accumulated(
    out: &Path,
    before: &[(usize, f64, f64)],
    after: &[(usize, f64, f64)],
) -> anyhow::Result<()> {
    let path = sibling(out, ".accumulated.csv");
    let csv = crate::compensate::report::accumulated_csv(before, after);
    crate::atomic::write(&path, csv.as_bytes()).with_context(|| path.display().to_string())?;
    crate::compensate::report::plot_accumulated(&sibling(out, ".accumulated.png"), before, after)?;
    Ok(())
}

pub fn predict(gpu: std::sync::Arc<Gpu>, args: &PredictArgs) -> anyhow::Result<()> {
    let ck = Checkpoint::load(&args.model)?;
    let t_len = ck.config.window;
    let (graph, robot, recordings) = load_inputs(&args.data, t_len)?;
    if graph.nodes != ck.graph.nodes {
        bail!(
            "the model was trained on the graph {:?}, the data uses {:?}",
            ck.graph.nodes,
            graph.nodes
        );
    }
    let mut predictor = Predictor::new(gpu, &ck, args.batch.max(1))?;
    let window = WindowConfig {
        length: t_len,
        stride: args.stride.max(1),
        ..WindowConfig::default()
    };
    let mut csv = String::from("recording,row,t,pred_dx_um,pred_dy_um,pred_dz_um,pred_rx_mdeg,pred_ry_mdeg,pred_rz_mdeg,true_dx_um,true_dy_um,true_dz_um,true_rx_mdeg,true_ry_mdeg,true_rz_mdeg\n");
    let mut all = (Vec::new(), Vec::new(), Vec::new());
    let mut panels = Vec::new();
    println!("recording                           windows  labelled  pos MAE/RMSE/MAPE           att MAE/RMSE/MAPE");
    for (name, rec) in &recordings {
        let prepared = prepare(name, rec, &graph, &robot, &FeatureConfig::default())?;
        // On rows the tracker measured when there are any (so windows have labels), as
        // the dataset does; every `stride` rows otherwise.
        let tracked = prepared.labels.iter().any(Option::is_some);
        let ends: Vec<Window> = window_ends(rec.rows.len(), &window, |e| {
            !tracked || prepared.labels[e].is_some()
        })
        .into_iter()
        .map(|end| Window { recording: 0, end })
        .collect();
        let chosen: Vec<Window> = if args.split == "all" {
            ends
        } else {
            let s = split(&ends, &[rec.rows.len()], &window, SplitMode::Contiguous);
            match args.split.as_str() {
                "train" => s.train,
                "validation" => s.validation,
                _ => s.test,
            }
        };
        let mut x = Vec::with_capacity(chosen.len() * predictor.window_len());
        let mut buf = Vec::new();
        for w in &chosen {
            prepared.window(w.end, t_len, &mut buf);
            x.extend_from_slice(&buf);
        }
        let mut out = Vec::new();
        predictor.predict_batch(&x, &mut out)?;
        let (mut pred, mut truth, mut axes) = (Vec::new(), Vec::new(), Vec::new());
        for (w, y) in chosen.iter().zip(&out) {
            let label = prepared.labels[w.end];
            csv += &format!("{name},{},{:.4}", w.end, rec.rows[w.end].t);
            for v in y {
                csv += &format!(",{v:.4}");
            }
            for k in 0..6 {
                match label {
                    Some(l) => csv += &format!(",{:.4}", l[k]),
                    None => csv += ",",
                }
            }
            csv.push('\n');
            if let (Some(l), Some(a)) = (label, prepared.axes[w.end]) {
                pred.push(*y);
                truth.push(l);
                axes.push(a);
            }
        }
        let m = Metrics::of(&pred, &truth, &axes);
        println!(
            "  {name:<34} {:>6}  {:>8}  {:.3}/{:.3}/{:.2}%   {:.3}/{:.3}/{:.2}%",
            chosen.len(),
            truth.len(),
            m.pos_mae,
            m.pos_rmse,
            m.pos_mape,
            m.att_mae,
            m.att_rmse,
            m.att_mape
        );
        let times: Vec<f64> = chosen
            .iter()
            .filter(|w| prepared.labels[w.end].is_some())
            .map(|w| rec.rows[w.end].t)
            .collect();
        let short = Path::new(name)
            .file_stem()
            .map_or(name.clone(), |s| s.to_string_lossy().into_owned());
        for (k, axis) in ["dx", "dy", "dz"].iter().enumerate() {
            let line = |v: &[[f64; 6]]| times.iter().zip(v).map(|(t, r)| (*t, r[k])).collect();
            panels.push(Panel {
                title: format!("{short}: {axis}"),
                x_label: "t (s)".into(),
                y_label: "µm".into(),
                series: vec![
                    Series::new("true", line(&truth)),
                    Series::new("predicted", line(&pred)),
                ],
                equal_aspect: false,
            });
        }
        all.0.extend(pred);
        all.1.extend(truth);
        all.2.extend(axes);
    }
    let m = Metrics::of(&all.0, &all.1, &all.2);
    println!(
        "  {:<34} {:>6}  {:>8}  {:.3}/{:.3}/{:.2}%   {:.3}/{:.3}/{:.2}%",
        "all", "", m.count, m.pos_mae, m.pos_rmse, m.pos_mape, m.att_mae, m.att_rmse, m.att_mape
    );
    crate::atomic::write(&args.out, csv.as_bytes())
        .with_context(|| args.out.display().to_string())?;
    let png = args.out.with_extension("png");
    let rows = panels.len() / 3;
    plot::draw(
        &png,
        &panels,
        rows.max(1),
        3,
        (1500, 330 * rows.max(1) as u32),
    )?;
    println!(
        "wrote {} (µm, mdeg; MAPE guard: {}% of the mean label norm) and {} (position residual traces, true vs predicted)",
        args.out.display(),
        100.0 * train::metrics::MAPE_GUARD,
        png.display()
    );
    Ok(())
}
