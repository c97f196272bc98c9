//! The serial-arm side of `iastgcn simulate --arm` and `iastgcn calibrate --robot
//! ARM.toml` (docs/arms.md): parse, call the library, print.

use std::path::Path;

use anyhow::Context;

use iastgcn::atomic::Batch;
use iastgcn::calibrate::arm::{arm_position_errors, calibrate_arm, ArmCalibrationConfig};
use iastgcn::calibrate::hold_out;
use iastgcn::data::arm_poses::{read_arm_poses, ArmPoses};
use iastgcn::robot::arm::Arm;
use iastgcn::stats::Summary;
use iastgcn::twin::arm::{ArmTwin, ArmTwinConfig, ARM_CHANNELS};

/// The hidden truth written beside a simulated pose file: `NAME.truth.toml`.
pub fn truth_path(csv: &Path) -> std::path::PathBuf {
    csv.with_extension("truth.toml")
}

/// `simulate --arm`: measures `poses` static poses of the serial twin of `arm_path`.
pub fn simulate(
    arm_path: &Path,
    poses: usize,
    seed: u64,
    machine_seed: u64,
    out: &Path,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=100_000).contains(&poses),
        "--poses: a pose list has from 1 to 100000 poses, got {poses}"
    );
    let nominal = Arm::load(arm_path)?;
    let twin = ArmTwin::draw(&nominal, machine_seed, ArmTwinConfig::default());
    let run = twin.measure(poses, seed);
    let file = ArmPoses {
        stamp: "time".into(),
        oriented: false,
        channels: ARM_CHANNELS.iter().map(|c| c.to_string()).collect(),
        poses: run.poses,
    };
    let truth = twin
        .truth
        .to_toml(None)
        .map_err(|e| anyhow::anyhow!("{}: {e}", truth_path(out).display()))?;
    let truth_text = format!(
        "# The hidden truth of the serial twin (machine seed {machine_seed}): its geometry, cold and \
         unloaded, with the tracker registration as its base. Not for calibration: for checking it.\n{truth}"
    );
    let mut batch = Batch::new();
    batch
        .add(out, file.to_csv().as_bytes())
        .with_context(|| out.display().to_string())?;
    batch
        .add(&truth_path(out), truth_text.as_bytes())
        .with_context(|| truth_path(out).display().to_string())?;
    batch.commit().with_context(|| out.display().to_string())?;
    let non_geometric: Vec<f64> = run
        .truth
        .iter()
        .zip(&run.geometric)
        .map(|(t, g)| (t - g).norm() * 1e3)
        .collect();
    let s = Summary::of(&non_geometric).context("no poses")?;
    println!(
        "wrote {} ({poses} poses of {}, seed {seed}, machine {machine_seed}; the twin's truth in {})",
        out.display(),
        nominal.spec.name,
        truth_path(out).display()
    );
    println!(
        "twin truth (not in the file): non-geometric error (compliance, backlash, warm-up) {:.1} µm mean, {:.1} µm max",
        s.mean, s.max
    );
    Ok(())
}

fn row(label: &str, stage: &str, errors_mm: &[f64]) -> String {
    let um: Vec<f64> = errors_mm.iter().map(|e| e * 1e3).collect();
    match Summary::of(&um) {
        Some(s) => format!(
            "{label:<22} {stage:<34} {:>9.1} {:>9.1} {:>9.1}",
            s.mean, s.sd, s.max
        ),
        None => format!("{label:<22} {stage:<34} (no poses)"),
    }
}

/// `calibrate --robot ARM.toml --data POSES.csv`: registration, identifiability and
/// Levenberg–Marquardt; writes the calibrated description to `out`.
pub fn calibrate(
    arm_path: &Path,
    data: &Path,
    hold_out_every: usize,
    out: &Path,
) -> anyhow::Result<()> {
    let nominal = Arm::load(arm_path)?;
    let file = read_arm_poses(data, nominal.joints())?;
    let (fit, held) = hold_out(&file.poses, hold_out_every);
    let cal = calibrate_arm(&nominal, &fit, &ArmCalibrationConfig::default())
        .with_context(|| format!("calibrating {} from {}", arm_path.display(), data.display()))?;
    let text = cal
        .arm
        .to_toml(Some(cal.record()))
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let header = format!(
        "# {} calibrated by iastgcn from {} ({} poses fitted, {} held out).\n",
        nominal.spec.name,
        data.display(),
        fit.len(),
        held.len()
    );
    iastgcn::atomic::write(out, format!("{header}{text}").as_bytes())
        .with_context(|| out.display().to_string())?;
    let names = nominal.names();
    println!(
        "identified {} of {} parameters from {} poses (condition number {:.0}, {} Levenberg–Marquardt iterations); wrote {}",
        cal.identified.len(),
        names.len(),
        fit.len(),
        cal.condition,
        cal.iterations,
        out.display()
    );
    println!(
        "\n{:<22} {:>14} {:>14} {:>12}",
        "parameter", "start", "calibrated", "± SD"
    );
    for (k, &i) in cal.identified.iter().enumerate() {
        let (unit, f) = if nominal.is_length(i) {
            ("mm", 1.0)
        } else {
            ("deg", 180.0 / std::f64::consts::PI)
        };
        println!(
            "{:<22} {:>14.5} {:>14.5} {:>12.5} {unit}",
            names[i],
            cal.registered.values[i] * f,
            cal.arm.values[i] * f,
            cal.sd[k] * f
        );
    }
    println!("\nleft at their nominal values:");
    for k in &cal.kept {
        println!("  {:<20} {}", k.name, k.reason);
    }
    println!(
        "\n{:<22} {:<34} {:>9} {:>9} {:>9}",
        "poses", "model", "mean µm", "SD µm", "max µm"
    );
    let groups = [
        (format!("fitted ({})", fit.len()), &fit),
        (format!("held out ({})", held.len()), &held),
    ];
    for (label, poses) in groups {
        if poses.is_empty() {
            continue;
        }
        println!(
            "{}",
            row(
                &label,
                "initial (nominal, registered)",
                &arm_position_errors(&cal.registered, poses)
            )
        );
        println!(
            "{}",
            row("", "calibrated", &arm_position_errors(&cal.arm, poses))
        );
    }
    Ok(())
}
