//! `iastgcn budget`: the error budget of one polishing run in the twin (the hidden
//! tool-pose error split by source, docs/twin.md "Error budget").

use std::path::PathBuf;

use anyhow::Context;

use crate::calibrate::file;
use crate::compensate::budget::{error_budget, markdown};
use crate::compensate::evaluate::warm_up;
use crate::robot::{Geometry, Robot};
use crate::twin::{draw_machine, PathKind, PathParams, SimConfig};

#[derive(clap::Args)]
pub struct BudgetArgs {
    /// Calibration file (the controller's model).
    #[arg(long)]
    pub calibration: PathBuf,
    /// Path to run: grid, fermat, hilbert or rosette.
    #[arg(long, default_value = "hilbert", value_parser = ["grid", "fermat", "hilbert", "rosette"])]
    pub trajectory: String,
    /// Place the path as the held-out runs do (turned or reversed on the part).
    #[arg(long)]
    pub held_out_placement: bool,
    /// Length of the run, minutes.
    #[arg(long, default_value_t = 1.0)]
    pub minutes: f64,
    /// Minutes of polishing that warm the machine up before the run (0: cold).
    #[arg(long, default_value_t = 2.0)]
    pub warm_up_minutes: f64,
    /// Seed of the run.
    #[arg(long, default_value_t = 301)]
    pub seed: u64,
    /// Seed of the machine (the twin's default machine is 1).
    #[arg(long, default_value_t = 1)]
    pub machine_seed: u64,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long)]
    pub robot: Option<PathBuf>,
}

pub fn run(args: &BudgetArgs) -> anyhow::Result<()> {
    let geometry = match &args.robot {
        Some(p) => Geometry::load(p)?,
        None => Geometry::default_asset(),
    };
    let machine = draw_machine(geometry.clone(), args.machine_seed);
    let calibrated = Robot::new(geometry, file::load(&args.calibration)?.errors);
    let path: PathKind = args.trajectory.parse().map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        args.minutes.is_finite() && args.minutes > 0.0,
        "--minutes must be positive, got {}",
        args.minutes
    );
    let start = warm_up(
        &machine,
        &calibrated,
        args.warm_up_minutes * 60.0,
        args.seed ^ 0x5741_524d,
    )
    .context("warm-up run")?;
    let mut config = SimConfig::new(path, args.minutes * 60.0, args.seed);
    if args.held_out_placement {
        config.path_params = PathParams::held_out(path);
    }
    let rows = error_budget(&machine, &calibrated, &config, &start)?;
    println!(
        "error budget of {} ({} min, seed {}, machine {}, {} min warm-up): true tool-pose error by source",
        path.name(),
        args.minutes,
        args.seed,
        args.machine_seed,
        args.warm_up_minutes
    );
    print!("{}", markdown(&rows));
    Ok(())
}
