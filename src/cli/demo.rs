//! `iastgcn demo` (the main job end to end on the embedded twin) and `iastgcn evaluate`
//! (Tables III and V and the report folder for models you trained): arguments, then the
//! library's `experiment::demo`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::Args;

use super::train::read_run_config;
use super::Console;
use iastgcn::data::DataSources;
use iastgcn::experiment::demo::{self, DemoConfig};
use iastgcn::experiment::evaluate::HeldOutConfig;
use iastgcn::gpu::Gpu;
use iastgcn::robot::Description;

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
    #[arg(long, default_value_t = iastgcn::experiment::demo::DEMO_MINUTES)]
    pub minutes: f64,
    /// Training seeds, comma-separated: every model is trained with each, and the tables
    /// report mean ± SD over them with paired comparisons (one seed: a single run).
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Also train and evaluate the spatio-temporal baselines of Table III (ConvLSTM, T-GCN,
    /// EAT-GCN, ST-GAT) at the same budget (beyond the demo's 15 minutes on 2 CPU cores).
    #[arg(long)]
    pub all_models: bool,
    #[command(flatten)]
    pub recipe: super::RecipeArgs,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}

#[derive(Args, Clone)]
pub struct HeldOutArgs {
    /// Length of each held-out compensation run, minutes (default 0.5; 2 for `scale`,
    /// whose held-out runs score every training size).
    #[arg(long)]
    pub held_out_minutes: Option<f64>,
    /// Seed of the first held-out run; the next paths take the following seeds (the
    /// demo's training recordings use 201–203, its calibration set 101).
    #[arg(long, default_value_t = 301)]
    pub held_out_seed: u64,
    /// Minutes of polishing that warm the machine before the held-out session's first
    /// scored run (0: it starts cold).
    #[arg(long, default_value_t = 2.0)]
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks during compensation.
    #[arg(long, default_value_t = 5, value_parser = super::count(1..=10_000))]
    pub every: usize,
}

impl HeldOutArgs {
    /// The session, with the demo's 0.5-minute runs unless `--held-out-minutes` is given.
    pub fn config(&self) -> HeldOutConfig {
        self.config_with_minutes(HeldOutConfig::default().minutes)
    }

    /// The session, with runs of `minutes` unless `--held-out-minutes` is given.
    pub fn config_with_minutes(&self, minutes: f64) -> HeldOutConfig {
        HeldOutConfig {
            minutes: self.held_out_minutes.unwrap_or(minutes),
            seed: self.held_out_seed,
            warm_up_minutes: self.warm_up_minutes,
            every: self.every,
        }
    }
}

