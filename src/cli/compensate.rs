//! `iastgcn compensate`: run a held-out polishing path in the twin three ways (nominal
//! controller, calibrated controller, calibrated controller compensating online with each
//! model) and print the Table V rows.

use std::path::PathBuf;

use anyhow::Context;

use super::Console;
use iastgcn::compensate::held_out::{Prepared, RunSpec};
use iastgcn::compensate::online::Online;
use iastgcn::experiment::evaluate::{predictors, runs_at_a_time, table_v, HeldOutResult};
use iastgcn::experiment::report::table_v_lines;
use iastgcn::gpu::Device;
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
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
    /// Turn the path this many degrees on the part instead of its held-out placement
    /// (the held-out margin kept); nothing checks that it keeps clear of the training
    /// recordings.
    #[arg(long)]
    pub rotation: Option<f64>,
    /// Walk the path from its other end (with --rotation; 0 when absent).
    #[arg(long)]
    pub reverse: bool,
}

impl RunArgs {
    /// Warns on stderr when the calibration file says its measurement set came from
    /// another twin machine than `--machine-seed`.
    pub fn warn_other_machine(&self) -> anyhow::Result<()> {
        let cal = iastgcn::calibrate::file::load(&self.calibration)?;
        if let Some(m) = cal.machine_seed.filter(|&m| m != self.machine_seed) {
            eprintln!(
                "warning: the calibration {} was measured on twin machine {m}, but this run is \
                 on machine {} (--machine-seed): the calibrated controller carries another \
                 machine's geometric errors",
                self.calibration.display(),
                self.machine_seed
            );
        }
        Ok(())
    }

    pub fn spec(&self) -> anyhow::Result<RunSpec> {
        Ok(RunSpec {
            calibration: self.calibration.clone(),
            path: self.trajectory.parse().map_err(anyhow::Error::msg)?,
            minutes: self.minutes,
            warm_up_minutes: self.warm_up_minutes,
            seed: self.seed,
            machine_seed: self.machine_seed,
            robot: self.robot.clone(),
            placement: self.placement()?,
        })
    }

    /// The placement `--rotation` and `--reverse` ask for, on the held-out margin; `None`
    /// (the held-out placement) without either.
    fn placement(&self) -> anyhow::Result<Option<iastgcn::twin::PathParams>> {
        if self.rotation.is_none() && !self.reverse {
            return Ok(None);
        }
        let rotation_deg = self.rotation.unwrap_or(0.0);
        anyhow::ensure!(
            rotation_deg.is_finite(),
            "--rotation: a finite angle in degrees, got {rotation_deg}"
        );
        let path = self.trajectory.parse().map_err(anyhow::Error::msg)?;
        Ok(Some(iastgcn::twin::PathParams {
            rotation_deg: rotation_deg.rem_euclid(360.0),
            reverse: self.reverse,
            ..iastgcn::twin::PathParams::held_out(path)
        }))
    }
}

/// The checkpoints at `paths`, each named by its file stem (the tables' model names).
pub fn named_checkpoints(paths: &[PathBuf]) -> anyhow::Result<Vec<(String, Checkpoint)>> {
    paths
        .iter()
        .map(|p| {
            let ck = Checkpoint::load(p)?;
            let name = p
                .file_stem()
                .map_or("model".into(), |s| s.to_string_lossy().into_owned());
            Ok((name, ck))
        })
        .collect()
}

pub fn run(device: Device, args: &CompensateArgs) -> anyhow::Result<()> {
    args.run.warn_other_machine()?;
    let Prepared {
        machine,
        nominal,
        calibrated,
        run,
    } = args.run.spec()?.prepare()?;
    let checkpoints = named_checkpoints(&args.model)?;
    let mut models = predictors(&device, &checkpoints)?;
    // Where each model predicts: the native CPU forward on a CPU adapter, else the adapter.
    let ran_on: Vec<String> = models.iter().map(|m| m.runs_on(&device)).collect();
    let sharing = runs_at_a_time(&models);
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
        window,
        &mut models,
        &run,
        Online { every: args.every },
        true,
        |_| {
            done += 1;
            if done.is_multiple_of(50) {
                console.update(done, "");
            }
        },
    )
    .context("compensation run")?;
    console.end();
    println!(
        "{} turned {}°{}",
        run.path.name(),
        run.params.rotation_deg,
        if run.params.reverse {
            ", walked from its other end"
        } else {
            ""
        }
    );
    for line in table_v_lines(&rows) {
        println!("{line}");
    }
    for ((m, ms), on) in latency.iter().zip(&ran_on) {
        println!("{m}: {ms:.2} ms per online prediction on {on}");
    }
    if sharing > 1 {
        println!("(the runs went {sharing} at a time, one per core: each time was taken beside another run)");
    }
    Ok(())
}
