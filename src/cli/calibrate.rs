//! `iastgcn calibrate`: EKF calibration from a measurement set, with a report of the pose
//! error before and after on held-out poses and on polishing recordings (Table V's first
//! two rows).

use std::path::PathBuf;

use indicatif::ProgressBar;

use iastgcn::experiment::calibration::{calibrate_hybrid, ErrorRow, Scoring};
use iastgcn::robot::Description;

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

/// One row of the error table (µm and mdeg).
fn row(r: &ErrorRow) -> String {
    let (label, stage) = (&r.label, &r.stage);
    let (Some(p), Some(a)) = (&r.position, &r.attitude) else {
        return format!("{label:<22} {stage:<11} (no poses)");
    };
    format!(
        "{label:<22} {stage:<11} {:>8.1} {:>8.1} {:>8.1}   {:>7.1} {:>7.1} {:>7.1}",
        p.mean, p.sd, p.max, a.mean, a.sd, a.max
    )
}

fn scoring(args: &CalibrateArgs) -> Scoring {
    match &args.test {
        Some(t) => Scoring::TestFile(t.clone()),
        None => Scoring::HoldOutEvery(args.hold_out_every),
    }
}

pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let geometry = match Description::load_or_default(args.robot.as_deref())? {
        Description::Hybrid(geometry) => geometry,
        Description::Serial(arm) => {
            return super::arm::calibrate(&arm, &args.measurements, &scoring(args), &args.out);
        }
    };
    let spinner = ProgressBar::new_spinner().with_message("EKF calibration");
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let done = calibrate_hybrid(
        geometry,
        &args.measurements,
        &scoring(args),
        &args.recordings,
    );
    spinner.finish_and_clear();
    let done = done?;
    done.save(&args.out)?;
    let cal = &done.calibration;
    let names = iastgcn::robot::ErrorParams::names();
    println!(
        "identified {} of {} parameters from {} poses (condition numbers {}); wrote {}",
        cal.identified.len(),
        names.len(),
        done.fitted,
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
    for r in &done.rows {
        println!("{}", row(r));
    }
    Ok(())
}
