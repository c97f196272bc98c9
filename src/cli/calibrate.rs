//! `iastgcn calibrate`: EKF calibration from a measurement set, with a report of the pose
//! error before and after on held-out poses and on polishing recordings (Table V's first
//! two rows).

use std::path::PathBuf;

use anyhow::Context;
use indicatif::ProgressBar;

use iastgcn::calibrate::{self, file, hold_out, pose_errors, EkfConfig};
use iastgcn::data::{read_measurements, recording_measurements};
use iastgcn::robot::{Description, Robot};
use iastgcn::stats::Summary;

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Calibration measurement set (CSV: q1..q5, x,y,z,rx,ry,rz), or with a serial arm's
    /// description in `--robot`, its pose file (docs/arms.md).
    #[arg(long, visible_alias = "data")]
    pub measurements: PathBuf,
    /// Output calibration file (TOML).
    #[arg(long)]
    pub out: PathBuf,
    /// Robot description (default: the embedded hybrid machine, assets/robot.toml): its
    /// `kind` picks the chain; a serial arm's (`kind = "serial"`, docs/arms.md) writes
    /// the calibrated description to `--out`.
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
    /// Every how many measurements one is held out for the report (0: none).
    #[arg(long, default_value_t = 5)]
    pub hold_out_every: usize,
    /// A separate file of test poses (same format as --data) to score instead of held-out
    /// ones: every pose of --data is fitted, and the test poses are used for nothing but
    /// the report (not the fit, not the registration).
    #[arg(long, conflicts_with = "hold_out_every")]
    pub test: Option<PathBuf>,
    /// Polishing recordings to report the error on before and after calibration.
    #[arg(long, num_args = 1..)]
    pub recordings: Vec<PathBuf>,
}

fn row(label: &str, stage: &str, (p, a): &(Vec<f64>, Vec<f64>)) -> String {
    let (Some(p), Some(a)) = (Summary::of(p), Summary::of(a)) else {
        return format!("{label:<22} {stage:<11} (no poses)");
    };
    format!(
        "{label:<22} {stage:<11} {:>8.1} {:>8.1} {:>8.1}   {:>7.1} {:>7.1} {:>7.1}",
        p.mean, p.sd, p.max, a.mean, a.sd, a.max
    )
}

/// How the poses of `--data` are scored: held out every few, or a separate test file.
pub enum Scoring {
    /// Every how many poses one is held out (0: none).
    HoldOutEvery(usize),
    /// Every pose is fitted; this file's poses are scored.
    TestFile(PathBuf),
}

fn split(args: &CalibrateArgs) -> Scoring {
    match &args.test {
        Some(t) => Scoring::TestFile(t.clone()),
        None => Scoring::HoldOutEvery(args.hold_out_every),
    }
}

/// `: NAME` of a test file, for the report's row label.
pub fn test_name(path: &std::path::Path) -> String {
    path.file_name()
        .map_or(String::new(), |n| format!(": {}", n.to_string_lossy()))
}

pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let geometry = match Description::load_or_default(args.robot.as_deref())? {
        Description::Hybrid(geometry) => geometry,
        Description::Serial(arm) => {
            return super::arm::calibrate(&arm, &args.measurements, &split(args), &args.out);
        }
    };
    let nominal = Robot::nominal(geometry);
    // The set's sidecar names the twin machine it was measured on; the file keeps it so
    // that an evaluation on another machine can warn.
    let sidecar = iastgcn::twin::RunInfo::sidecar(&args.measurements);
    let machine_seed = if sidecar.exists() {
        Some(
            iastgcn::twin::RunInfo::read(&args.measurements)
                .map_err(anyhow::Error::msg)?
                .machine_seed,
        )
    } else {
        None
    };
    let all = read_measurements(&args.measurements)?;
    let (fit, held) = match &args.test {
        Some(test) => (all, read_measurements(test)?),
        None => hold_out(&all, args.hold_out_every),
    };
    let spinner = ProgressBar::new_spinner().with_message(format!("EKF on {} poses", fit.len()));
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let cal = calibrate::calibrate(&nominal, &fit, &EkfConfig::default())
        .with_context(|| format!("calibrating from {}", args.measurements.display()))?;
    spinner.finish_and_clear();
    // Every recording is read before anything is written, so a bad one leaves no file.
    let recordings = args
        .recordings
        .iter()
        .map(|p| Ok((p, recording_measurements(p)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    // The error table is computed before the calibration file is written: a
    // recording the robot cannot follow fails the command with no file replaced.
    let calibrated = nominal.with_errors(cal.errors.clone());
    let mut rows = Vec::new();
    if !held.is_empty() {
        let label = match &args.test {
            Some(t) => format!("test file ({})", held.len()) + &test_name(t),
            None => format!("held-out poses ({})", held.len()),
        };
        rows.push(row(&label, "initial", &pose_errors(&nominal, &held)?));
        rows.push(row("", "calibrated", &pose_errors(&calibrated, &held)?));
    } else {
        // --hold-out-every 0: nothing held out, so the fitted poses (an optimistic score:
        // the filter saw them) rather than an empty table.
        let label = format!("fitted poses ({})", fit.len());
        rows.push(row(&label, "initial", &pose_errors(&nominal, &fit)?));
        rows.push(row("", "calibrated", &pose_errors(&calibrated, &fit)?));
    }
    for (path, ms) in &recordings {
        let label = path
            .file_name()
            .map_or("recording".into(), |n| n.to_string_lossy().into_owned());
        rows.push(row(&label, "initial", &pose_errors(&nominal, ms)?));
        rows.push(row("", "calibrated", &pose_errors(&calibrated, ms)?));
    }
    file::save_from(&args.out, &cal, fit.len(), machine_seed)?;
    let names = iastgcn::robot::ErrorParams::names();
    println!(
        "identified {} of {} parameters from {} poses (condition numbers {}); wrote {}",
        cal.identified.len(),
        names.len(),
        fit.len(),
        cal.condition
            .iter()
            .map(|c| format!("{c:.0}"))
            .collect::<Vec<_>>()
            .join(", "),
        args.out.display()
    );
    let identified: Vec<&str> = cal.identified.iter().map(|&k| names[k].as_str()).collect();
    println!("  identified: {}", identified.join(" "));
    for s in &cal.stages {
        println!(
            "  {:<8} round {} : {:>2} parameters, {} sweeps, Γ = {:.1e}",
            s.name, s.round, s.parameters, s.sweeps, s.gamma
        );
    }
    println!(
        "\n{:<22} {:<11} {:>8} {:>8} {:>8}   {:>7} {:>7} {:>7}",
        "data", "stage", "pos mean", "SD", "max", "att mean", "SD", "max"
    );
    println!("{:<22} {:<11} {:>26}   {:>23}", "", "", "(µm)", "(mdeg)");
    for r in &rows {
        println!("{r}");
    }
    Ok(())
}
