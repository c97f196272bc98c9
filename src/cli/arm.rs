//! The serial-arm side of `iastgcn simulate --robot ARM.toml` and `iastgcn calibrate --robot
//! ARM.toml` (docs/arms.md): parse, call the library, print.

use std::path::Path;

use anyhow::Context;

use iastgcn::atomic::Batch;
use iastgcn::calibrate::arm::ArmCalibration;
use iastgcn::data::arm_poses::{read_arm_poses, read_arm_targets, ArmPoses};
use iastgcn::experiment::arm::{
    arm_run_config, calibrated_targets, corrected_targets, evaluate_arm, targets_csv,
};
use iastgcn::experiment::block_study::{block_study, BlockStudy, BlockStudyConfig};
use iastgcn::experiment::calibration::{calibrate_serial, ErrorRow, HoldOut, Scoring};
use iastgcn::experiment::report::seeds::Spread;
use iastgcn::model::Variant;
use iastgcn::robot::arm::Arm;
use iastgcn::stats::Summary;
use iastgcn::twin::arm::{ArmTwin, ArmTwinConfig, ARM_CHANNELS};

/// The hidden truth written beside a simulated pose file: `NAME.truth.toml`.
pub fn truth_path(csv: &Path) -> std::path::PathBuf {
    csv.with_extension("truth.toml")
}

