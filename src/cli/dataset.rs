//! `iastgcn dataset`: build the model-ready dataset from recordings and a calibration, and
//! print its summary (windows per split and recording, label statistics).

use std::path::PathBuf;

use iastgcn::data::DataSources;
use iastgcn::model::ModelConfig;
use iastgcn::train::build_dataset;
use iastgcn::train::{DataConfig, RunConfig};

#[derive(clap::Args)]
pub struct DatasetArgs {
    /// Recordings (CSV).
    #[arg(long, num_args = 1.., required = true)]
    recordings: Vec<PathBuf>,
    /// Calibration file from `iastgcn calibrate` (labels are residuals under it).
    #[arg(long)]
    calibration: PathBuf,
    /// Sensor graph asset (default: the embedded assets/graph.toml).
    #[arg(long)]
    graph: Option<PathBuf>,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long, visible_alias = "arm")]
    robot: Option<PathBuf>,
    /// Window length T: the steps each window holds (model.window of a run config).
    #[arg(long, default_value_t = 100, value_parser = super::count(1..=1 << 20))]
    window: usize,
    /// Stride S: the steps between consecutive window ends (data.stride of a run config).
    #[arg(long, default_value_t = 20, value_parser = super::count(1..))]
    stride: usize,
    /// `random` reproduces the paper's protocol (windows leak between splits).
    #[arg(long, default_value = "contiguous", value_parser = ["contiguous", "random"])]
    split: String,
    /// Seed of the shuffle of `--split random` (data.split_seed of a run config).
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Share of each recording's training block kept, from its start (0, 1].
    #[arg(long, default_value_t = 1.0)]
    train_fraction: f64,
    /// Share of each recording's validation block kept, from its start (0, 1].
    #[arg(long, default_value_t = 1.0)]
    validation_fraction: f64,
}

pub fn run(args: &DatasetArgs) -> anyhow::Result<()> {
    let config = RunConfig {
        model: ModelConfig {
            window: args.window,
            ..ModelConfig::default()
        },
        data: DataConfig {
            stride: args.stride,
            split: args.split.clone(),
            split_seed: args.seed,
            train_fraction: args.train_fraction,
            validation_fraction: args.validation_fraction,
            ..DataConfig::default()
        },
        ..RunConfig::default()
    };
    let data = DataSources {
        recordings: args.recordings.clone(),
        calibration: args.calibration.clone(),
        graph: args.graph.clone(),
        robot: args.robot.clone(),
    };
    config.validate().map_err(anyhow::Error::msg)?;
    let (_, ds) = build_dataset(&data, &config, None)?;
    print!("{}", ds.summary());
    Ok(())
}
