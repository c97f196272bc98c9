//! `iastgcn register`: a calibrated serial arm in a new campaign (docs/arms.md "A new
//! campaign"): the tracker's and the tool's placement fitted again on a few poses, the
//! kinematics kept; with `--fit`, the study of how few poses serve.

use std::path::PathBuf;

use anyhow::Context;

use iastgcn::calibrate::arm::{reregister, ArmCalibration, ArmCalibrationConfig};
use iastgcn::data::arm_poses::read_arm_poses;
use iastgcn::experiment::calibration::arm_error_summaries;
use iastgcn::experiment::campaign::campaign_study;
use iastgcn::robot::arm::{Arm, ArmPose};

#[derive(clap::Args)]
pub struct RegisterArgs {
    /// The calibrated description (what `iastgcn calibrate --robot` wrote).
    #[arg(long, visible_alias = "arm")]
    pub robot: PathBuf,
    /// Poses of the new campaign (a pose file, docs/arms.md "The pose file").
    #[arg(long)]
    pub data: PathBuf,
    /// The description for the new campaign to write (TOML).
    #[arg(long)]
    pub out: PathBuf,
    /// A separate pose file of the new campaign to score (used for nothing else).
    #[arg(long, conflicts_with = "fit")]
    pub test: Option<PathBuf>,
    /// Fit on the first N poses of --data only and score the others; --out gets that fit.
    #[arg(long)]
    pub fit: Option<usize>,
    /// With --fit: this many disjoint blocks of N poses from the start, each fitted and
    /// scored on all poses outside it (mean ± SD over the blocks).
    #[arg(long, default_value_t = 1, requires = "fit")]
    pub blocks: usize,
    /// With --fit: the nominal description the calibration started from, to compare a
    /// full calibration and a registration of the nominal kinematics on the same poses.
    #[arg(long, requires = "fit")]
    pub compare: Option<PathBuf>,
}

fn scores(label: &str, arm: &Arm, poses: &[ArmPose]) {
    let (Some(p), turned) = arm_error_summaries(arm, poses) else {
        return;
    };
    let turned = turned
        .map(|a| format!(" {:>10.1} {:>10.1}", a.mean, a.max))
        .unwrap_or_default();
    println!(
        "{label:<34} {:>9.1} {:>9.1} {:>9.1}{turned}",
        p.mean,
        p.rms(),
        p.max
    );
}

fn save(fit: &ArmCalibration, header: String, out: &std::path::Path) -> anyhow::Result<()> {
    let text = fit
        .arm
        .to_toml(Some(fit.record()))
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    iastgcn::atomic::write(out, format!("{header}{text}").as_bytes())
        .with_context(|| out.display().to_string())
}

pub fn run(args: &RegisterArgs) -> anyhow::Result<()> {
    let calibrated = Arm::load(&args.robot)?;
    let all = read_arm_poses(&args.data, calibrated.joints())?.poses;
    let nominal = args.compare.as_ref().map(|p| Arm::load(p)).transpose()?;
    let (fit, held): (Vec<ArmPose>, Vec<ArmPose>) = match (args.fit, &args.test) {
        (Some(n), _) => {
            anyhow::ensure!(
                n >= 1 && n * args.blocks < all.len(),
                "--fit {n} --blocks {}: {} poses in {}, and some must be left to score",
                args.blocks,
                all.len(),
                args.data.display()
            );
            (all[..n].to_vec(), all[n..].to_vec())
        }
        (None, Some(test)) => (
            all.clone(),
            read_arm_poses(test, calibrated.joints())?.poses,
        ),
        (None, None) => (all.clone(), Vec::new()),
    };
    // With --compare the study's first block is this fit: it is done once.
    let study = match (args.fit, &nominal) {
        (Some(n), Some(nominal)) => {
            Some(campaign_study(&calibrated, nominal, &all, n, args.blocks)?)
        }
        _ => None,
    };
    let done = match &study {
        Some(s) => s.first.clone(),
        None => reregister(&calibrated, &fit, &ArmCalibrationConfig::default())
            .map_err(anyhow::Error::from)
            .with_context(|| {
                format!(
                    "re-registering {} on {}",
                    args.robot.display(),
                    args.data.display()
                )
            })?,
    };
    let header = format!(
        "# {} re-registered by iastgcn for a new campaign: tracker and tool fitted on {} poses of {}, the kinematics kept from {}.\n",
        calibrated.spec.name,
        fit.len(),
        args.data.display(),
        args.robot.display()
    );
    save(&done, header, &args.out)?;
    println!(
        "re-registered on {} poses ({} parameters: tracker and tool; {} Levenberg–Marquardt iterations); wrote {}",
        fit.len(),
        done.identified.len(),
        done.iterations,
        args.out.display()
    );
    super::arm::print_fitted(&done, &calibrated.values, ["before", "fitted"]);
    for k in &done.kept {
        println!("  {:<20} {}", k.name, k.reason);
    }
    println!(
        "\n{:<34} {:>9} {:>9} {:>9} {:>10} {:>10}",
        "poses", "mean µm", "RMS µm", "max µm", "mean mdeg", "max mdeg"
    );
    scores(&format!("fitted ({})", fit.len()), &done.arm, &fit);
    if !held.is_empty() {
        scores(&format!("scored ({})", held.len()), &done.arm, &held);
    }
    if let Some(study) = &study {
        println!("\n{}", study.markdown());
    }
    Ok(())
}