/// `simulate --robot ARM.toml`: measures `poses` static poses of the serial twin of
/// `nominal`.
pub fn simulate(
    nominal: &Arm,
    poses: usize,
    seed: u64,
    machine_seed: u64,
    out: &Path,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=100_000).contains(&poses),
        "--poses: a pose list has from 1 to 100000 poses, got {poses}"
    );
    let twin = ArmTwin::draw(nominal, machine_seed, ArmTwinConfig::default());
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
    let c = &twin.config;
    let truth_text = format!(
        "# The hidden truth of the serial twin (machine seed {machine_seed}): its geometry, cold, with the \
         tracker registration as its base, its link masses, payload, joint compliances and lost motions. \
         Not for calibration: for checking it.\n\
         # This machine's non-geometric constants: compliance {:.3e} rad/(N·m), link mass {:.2} kg, \
         payload {:.2} kg, backlash {:.4}, expansion {:.2e} 1/K, warm rise {:.2} K over {:.0} s.\n{truth}",
        c.compliance_rad_per_nm,
        c.link_mass_kg,
        c.payload_kg,
        c.backlash,
        c.expansion_per_k,
        c.warm_rise_k,
        c.warm_time_s
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

/// One row of the table, its label `width` characters wide.
fn row(r: &ErrorRow, oriented: bool, width: usize) -> String {
    let (label, stage) = (&r.label, &r.stage);
    let Some(s) = &r.position else {
        return format!("{label:<width$} {stage:<34} (no poses)");
    };
    let mut line = format!(
        "{label:<width$} {stage:<34} {:>9.1} {:>9.1} {:>9.1}",
        s.mean,
        s.rms(),
        s.max
    );
    if oriented {
        if let Some(a) = &r.attitude {
            line.push_str(&format!(" {:>10.1} {:>10.1}", a.mean, a.max));
        }
    }
    line
}

/// The identified parameters of `cal`: name, the value at `start`, the fitted value and
/// its SD, each in its display unit; `heads` names the two value columns.
pub(super) fn print_fitted(cal: &ArmCalibration, start: &[f64], heads: [&str; 2]) {
    let names = cal.arm.names();
    println!(
        "\n{:<22} {:>14} {:>14} {:>12}",
        "parameter", heads[0], heads[1], "± SD"
    );
    for (k, &i) in cal.identified.iter().enumerate() {
        let (unit, f) = cal.arm.param_kind(i).display();
        println!(
            "{:<22} {:>14.5} {:>14.5} {:>12.5} {unit}",
            names[i],
            start[i] * f,
            cal.arm.values[i] * f,
            cal.sd[k] * f
        );
    }
}

/// `calibrate --robot ARM.toml --data POSES.csv`: registration, identifiability and
/// Levenberg–Marquardt; writes the calibrated description to `out`.
pub fn calibrate(
    nominal: &Arm,
    data: &Path,
    scoring: &Scoring,
    study: Option<&BlockStudyConfig>,
    out: &Path,
) -> anyhow::Result<()> {
    let done = calibrate_serial(nominal, data, scoring)?;
    done.save(out)?;
    let cal = &done.calibration;
    let names = nominal.names();
    println!(
        "identified {} of {} parameters from {} poses (condition number {:.0}, {} Levenberg–Marquardt iterations); wrote {}",
        cal.identified.len(),
        names.len(),
        cal.poses,
        cal.condition,
        cal.iterations,
        out.display()
    );
    print_fitted(cal, &cal.registered.values, ["start", "calibrated"]);
    println!("\nleft at their nominal values:");
    for k in &cal.kept {
        println!("  {:<20} {}", k.name, k.reason);
    }
    let oriented = done.rows.iter().any(|r| r.attitude.is_some());
    let width = done
        .rows
        .iter()
        .map(|r| r.label.chars().count())
        .max()
        .unwrap_or(0)
        .max(22);
    println!(
        "\n{:<width$} {:<34} {:>9} {:>9} {:>9}{}",
        "poses",
        "model",
        "mean µm",
        "RMS µm",
        "max µm",
        if oriented {
            format!(" {:>10} {:>10}", "mean mdeg", "max mdeg")
        } else {
            String::new()
        }
    );
    for r in &done.rows {
        println!("{}", row(r, oriented, width));
    }
    if let (
        Some(config),
        Scoring::HoldOut(HoldOut::Block {
            from_percent,
            to_percent,
        }),
    ) = (study, scoring)
    {
        let block = HoldOut::block_range(done.file.poses.len(), *from_percent, *to_percent);
        let spinner = indicatif::ProgressBar::new_spinner().with_message(format!(
            "{} random hold-outs of {} poses",
            config.random_splits,
            block.len()
        ));
        spinner.enable_steady_tick(std::time::Duration::from_millis(200));
        let result = block_study(nominal, &done.file.poses, block, cal, config);
        spinner.finish_and_clear();
        print_block_study(&result?, &done.file.stamp);
    }
    Ok(())
}

/// `calibrate --hold-out-block … --compare-random K --reregister N`: the block against
/// random hold-outs on the same poses, re-registered, and along the block.
fn print_block_study(study: &BlockStudy, stamp: &str) {
    let hours = stamp == "time";
    let show = |v: f64| {
        if hours {
            format!("{:.1} h", v / 3600.0)
        } else {
            format!("{v:.0}")
        }
    };
    let cell = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.1}"));
    let (Some(first), Some(last)) = (study.parts.first(), study.parts.last()) else {
        return;
    };
    println!(
        "\nthe block: poses {}–{} of the file ({} poses, {} {} to {})",
        study.block.start + 1,
        study.block.end,
        study.block.len(),
        stamp,
        show(first.stamps.0),
        show(last.stamps.1)
    );
    if let Some(p) = &study.block_errors.0 {
        println!(
            "  calibrated on the other poses: {:.1} µm mean, {:.1} RMS, {:.1} max{}",
            p.mean,
            p.rms(),
            p.max,
            study
                .block_errors
                .1
                .as_ref()
                .map_or(String::new(), |a| format!("; {:.1} mdeg mean", a.mean))
        );
    }
    if !study.random.is_empty() {
        let spread = |v: Vec<f64>| Spread::of(&v).text(1);
        let inside: Vec<f64> = study.random.iter().filter_map(|r| r.block_um).collect();
        let inside_mdeg: Vec<f64> = study.random.iter().filter_map(|r| r.block_mdeg).collect();
        let all: Vec<f64> = study.random.iter().map(|r| r.all_um).collect();
        let counts: Vec<String> = study
            .random
            .iter()
            .map(|r| r.block_poses.to_string())
            .collect();
        println!(
            "  random hold-outs of as many poses (seeds 1–{}), on the block's poses they held out ({}): {} µm mean{}",
            study.random.len(),
            counts.join(", "),
            spread(inside),
            if inside_mdeg.is_empty() {
                String::new()
            } else {
                format!(", {} mdeg", spread(inside_mdeg))
            }
        );
        println!(
            "  the same random hold-outs on every pose they held out: {} µm mean (mean ± SD over seeds)",
            spread(all)
        );
    }
    if let Some(r) = &study.reregistered {
        let mdeg = |a: &Option<Summary>| {
            a.as_ref()
                .map_or(String::new(), |a| format!(", {:.1} mdeg", a.mean))
        };
        println!(
            "  re-registered on {} poses spread over the block, on its other {}: {:.1} µm{} before, {:.1} µm{} after",
            r.fitted,
            r.after.0.count,
            r.before.0.mean,
            mdeg(&r.before.1),
            r.after.0.mean,
            mdeg(&r.after.1)
        );
    }
    println!(
        "\n{:<6} {:>13} {:>22} {:>12} {:>12} {:>14}",
        "part", "poses", stamp, "block µm", "random µm", "re-reg. µm"
    );
    for (k, p) in study.parts.iter().enumerate() {
        println!(
            "{:<6} {:>13} {:>22} {:>12.1} {:>12} {:>14}",
            k + 1,
            format!("{}–{}", p.poses.start + 1, p.poses.end),
            format!("{}–{}", show(p.stamps.0), show(p.stamps.1)),
            p.block_um,
            cell(p.random_um),
            cell(p.reregistered_um)
        );
    }
}