#[derive(Args)]
pub struct EvaluateArgs {
    /// Recordings (CSV, docs/twin.md "File formats"), or with a serial arm's description
    /// in `--robot`, its pose files (docs/arms.md).
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Calibration file from `iastgcn calibrate` (the hybrid machine; labels are
    /// residuals under it). A serial arm is calibrated on the training blocks instead.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Sensor graph asset (default: the embedded assets/graph.toml; the hybrid machine).
    #[arg(long)]
    pub graph: Option<PathBuf>,
    /// Robot description (default: the embedded hybrid machine, assets/robot.toml); a
    /// serial arm's (`kind = "serial"`) is calibrated, its residual models trained and
    /// scored on held-out poses.
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
    /// Checkpoints to compare (the hybrid machine; named by file stem; a `<stem>.log.csv`
    /// beside one gives its training time per epoch).
    #[arg(long, num_args = 1..)]
    pub models: Vec<PathBuf>,
    /// A serial arm's desired tool points (CSV: pose,x,y,z and the pose files' channels):
    /// corrected joint targets into `targets.csv`, from the model with the lowest
    /// validation loss.
    #[arg(long)]
    pub targets: Option<PathBuf>,
    /// A serial arm's separate test pose files: --data is cut into 80/20 % training and
    /// validation blocks only, and every pose of these files with a full window is scored
    /// (they serve nothing else: not the calibration, early stopping or model choice).
    #[arg(long, num_args = 1..)]
    pub test: Vec<PathBuf>,
    /// A serial arm's training seeds, comma-separated: every model is trained with each
    /// and the table gives mean ± SD over them (default: the config's `[train] seed`
    /// alone).
    #[arg(long, value_delimiter = ',')]
    pub seeds: Option<Vec<u64>>,
    /// The models to train on a serial arm's residuals, comma-separated.
    #[arg(long, default_value_t = iastgcn::experiment::arm::ARM_MODELS.map(iastgcn::model::Variant::name).join(","))]
    pub train_models: String,
    /// Run config (its [data] table windows the recordings for Table III); for a serial
    /// arm, the residual models' config (default: the embedded assets/arms/residual.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Report folder.
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}

pub fn evaluate(gpu: Gpu, args: &EvaluateArgs) -> anyhow::Result<()> {
    super::make_output_folder("--out", &args.out)?;
    if let Description::Serial(arm) = Description::load_or_default(args.robot.as_deref())? {
        // The arm's models are trained here and its calibration fitted here: flags of
        // the hybrid machine's evaluation would be ignored, so they are refused.
        let robot = args.robot.as_deref().unwrap_or(Path::new("")).display();
        let unused = [
            (
                !args.models.is_empty(),
                "--models",
                "its residual models are trained here (--train-models picks them)",
            ),
            (
                args.calibration.is_some(),
                "--calibration",
                "it is calibrated here on the training blocks of its pose files",
            ),
            (
                args.graph.is_some(),
                "--graph",
                "its sensor graph comes from its description",
            ),
        ];
        if let Some((_, flag, why)) = unused.iter().find(|u| u.0) {
            anyhow::bail!("{flag} does not apply to a serial arm (--robot {robot}): {why}");
        }
        return super::arm::evaluate(Arc::new(gpu), &arm, args);
    }
    anyhow::ensure!(
        args.targets.is_none(),
        "--targets is for a serial arm's corrected joint targets: give its description in --robot"
    );
    anyhow::ensure!(
        args.seeds.is_none(),
        "--seeds is for a serial arm's residual models, trained here: give its description in --robot (the hybrid machine's evaluation scores the checkpoints of --models; `demo` and `reproduce` train over seeds)"
    );
    anyhow::ensure!(
        args.test.is_empty(),
        "--test is for a serial arm's separate test poses: give its description in --robot (the hybrid machine's Table V scores held-out runs in the twin)"
    );
    let calibration = args.calibration.clone().ok_or_else(|| {
        anyhow::anyhow!("--calibration is required (or give a serial arm's description in --robot)")
    })?;
    anyhow::ensure!(
        !args.models.is_empty(),
        "--models is required: the checkpoints to compare (or give a serial arm's description in --robot)"
    );
    let config = read_run_config(args.config.as_deref(), None)?;
    let sources = DataSources {
        recordings: args.data.clone(),
        calibration,
        graph: args.graph.clone(),
        robot: args.robot.clone(),
    };
    demo::evaluation_report(
        Arc::new(gpu),
        &args.models,
        &sources,
        &config,
        &args.held_out.config(),
        &args.out,
        &mut Console::default(),
    )?;
    Ok(())
}

pub fn demo(gpu: Gpu, args: &DemoArgs) -> anyhow::Result<()> {
    let mut config = DemoConfig {
        minutes: args.minutes,
        held_out: args.held_out.config(),
        all_models: args.all_models,
        seeds: args.seeds.clone(),
        recipe: args.recipe.recipe()?,
        ..DemoConfig::default()
    };
    if let Some(p) = &args.config {
        config.run = read_run_config(Some(p), None)?;
        config.run_source = p.display().to_string();
    }
    let report = demo::demo(Arc::new(gpu), &config, &args.out, &mut Console::default())?;
    println!("demo finished in {:.0} s", report.wall_seconds);
    Ok(())
}
