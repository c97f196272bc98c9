//! `iastgcn simulate`: run the digital twin and write a recording (or a calibration
//! measurement set), with a progress bar and a PNG of the path and the error traces.

use std::path::PathBuf;

use super::Console;
use iastgcn::data::{record_calibration_set, record_run};
use iastgcn::robot::{Description, Robot};
use iastgcn::twin::{draw_machine, PathKind, PathParams, Recipe, RunInfo};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Path to polish (grid, fermat, hilbert, rosette), `calibration` for static
    /// measurement poses, or `training` for a whole training set into the folder --out
    /// (calibration set, its calibration, and --minutes per path of grid, fermat and
    /// hilbert in the recipe's sessions, as `demo` and `reproduce` record it, open loop).
    /// Required for the hybrid machine; a serial arm's twin measures static poses.
    #[arg(long, value_parser = ["grid", "fermat", "hilbert", "rosette", "calibration", "training"])]
    pub trajectory: Option<String>,
    /// Rotation of the pattern on the part, degrees.
    #[arg(long, default_value_t = 0.0)]
    pub rotation: f64,
    /// Walk the pattern from its other end.
    #[arg(long)]
    pub reverse: bool,
    /// Drive with this calibration's model (default: the nominal model, as an
    /// uncalibrated machine does).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Length of a polishing run, minutes.
    #[arg(long, default_value_t = 5.0)]
    pub minutes: f64,
    /// Seed of the run (sensor noise, force, feed modulation, calibration poses).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Seed of the machine: its geometric errors and non-geometric sources (the twin's
    /// default machine is 1).
    #[arg(long, default_value_t = 1)]
    pub machine_seed: u64,
    /// Robot description (default: the embedded hybrid machine, assets/robot.toml). With
    /// a serial arm's (`kind = "serial"`, docs/arms.md; `--arm` is the same flag) the
    /// twin measures static poses of that arm: a pose CSV and its hidden truth beside it.
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
    /// Number of measurement poses for `--trajectory calibration` or a serial arm.
    #[arg(long, default_value_t = 80)]
    pub poses: usize,
    /// Output CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// PNG of the path and error traces (default: the output path with `.png`).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    #[command(flatten)]
    pub recipe: super::RecipeArgs,
}

pub fn run(args: &SimulateArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let description = Description::load_or_default(args.robot.as_deref())?;
    // Static poses have no plot: refuse --plot rather than ignore it.
    let static_poses = matches!(description, Description::Serial(_))
        || args.trajectory.as_deref() == Some("calibration");
    if let (Some(plot), true) = (&args.plot, static_poses) {
        anyhow::bail!(
            "--plot {}: static measurement poses (a calibration set or a serial arm's poses) \
             have no plot; only a polishing run (--trajectory grid, fermat, hilbert or \
             rosette) writes one",
            plot.display()
        );
    }
    let (geometry, trajectory) = match (description, args.trajectory.as_deref()) {
        (Description::Serial(arm), None) => {
            return super::arm::simulate(&arm, args.poses, args.seed, args.machine_seed, &args.out)
        }
        (Description::Serial(arm), Some(t)) => anyhow::bail!(
            "--trajectory {t}: {} is a serial arm, whose twin measures static poses (--poses); leave --trajectory out",
            arm.spec.name
        ),
        (Description::Hybrid(_), None) => anyhow::bail!(
            "give --trajectory (a polishing path, or `calibration` for static poses), or a serial arm's description in --robot"
        ),
        (Description::Hybrid(geometry), Some(t)) => (geometry, t),
    };
    anyhow::ensure!(
        !args.recipe.closed_loop,
        "--closed-loop: simulate records open loop (closed-loop data need a model in the \
         loop: demo, reproduce and scale record them)"
    );
    let recipe = args.recipe.sessions()?;
    if trajectory == "training" {
        return training_set(args, &recipe);
    }
    anyhow::ensure!(
        !args.recipe.given(),
        "--recipe, --sessions, --placement, --path-order and --open-loop describe a training \
         set: give --trajectory training, or leave them out for a single run (--rotation and \
         --reverse place it)"
    );
    let machine = draw_machine(geometry.clone(), args.machine_seed);
    let (controller, controller_name) = match &args.calibration {
        Some(p) => (
            iastgcn::calibrate::file::calibrated_robot(geometry, p)?,
            p.display().to_string(),
        ),
        None => (Robot::nominal(geometry), "nominal".to_string()),
    };
    let mut console = Console::default();
    if trajectory == "calibration" {
        let mut info = RunInfo::calibration(args.seed);
        info.machine_seed = args.machine_seed;
        info.controller = controller_name;
        let poses = record_calibration_set(
            &machine,
            &controller,
            args.poses,
            &info,
            &args.out,
            &mut console,
        )?;
        println!(
            "wrote {} ({poses} measurement poses, tracker averaged over 10 readings each)",
            args.out.display()
        );
        return Ok(());
    }
    let kind: PathKind = trajectory.parse().map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        args.minutes.is_finite() && args.minutes > 0.0,
        "--minutes must be positive, got {}",
        args.minutes
    );
    let params = PathParams {
        rotation_deg: args.rotation,
        reverse: args.reverse,
        ..PathParams::default()
    };
    let mut info = RunInfo::polishing(kind, &params, args.minutes * 60.0, args.seed);
    info.machine_seed = args.machine_seed;
    info.controller = controller_name;
    let r = record_run(
        &machine,
        &controller,
        info,
        machine.cold(),
        &args.out,
        args.plot.clone(),
        &mut console,
    )?;
    println!(
        "wrote {} ({} rows, {:.0} s, {} tracker samples; seed {}, {} start, controller {})",
        args.out.display(),
        r.rows,
        r.info.seconds,
        r.tracker_samples,
        r.info.seed,
        r.info.start,
        r.info.controller
    );
    println!(
        "twin truth (not in the file): machine {} is off by {:.1} µm and {:.1} mdeg on average",
        r.info.machine_seed,
        r.mean_position_error_mm * 1e3,
        r.mean_attitude_error_deg * 1e3
    );
    println!("plot {}", r.plot.display());
    Ok(())
}

/// `--trajectory training`: the protocol's whole training set into the folder `--out`.
fn training_set(args: &SimulateArgs, recipe: &Recipe) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.robot.is_none() && args.calibration.is_none() && args.plot.is_none(),
        "--trajectory training records the embedded machine's calibration set, calibrates \
         it and drives the training runs with that calibration: leave out --robot, \
         --calibration and --plot (each run writes its PNG beside its CSV)"
    );
    anyhow::ensure!(
        args.rotation == 0.0 && !args.reverse,
        "--trajectory training places its runs by --placement: leave out --rotation and --reverse"
    );
    anyhow::ensure!(
        args.minutes.is_finite() && args.minutes > 0.0,
        "--minutes must be positive, got {}",
        args.minutes
    );
    recipe
        .validate(args.minutes)
        .map_err(|m| anyhow::anyhow!("--sessions: {m}"))?;
    let sources = iastgcn::experiment::protocol::record_data(
        &args.out,
        args.minutes,
        args.machine_seed,
        recipe,
        &mut Console::default(),
    )?;
    println!(
        "wrote a training set of {} recordings ({} min per path in {} session(s), placement \
         {}, path order {}) and {} into {}",
        sources.recordings.len(),
        args.minutes,
        recipe.sessions,
        recipe.placement.name(),
        recipe.path_order.name(),
        sources.calibration.display(),
        args.out.display()
    );
    Ok(())
}
