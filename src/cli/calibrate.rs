//! `iastgcn calibrate`: EKF calibration from a measurement set, with a report of the pose
//! error before and after on held-out poses and on polishing recordings (Table V's first
//! two rows).

use std::path::PathBuf;

use anyhow::Context;
use indicatif::ProgressBar;
use nalgebra::Vector3;

use crate::calibrate::{self, file, jacobian::twist, EkfConfig, Measurement};
use crate::data::{expected_channels, read_calibration_set, tracker_pose, Recording};
use crate::graph::Graph;
use crate::robot::{Geometry, Joints, Robot};
use crate::stats::Summary;

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Calibration measurement set (CSV: q1..q5, x,y,z,rx,ry,rz).
    #[arg(long)]
    pub measurements: PathBuf,
    /// Output calibration file (TOML).
    #[arg(long)]
    pub out: PathBuf,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long)]
    pub robot: Option<PathBuf>,
    /// Every how many measurements one is held out for the report (0: none).
    #[arg(long, default_value_t = 5)]
    pub hold_out_every: usize,
    /// Polishing recordings to report the error on before and after calibration.
    #[arg(long, num_args = 1..)]
    pub recordings: Vec<PathBuf>,
}

/// Position (µm) and attitude (mdeg) errors of `model`'s prediction of each measurement.
fn errors(model: &Robot, ms: &[Measurement]) -> anyhow::Result<(Vec<f64>, Vec<f64>)> {
    let (mut p, mut a) = (Vec::new(), Vec::new());
    let mut guess = None;
    for m in ms {
        let (platform, tool) = model.forward(&m.joints, guess)?;
        guess = Some(platform);
        let d = twist(&(model.tracker_from_base() * tool), &m.pose);
        p.push(Vector3::new(d[0], d[1], d[2]).norm() * 1e3);
        a.push(Vector3::new(d[3], d[4], d[5]).norm().to_degrees() * 1e3);
    }
    Ok((p, a))
}

fn row(label: &str, stage: &str, (p, a): &(Vec<f64>, Vec<f64>)) -> String {
    let (p, a) = (
        Summary::of(p).expect("non-empty"),
        Summary::of(a).expect("non-empty"),
    );
    format!(
        "{label:<22} {stage:<11} {:>8.1} {:>8.1} {:>8.1}   {:>7.1} {:>7.1} {:>7.1}",
        p.mean, p.sd, p.max, a.mean, a.sd, a.max
    )
}

/// The tracked rows of a recording as measurements (Q1–Q5 as joint inputs).
fn recording_measurements(path: &std::path::Path) -> anyhow::Result<Vec<Measurement>> {
    let channels = expected_channels(&Graph::default_asset().nodes);
    let channels: Vec<&str> = channels.iter().map(String::as_str).collect();
    let rec = Recording::read(path, &channels, 1)?;
    let col = |name: &str| {
        rec.channels
            .iter()
            .position(|c| c == name)
            .expect("checked by the reader")
    };
    let q = ["Q1", "Q2", "Q3", "Q4", "Q5"].map(col);
    let mut out = Vec::new();
    for r in &rec.rows {
        let (Some(t), Some(q1), Some(q2), Some(q3), Some(q4), Some(q5)) = (
            r.tracker,
            r.values[q[0]],
            r.values[q[1]],
            r.values[q[2]],
            r.values[q[3]],
            r.values[q[4]],
        ) else {
            continue;
        };
        out.push(Measurement {
            joints: Joints {
                limbs: [q1, q2, q3],
                head: [q4.to_radians(), q5.to_radians()],
            },
            pose: tracker_pose(&t),
        });
    }
    anyhow::ensure!(
        !out.is_empty(),
        "{}: no row has both the tracker and Q1-Q5",
        path.display()
    );
    Ok(out)
}

pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    let geometry = match &args.robot {
        Some(p) => Geometry::load(p)?,
        None => Geometry::default_asset(),
    };
    let nominal = Robot::nominal(geometry);
    let rows = read_calibration_set(&args.measurements)?;
    let all: Vec<Measurement> = rows
        .iter()
        .map(|r| Measurement {
            joints: Joints {
                limbs: [r.joints[0], r.joints[1], r.joints[2]],
                head: [r.joints[3].to_radians(), r.joints[4].to_radians()],
            },
            pose: tracker_pose(&r.pose),
        })
        .collect();
    let (fit, held): (Vec<_>, Vec<_>) = all
        .iter()
        .enumerate()
        .partition(|(i, _)| args.hold_out_every == 0 || (i + 1) % args.hold_out_every != 0);
    let fit: Vec<Measurement> = fit.into_iter().map(|(_, m)| *m).collect();
    let held: Vec<Measurement> = held.into_iter().map(|(_, m)| *m).collect();
    let spinner = ProgressBar::new_spinner().with_message(format!("EKF on {} poses", fit.len()));
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let cal = calibrate::calibrate(&nominal, &fit, &EkfConfig::default())
        .with_context(|| format!("calibrating from {}", args.measurements.display()))?;
    spinner.finish_and_clear();
    file::save(&args.out, &cal, fit.len())?;
    let names = crate::robot::ErrorParams::names();
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
    let calibrated = nominal.with_errors(cal.errors.clone());
    println!(
        "\n{:<22} {:<11} {:>8} {:>8} {:>8}   {:>7} {:>7} {:>7}",
        "data", "stage", "pos mean", "SD", "max", "att mean", "SD", "max"
    );
    println!("{:<22} {:<11} {:>26}   {:>23}", "", "", "(µm)", "(mdeg)");
    if !held.is_empty() {
        println!(
            "{}",
            row(
                &format!("held-out poses ({})", held.len()),
                "initial",
                &errors(&nominal, &held)?
            )
        );
        println!("{}", row("", "calibrated", &errors(&calibrated, &held)?));
    }
    for path in &args.recordings {
        let ms = recording_measurements(path)?;
        let label = path
            .file_name()
            .map_or("recording".into(), |n| n.to_string_lossy().into_owned());
        println!("{}", row(&label, "initial", &errors(&nominal, &ms)?));
        println!("{}", row("", "calibrated", &errors(&calibrated, &ms)?));
    }
    Ok(())
}
