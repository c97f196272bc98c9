//! `iastgcn calibrate`: EKF calibration from a measurement set, with a report of the pose
//! error before and after on held-out poses and on polishing recordings (Table V's first
//! two rows).

use std::path::PathBuf;

use indicatif::ProgressBar;

use iastgcn::experiment::block_study::BlockStudyConfig;
use iastgcn::experiment::calibration::{calibrate_hybrid, ErrorRow, HoldOut, Scoring};
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
    /// Hold out the poses from FROM to TO per cent of the file's order instead, a
    /// stretch of time (`70,100`: the last 30 %) or a slab of a grid, and fit the others.
    #[arg(long, value_name = "FROM,TO", value_delimiter = ',',
          conflicts_with_all = ["hold_out_every", "test", "hold_out_random"])]
    pub hold_out_block: Option<Vec<f64>>,
    /// Hold out this many per cent of the poses instead, drawn at random with `--seed`.
    #[arg(long, value_name = "PERCENT", conflicts_with_all = ["hold_out_every", "test"])]
    pub hold_out_random: Option<f64>,
    /// The seed of `--hold-out-random`'s draw.
    #[arg(long, default_value_t = 1, requires = "hold_out_random")]
    pub seed: u64,
    /// With `--hold-out-block` (serial arms): also fit K random hold-outs of the block's
    /// size (seeds 1 to K) and score them on the block's poses they held out: what those
    /// poses cost with fitted poses all around them (docs/arms.md "Time").
    #[arg(
        long,
        value_name = "K",
        default_value_t = 0,
        requires = "hold_out_block"
    )]
    pub compare_random: usize,
    /// With `--hold-out-block` (serial arms): re-register the calibration on N poses
    /// spread evenly over the block and score it before and after on the block's others:
    /// what a tracker or probe that moved explains.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 0,
        requires = "hold_out_block"
    )]
    pub reregister: usize,
    /// With `--hold-out-block` (serial arms): the block's mean errors in this many parts,
    /// in the file's order.
    #[arg(
        long,
        value_name = "K",
        default_value_t = 10,
        requires = "hold_out_block"
    )]
    pub parts: usize,
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

fn scoring(args: &CalibrateArgs) -> anyhow::Result<Scoring> {
    if let Some(t) = &args.test {
        return Ok(Scoring::TestFile(t.clone()));
    }
    Ok(Scoring::HoldOut(
        match (&args.hold_out_block, args.hold_out_random) {
            (Some(block), _) => match block[..] {
                [from_percent, to_percent] => HoldOut::Block {
                    from_percent,
                    to_percent,
                },
                _ => anyhow::bail!(
                    "--hold-out-block takes FROM,TO (two per cents, e.g. 70,100), got {} values",
                    block.len()
                ),
            },
            (None, Some(percent)) => HoldOut::Random {
                percent,
                seed: args.seed,
            },
            (None, None) => HoldOut::Every(args.hold_out_every),
        },
    ))
}

/// What `--compare-random`, `--reregister` and `--parts` ask of a block hold-out.
fn block_study(args: &CalibrateArgs) -> Option<BlockStudyConfig> {
    args.hold_out_block.as_ref()?;
    Some(BlockStudyConfig {
        random_splits: args.compare_random,
        reregister: args.reregister,
        parts: args.parts,
    })
}

pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let description = Description::load_or_default(args.robot.as_deref())?;
    if matches!(description, Description::Hybrid(_))
        && (args.compare_random > 0 || args.reregister > 0)
    {
        anyhow::bail!(
            "--compare-random and --reregister study a serial arm's calibration (--robot ARM.toml); \
             the hybrid machine's EKF has no such study"
        );
    }
    let geometry = match description {
        Description::Hybrid(geometry) => geometry,
        Description::Serial(arm) => {
            return super::arm::calibrate(
                &arm,
                &args.measurements,
                &scoring(args)?,
                block_study(args).as_ref(),
                &args.out,
            );
        }
    };
    let spinner = ProgressBar::new_spinner().with_message("EKF calibration");
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let done = calibrate_hybrid(
        geometry,
        &args.measurements,
        &scoring(args)?,
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
