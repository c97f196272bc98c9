//! `iastgcn polish`: the mirror study (docs/polishing.md): the same starting surfaces
//! polished under the nominal and calibrated controllers, each model compensating
//! online, the oracle and a perfect machine; Table VI, Fig. 13 and Fig. 14.

use std::path::PathBuf;

use anyhow::Context;

use super::compensate::{named_checkpoints, RunArgs};
use super::Console;
use iastgcn::compensate::held_out::Prepared;
use iastgcn::experiment::evaluate::predictors;
use iastgcn::experiment::polish::{self, PolishSpec};
use iastgcn::polish::{Polisher, Setup, StartingPoint};
use iastgcn::progress::Reporter;

#[derive(clap::Args)]
pub struct PolishArgs {
    /// Checkpoints that compensate online (each polishes the surfaces on its own); none:
    /// only the nominal and calibrated controllers, the oracle and a perfect machine.
    #[arg(long, num_args = 1..)]
    pub model: Vec<PathBuf>,
    /// Calibration file (the controller's model).
    #[arg(long)]
    pub calibration: PathBuf,
    /// Path the pad walks: grid, fermat, hilbert or rosette, at its held-out placement.
    #[arg(long, default_value = "grid", value_parser = ["grid", "fermat", "hilbert", "rosette"])]
    pub trajectory: String,
    /// Polishing iterations (measure, plan the dwell, polish) per surface and controller.
    #[arg(long, default_value_t = 3, value_parser = super::count(1..=100))]
    pub iterations: usize,
    /// Seeds of the starting surfaces, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub surface_seeds: Vec<u64>,
    /// Seed of the polishing runs (the same for every controller).
    #[arg(long, default_value_t = 501)]
    pub seed: u64,
    /// Minutes of polishing that warm the machine up before each iteration.
    #[arg(long, default_value_t = 2.0)]
    pub warm_up_minutes: f64,
    /// Map pixel size, mm (2 mm: a 284 × 284 map).
    #[arg(long, default_value_t = 2.0)]
    pub pixel_mm: f64,
    /// Diameter over which PV and RMS are judged, mm (the mirror is 510 mm).
    #[arg(long, default_value_t = iastgcn::polish::CLEAR_APERTURE)]
    pub clear_aperture_mm: f64,
    /// Predict every this many control ticks (the correction is held in between).
    #[arg(long, default_value_t = 5, value_parser = super::count(1..=10_000))]
    pub every: usize,
    /// Seed of the machine (the twin's default machine is 1).
    #[arg(long, default_value_t = 1)]
    pub machine_seed: u64,
    /// Output folder: polish.md, polish.csv, convergence.png, maps.png.
    #[arg(long, default_value = "polish")]
    pub out: PathBuf,
}

pub fn run(adapter: Option<&str>, args: &PolishArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.warm_up_minutes.is_finite() && args.warm_up_minutes >= 0.0,
        "--warm-up-minutes must be ≥ 0, got {}",
        args.warm_up_minutes
    );
    anyhow::ensure!(
        !args.surface_seeds.is_empty(),
        "--surface-seeds: give at least one seed"
    );
    super::make_output_folder("--out", &args.out)?;
    let run_args = RunArgs {
        calibration: args.calibration.clone(),
        trajectory: args.trajectory.clone(),
        minutes: 1.0,
        warm_up_minutes: 0.0,
        seed: args.seed,
        machine_seed: args.machine_seed,
        robot: None,
        rotation: None,
        reverse: false,
    };
    run_args.warn_other_machine()?;
    let Prepared {
        machine,
        nominal,
        calibrated,
        ..
    } = run_args.spec()?.prepare()?;
    let mut setup = Setup::new(args.trajectory.parse().map_err(anyhow::Error::msg)?);
    setup.pitch = args.pixel_mm;
    setup.clear_aperture = args.clear_aperture_mm;
    let mut polisher = Polisher::new(setup).context("--pixel-mm")?;
    let checkpoints = named_checkpoints(&args.model)?;
    // The removal's and the dwell solve's WGSL kernels on a GPU; the models on whatever
    // device runs them best.
    let device = super::open_device(adapter)?;
    polisher.run_on(&device)?;
    eprintln!(
        "removal laid on {}, dwell solved on {}",
        polisher.removal_device(),
        polisher.solve_device()
    );
    let (mut models, window) = match checkpoints.first() {
        Some((_, first)) => (predictors(&device, &checkpoints)?, first.config.window),
        None => (Vec::new(), 48),
    };
    let spec = PolishSpec {
        iterations: args.iterations,
        surface_seeds: args.surface_seeds.clone(),
        seed: args.seed,
        warm_up_minutes: args.warm_up_minutes,
        every: args.every,
        start: StartingPoint::default(),
        split_nominal: true,
    };
    let mut console = Console::default();
    let result = polish::run(
        &mut polisher,
        &spec,
        &machine,
        &nominal,
        &calibrated,
        &mut models,
        window,
        &mut console,
    )
    .context("polishing")?;
    console.end();
    polish::write(&args.out, &spec, &polisher, &result)?;
    println!("{}", polish::report(&spec, &polisher, &result));
    println!("written to {}", args.out.display());
    Ok(())
}
