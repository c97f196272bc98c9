//! `iastgcn train`, `iastgcn refine` and `iastgcn predict`: arguments, the library's
//! `train::train`, `train::refine` and `train::predict_recordings`, and their printout.

use std::path::{Path, PathBuf};

use clap::Args;

use super::Console;
use iastgcn::data::DataSources;
use iastgcn::gpu::Device;
use iastgcn::model::Checkpoint;
use iastgcn::train::predict::{overall_metrics, write_predictions};
use iastgcn::train::refine::AccumulatedCurve;
use iastgcn::train::{
    self, build_dataset, predict_recordings, PredictOptions, RunConfig, Subset, TestMetrics,
};

/// Where the data comes from (shared by train, refine, predict and evaluate).
#[derive(Args, Clone)]
pub struct DataArgs {
    /// Recordings (CSV, docs/twin.md "File formats").
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Calibration file from `iastgcn calibrate` (labels are residuals under it).
    #[arg(long)]
    pub calibration: PathBuf,
    /// Sensor graph asset (default: the embedded assets/graph.toml).
    #[arg(long)]
    pub graph: Option<PathBuf>,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
}

impl DataArgs {
    pub fn sources(&self) -> DataSources {
        DataSources {
            recordings: self.data.clone(),
            calibration: self.calibration.clone(),
            graph: self.graph.clone(),
            robot: self.robot.clone(),
        }
    }
}

#[derive(Args)]
pub struct TrainArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// Run config (TOML: [model], [data], [train], [refine]); the paper's values when absent.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the config's variant: iastgcn, iastgcn-a, iastgcn-t, iastgcn-s, or a baseline: convlstm, tgcn, eat-gcn, st-gat, mlp, bkls-ann, ann-bfpa, erc.
    #[arg(long)]
    pub variant: Option<String>,
    /// Override train.max_epochs, the epochs of the whole run (a total count: a resumed
    /// run at epoch 72 needs more than 72 to train further).
    #[arg(long, value_parser = super::count(1..))]
    pub max_epochs: Option<usize>,
    /// Override train.patience, the epochs without a better validation loss before
    /// training stops (e.g. to continue a resumed run that stopped early).
    #[arg(long, value_parser = super::count(1..))]
    pub patience: Option<usize>,
    /// Best checkpoint. Beside it: `<stem>.state.safetensors` (resumable state),
    /// `<stem>.log.csv`, `<stem>.loss.png`; all written atomically after the first epoch,
    /// at most every 2 s after it, and after the last (docs/usage.md).
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
    /// Run config: its [data], [train] and [refine] tables are used; the model's shape and
    /// variant always come from the checkpoint (the config's [model] table is ignored).
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
    /// Checkpoint to run (from `train` or `refine`); its normalisation standardises the
    /// recordings.
    #[arg(long)]
    pub model: PathBuf,
    /// Output CSV: one row per window end with the predicted and (where the tracker
    /// measured) the true residual; beside it a PNG of the position residual traces.
    #[arg(long)]
    pub out: PathBuf,
    /// Steps between window ends (window ends fall on rows the tracker measured when the
    /// recording has tracker data, so every window has a label).
    #[arg(long, default_value_t = 20, value_parser = super::count(1..))]
    pub stride: usize,
    /// Only windows of this contiguous split (70/20/10 of each recording): all, train,
    /// validation, test.
    #[arg(long, default_value = "all", value_parser = ["all", "train", "validation", "test"])]
    pub split: String,
    /// Windows per submit; refused with a smaller batch to try when the adapter
    /// cannot hold it (on a CPU adapter windows run one by one natively).
    #[arg(long, default_value_t = 64, value_parser = super::count(1..))]
    pub batch: usize,
}

/// The run config at `path` (the paper's values when absent), with `variant` overriding
/// its model's.
pub fn read_run_config(path: Option<&Path>, variant: Option<&str>) -> anyhow::Result<RunConfig> {
    Ok(RunConfig::read(path, variant)?)
}

