//! `iastgcn compensate`: run a held-out polishing path in the twin three ways (nominal
//! controller, calibrated controller, calibrated controller compensating online with each
//! model) and print the Table V rows.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use indicatif::ProgressBar;

use crate::calibrate::file;
use crate::compensate::evaluate::{predictors, table_v, warm_up, HeldOut, HeldOutResult};
use crate::compensate::online::Online;
use crate::compensate::report::TableVRow;
use crate::gpu::Gpu;
use crate::model::Checkpoint;
use crate::robot::{Geometry, Robot};
use crate::twin::{draw_machine, Machine, PathKind, PathParams};

#[derive(clap::Args)]
pub struct CompensateArgs {
    /// Checkpoints to compensate with (each gets its own run).
    #[arg(long, num_args = 1.., required = true)]
    pub model: Vec<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
    /// Predict every this many control ticks (the correction is held in between).
    #[arg(long, default_value_t = 1)]
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

/// A held-out run ready to go: the machine, both controllers, and the run itself (at
/// its held-out placement, starting from the warmed-up machine).
pub struct Prepared {
    pub machine: Machine,
    pub nominal: Robot,
    pub calibrated: Robot,
    pub run: HeldOut,
}

impl RunArgs {
    pub fn prepare(&self) -> anyhow::Result<Prepared> {
        let geometry = match &self.robot {
            Some(p) => Geometry::load(p)?,
            None => Geometry::default_asset(),
        };
        let machine = draw_machine(geometry.clone(), self.machine_seed);
        let nominal = Robot::nominal(geometry.clone());
        let calibrated = Robot::new(geometry, file::load(&self.calibration)?.errors);
        let path: PathKind = self.trajectory.parse().map_err(anyhow::Error::msg)?;
        anyhow::ensure!(
            self.minutes.is_finite() && self.minutes > 0.0,
            "--minutes must be positive, got {}",
            self.minutes
        );
        let start = warm_up(
            &machine,
            &calibrated,
            self.warm_up_minutes * 60.0,
            self.seed ^ 0x5741_524d,
        )
        .context("warm-up run")?;
        let run = HeldOut {
            path,
            params: PathParams::held_out(path),
            seconds: self.minutes * 60.0,
            seed: self.seed,
            start,
        };
        Ok(Prepared {
            machine,
            nominal,
            calibrated,
            run,
        })
    }
}

/// A progress bar over control ticks.
pub fn tick_bar(len: usize, what: &str) -> ProgressBar {
    super::progress_bar(
        len as u64,
        &format!("{what} {{bar:40}} {{pos}}/{{len}} ticks {{elapsed}}"),
    )
}

/// Prints Table V rows.
pub fn print_table_v(rows: &[TableVRow]) {
    println!(
        "{:<10} {:<12} {:<14} {:<7} {:>9} {:>8} {:>9}   {:>8} {:>7} {:>8}",
        "path", "stage", "model", "vs", "pos mean", "SD", "max", "att mean", "SD", "max"
    );
    println!("{:<46} {:>28}   {:>25}", "", "(µm)", "(mdeg)");
    for r in rows {
        for (what, e) in [("truth", &r.truth), ("tracker", &r.tracker)] {
            let (p, a) = (e.position, e.attitude);
            println!(
                "{:<10} {:<12} {:<14} {:<7} {:>9.1} {:>8.1} {:>9.1}   {:>8.2} {:>7.2} {:>8.2}",
                r.trajectory, r.stage, r.model, what, p.mean, p.sd, p.max, a.mean, a.sd, a.max
            );
        }
    }
}

pub fn run(gpu: Gpu, args: &CompensateArgs) -> anyhow::Result<()> {
    let Prepared {
        machine,
        nominal,
        calibrated,
        run,
    } = args.run.prepare()?;
    let path = run.path;
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
    let ticks = run.config().steps();
    let bar = tick_bar(
        ticks * (3 + models.len()),
        &format!("compensating {}", path.name()),
    );
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
        |_| bar.inc(1),
    )
    .context("compensation run")?;
    bar.finish_and_clear();
    print_table_v(&rows);
    for (m, ms) in latency {
        println!(
            "{m}: {ms:.2} ms per online prediction on {}",
            gpu.info().name
        );
    }
    Ok(())
}
