//! `iastgcn dataset`: build the model-ready dataset from recordings and a calibration, and
//! print its summary (windows per split and recording, label statistics).

use std::path::PathBuf;

use crate::calibrate::file;
use crate::data::{expected_channels, Dataset, FeatureConfig, Recording, SplitMode, WindowConfig};
use crate::graph::Graph;
use crate::robot::{Geometry, Robot};

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
    #[arg(long)]
    robot: Option<PathBuf>,
    /// Window length T and stride S.
    #[arg(long, default_value_t = 100)]
    window: usize,
    #[arg(long, default_value_t = 20)]
    stride: usize,
    /// `random` reproduces the paper's protocol (windows leak between splits).
    #[arg(long, default_value = "contiguous", value_parser = ["contiguous", "random"])]
    split: String,
    #[arg(long, default_value_t = 7)]
    seed: u64,
}

pub fn run(args: &DatasetArgs) -> anyhow::Result<()> {
    let graph = match &args.graph {
        Some(p) => Graph::load(p)?,
        None => Graph::default_asset(),
    };
    let geometry = match &args.robot {
        Some(p) => Geometry::load(p)?,
        None => Geometry::default_asset(),
    };
    let cal = file::load(&args.calibration)?;
    let model = Robot::new(geometry, cal.errors);
    let channels = expected_channels(&graph.nodes);
    let channels: Vec<&str> = channels.iter().map(String::as_str).collect();
    let window = WindowConfig {
        length: args.window,
        stride: args.stride,
        ..WindowConfig::default()
    };
    let recordings = args
        .recordings
        .iter()
        .map(|p| {
            Ok((
                p.display().to_string(),
                Recording::read(p, &channels, args.window)?,
            ))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mode = if args.split == "random" {
        SplitMode::Random { seed: args.seed }
    } else {
        SplitMode::Contiguous
    };
    let ds = Dataset::build(
        &recordings,
        &graph,
        &model,
        &FeatureConfig::default(),
        &window,
        mode,
    )?;
    print!("{}", ds.summary());
    Ok(())
}