pub fn print_metrics(rows: &[TestMetrics]) {
    println!("test split (per recording)          model MAE µm/mdeg   training-mean MAE µm/mdeg   windows");
    for r in rows {
        let (m, b) = (&r.model, &r.training_mean);
        println!(
            "  {:<34} {:>7.3} / {:<8.3}   {:>7.3} / {:<8.3}        {}",
            r.recording, m.pos_mae, m.att_mae, b.pos_mae, b.att_mae, m.count
        );
    }
}

pub fn train(device: &Device, args: &TrainArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let mut config = read_run_config(args.config.as_deref(), args.variant.as_deref())?;
    if let Some(n) = args.max_epochs {
        config.train.max_epochs = n;
    }
    if let Some(n) = args.patience {
        config.train.patience = n;
    }
    config.validate().map_err(anyhow::Error::msg)?;
    let (graph, data) = build_dataset(&args.data.sources(), &config, None)?;
    print!("{}", data.summary());
    let t = train::train(
        device,
        &data,
        &graph,
        &config,
        &args.out,
        args.resume.as_deref(),
        &mut Console::default(),
    )?;
    println!("stopped: {}", t.stopped);
    println!(
        "best validation loss {:.5} at epoch {} of {}; saved {}",
        t.best_val,
        t.best_epoch,
        t.epochs,
        args.out.display()
    );
    print_metrics(&t.test);
    Ok(())
}

/// Prints the accumulated-error table of a refinement.
pub fn print_accumulated(before: &AccumulatedCurve, after: &AccumulatedCurve) {
    println!("accumulated error over consecutive held-out windows |Σ(ŷ−y)|, position µm / attitude mdeg:");
    println!("  k    before              after");
    for ((k, pb, ab), (_, pa, aa)) in before.iter().zip(after) {
        println!("  {k:<4} {pb:>8.3} / {ab:<8.3}  {pa:>8.3} / {aa:<8.3}");
    }
}

pub fn refine(device: &Device, args: &RefineArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let ck = Checkpoint::load(&args.model)?;
    let config = read_run_config(args.config.as_deref(), None)?;
    let r = train::refine_checkpoint(
        device,
        &args.data.sources(),
        &config,
        &ck,
        &mut Console::default(),
    )?;
    r.save(&ck, &args.out)?;
    print_accumulated(&r.before, &r.after);
    println!("before refinement:");
    print_metrics(&r.metrics_before);
    println!("after refinement:");
    print_metrics(&r.metrics_after);
    println!("{}", r.verdict());
    println!("saved {}", args.out.display());
    Ok(())
}

pub fn predict(device: &Device, args: &PredictArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let ck = Checkpoint::load(&args.model)?;
    let subset: Subset = args.split.parse().map_err(anyhow::Error::msg)?;
    let options = PredictOptions {
        stride: args.stride,
        subset,
        batch: args.batch,
    };
    let results = predict_recordings(device, &ck, &args.data.sources(), &options)?;
    println!("recording                           windows  labelled  pos MAE/RMSE/MAPE           att MAE/RMSE/MAPE");
    let line = |name: &str, windows: String, m: &train::Metrics| {
        println!(
            "  {name:<34} {windows:>6}  {:>8}  {:.3}/{:.3}/{:.2}%   {:.3}/{:.3}/{:.2}%",
            m.count, m.pos_mae, m.pos_rmse, m.pos_mape, m.att_mae, m.att_rmse, m.att_mape
        )
    };
    for r in &results {
        line(&r.recording, r.windows.len().to_string(), &r.metrics);
    }
    line("all", String::new(), &overall_metrics(&results));
    let png = write_predictions(&args.out, &results)?;
    println!(
        "wrote {} (µm, mdeg; MAPE guard: {}% of the mean label norm) and {} (position residual traces, true vs predicted)",
        args.out.display(),
        100.0 * train::metrics::MAPE_GUARD,
        png.display()
    );
    Ok(())
}