/// `evaluate --robot ARM.toml --data POSES.csv…`: calibration on the training blocks,
/// the residual models, and the table on the test blocks; report files into `--out`.
pub fn evaluate(
    device: iastgcn::gpu::Device,
    nominal: &Arm,
    args: &super::evaluate_args::EvaluateArgs,
) -> anyhow::Result<()> {
    let read = |paths: &[std::path::PathBuf]| {
        paths
            .iter()
            .map(|p| {
                let name = p.file_stem().map_or(p.display().to_string(), |s| {
                    s.to_string_lossy().into_owned()
                });
                Ok((name, read_arm_poses(p, nominal.joints())?))
            })
            .collect::<anyhow::Result<Vec<_>>>()
    };
    let files = read(&args.data)?;
    let tests = read(&args.test)?;
    let mut config = match &args.config {
        Some(p) => iastgcn::train::RunConfig::load(p)?,
        None => arm_run_config(),
    };
    if args.without_channel_time {
        config.data.channel_time = false;
    }
    let variants = args
        .train_models
        .split(',')
        .map(|name| {
            Variant::parse(name.trim()).with_context(|| {
                format!(
                    "--train-models: unknown model {name:?} ({})",
                    Variant::names()
                )
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    // Every input is read and checked before the first model trains (the targets'
    // reach once the calibration is known, still before training).
    let targets = match &args.targets {
        Some(path) => Some(read_arm_targets(path, &files[0].1.channels)?),
        None => None,
    };
    std::fs::create_dir_all(&args.out).with_context(|| args.out.display().to_string())?;
    let result = evaluate_arm(
        &device,
        nominal,
        &files,
        &tests,
        &config,
        &variants,
        args.seeds.as_deref().unwrap_or(&[config.train.seed]),
        targets.as_ref(),
        &args.out,
        &mut super::Console::default(),
    )?;
    // Joint targets from the model recommended on validation, or from calibration alone
    // where no model beats it there.
    let targets = match (&targets, result.recommended()) {
        (Some(list), Some((name, ck))) => {
            let corrected = corrected_targets(
                &device,
                ck,
                &result.calibration.arm,
                list,
                config.data.channel_time,
            )?;
            Some((
                format!("{name} (recommended on validation)"),
                targets_csv(&list.stamp, &corrected),
            ))
        }
        (Some(list), None) => {
            let plain = calibrated_targets(&result.calibration.arm, list)?;
            Some((
                "calibration alone (no model beats it on validation)".to_string(),
                targets_csv(&list.stamp, &plain),
            ))
        }
        (None, _) => None,
    };
    let [train, validation, test] = result.split_poses;
    let table = result.markdown();
    let names = |paths: &[std::path::PathBuf]| {
        paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (blocks, scored) = if args.test.is_empty() {
        (
            "contiguous 70/20/10 % blocks".to_string(),
            "test poses".to_string(),
        )
    } else {
        (
            "contiguous 80/20 % training and validation blocks".to_string(),
            format!(
                "poses of the separate test files {} (used for nothing else)",
                names(&args.test)
            ),
        )
    };
    let report = format!(
        "# {} — residual models\n\n\
         Pose files: {}. Each file is cut into {blocks} in measurement \
         order; a window is the last {} poses in that order (the data are static poses, not \
         a time series). The geometric calibration ({} parameters identified) and the models \
         saw the training blocks only ({train} windows; validation {validation} for early \
         stopping); the table scores the {test} {scored} against the tracker's \
         measurement. `initial`: the nominal description with the tracker registration \
         fitted; `training mean`: the calibrated model plus the training blocks' mean \
         residual; each model: the calibrated model plus its predicted residual.\n\n\
         {table}\n{}\n",
        nominal.spec.name,
        names(&args.data),
        config.model.window,
        result.calibration.identified.len(),
        result.recommendation(),
    );
    let mut batch = Batch::new();
    let (md, csv) = (args.out.join("report.md"), args.out.join("arm_table.csv"));
    batch
        .add(&md, report.as_bytes())
        .with_context(|| md.display().to_string())?;
    batch
        .add(&csv, result.csv().as_bytes())
        .with_context(|| csv.display().to_string())?;
    if let Some((name, text)) = &targets {
        let path = args.out.join("targets.csv");
        batch
            .add(&path, text.as_bytes())
            .with_context(|| path.display().to_string())?;
        println!("joint targets from {name}: {}", path.display());
    }
    batch.commit().with_context(|| md.display().to_string())?;
    println!("\n{table}\n{}", result.recommendation());
    println!("wrote {} and {}", md.display(), csv.display());
    Ok(())
}
