//! `iastgcn compensate`: run a held-out polishing path in the twin three ways (nominal
//! controller, calibrated controller, calibrated controller compensating online with each
//! model) and print the Table V rows.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;

use super::Console;
use iastgcn::compensate::held_out::{Prepared, RunSpec};
use iastgcn::compensate::online::Online;
use iastgcn::experiment::evaluate::{predictors, table_v, HeldOutResult};
use iastgcn::experiment::report::table_v_lines;
use iastgcn::gpu::Gpu;
use iastgcn::model::Checkpoint;
use iastgcn::progress::Reporter;

#[derive(clap::Args)]
pub struct CompensateArgs {
    /// Checkpoints to compensate with (each gets its own run).
    #[arg(long, num_args = 1.., required = true)]
    pub model: Vec<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
    /// Predict every this many control ticks (the correction is held in between).
    #[arg(long, default_value_t = 1, value_parser = super::count(1..=10_000))]
    pub every: usize,
}

/// One held-out run in the twin: shared by `compensate` and `budget`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Calibration file (the controller's model).
    #[arg(long)]
    pub calibration: PathBuf,
    /// Path to run: grid, fermat, hilbert (placed as the held-out runs place them, never
    /// retracing a training recording) or rosette (never in training).
    #[arg(long, default_value = "hilbert", value_parser = ["grid", "fermat", "hilbert", "rosette"])]
    pub trajectory: String,
    /// Length of the run, minutes.
    #[arg(long, default_value_t = 1.0)]
    pub minutes: f64,
    /// Minutes of polishing that warm the machine up before the run (0: cold).
    #[arg(long, default_value_t = 2.0)]
    pub warm_up_minutes: f64,
    /// Seed of the run (use one the training recordings did not).
    #[arg(long, default_value_t = 12)]
    pub seed: u64,
    /// Seed of the machine (the twin's default machine is 1).
    #[arg(long, default_value_t = 1)]
    pub machine_seed: u64,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long)]
    pub robot: Option<PathBuf>,
}

impl RunArgs {
    pub fn spec(&self) -> anyhow::Result<RunSpec> {
        Ok(RunSpec {
            calibration: self.calibration.clone(),
            path: self.trajectory.parse().map_err(anyhow::Error::msg)?,
            minutes: self.minutes,
            warm_up_minutes: self.warm_up_minutes,
            seed: self.seed,
            machine_seed: self.machine_seed,
            robot: self.robot.clone(),
        })
    }
}

pub fn run(gpu: Gpu, args: &CompensateArgs) -> anyhow::Result<()> {
    let Prepared {
        machine,
        nominal,
        calibrated,
        run,
    } = args.run.spec()?.prepare()?;
    let checkpoints = args
        .model
        .iter()
        .map(|p| {
            let ck = Checkpoint::load(p)?;
            let name = p
                .file_stem()
                .map_or("model".into(), |s| s.to_string_lossy().into_owned());
            Ok((name, ck))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let graph = checkpoints[0].1.graph.clone();
    let gpu = Arc::new(gpu);
    let mut models = predictors(&gpu, &checkpoints)?;
    let ticks = run.config().steps() * (3 + models.len());
    let mut console = Console::default();
    console.begin(
        &format!("compensating {} (ticks)", run.path.name()),
        ticks as u64,
    );
    let mut done = 0u64;
    let window = checkpoints[0].1.config.window;
    let HeldOutResult { rows, latency, .. } = table_v(
        &machine,
        &nominal,
        &calibrated,
        &graph,
        window,
        &mut models,
        &run,
        Online { every: args.every },
        |_| {
            done += 1;
            if done.is_multiple_of(50) {
                console.update(done, "");
            }
        },
    )
    .context("compensation run")?;
    console.end();
    for line in table_v_lines(&rows) {
        println!("{line}");
    }
    for (m, ms) in latency {
        println!(
            "{m}: {ms:.2} ms per online prediction on {}",
            gpu.info().name
        );
    }
    Ok(())
}
