//! `iastgcn import`: a tracker export (any CSV with a header) into a serial arm's pose
//! file, its columns mapped by name (docs/arms.md "Importing tracker exports").

use std::path::PathBuf;

use clap::{Args, ValueEnum};

use iastgcn::data::arm_import::{import_arm_poses, Difference, PoseColumns};
use iastgcn::robot::arm::Arm;

#[derive(Clone, Copy, ValueEnum)]
pub enum AngleUnit {
    Deg,
    Rad,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum LengthUnit {
    Mm,
    M,
}

#[derive(Args)]
pub struct ImportArgs {
    /// The export to read (CSV with a header line).
    #[arg(long)]
    pub from: PathBuf,
    /// The pose file to write (docs/arms.md "The pose file").
    #[arg(long)]
    pub out: PathBuf,
    /// The column of the pose number or time (increasing); without it the rows are
    /// numbered 1, 2, ….
    #[arg(long)]
    pub pose: Option<String>,
    /// The joint columns in chain order, comma-separated.
    #[arg(long, value_delimiter = ',', required = true)]
    pub joints: Vec<String>,
    /// The x,y,z columns of the measured point, or of the reference point that --minus or
    /// --plus correct.
    #[arg(long, value_delimiter = ',', num_args = 1, required = true)]
    pub position: Vec<String>,
    /// x,y,z columns of "reference minus measured": measured = position − these.
    #[arg(long, value_delimiter = ',', conflicts_with = "plus")]
    pub minus: Vec<String>,
    /// x,y,z columns of "measured minus reference": measured = position + these.
    #[arg(long, value_delimiter = ',')]
    pub plus: Vec<String>,
    /// Unit of the joint columns (prismatic joints: the length unit).
    #[arg(long, value_enum, default_value = "deg")]
    pub joint_unit: AngleUnit,
    /// Unit of the position and difference columns.
    #[arg(long, value_enum, default_value = "mm")]
    pub length_unit: LengthUnit,
    /// Further columns to keep as sensor channels, comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub channels: Vec<String>,
    /// The arm's description: checks that the joint columns match its joints.
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
}

fn three(flag: &str, v: &[String]) -> anyhow::Result<[String; 3]> {
    <[String; 3]>::try_from(v.to_vec()).map_err(|_| {
        anyhow::anyhow!(
            "{flag}: expected three columns x,y,z, got {}: {}",
            v.len(),
            v.join(",")
        )
    })
}

pub fn run(args: &ImportArgs) -> anyhow::Result<()> {
    let (difference, sign) = match (args.minus.is_empty(), args.plus.is_empty()) {
        (false, _) => (Some(three("--minus", &args.minus)?), Difference::Minus),
        (_, false) => (Some(three("--plus", &args.plus)?), Difference::Plus),
        _ => (None, Difference::None),
    };
    let length = args
        .robot
        .as_ref()
        .map(|p| Arm::load(p).map(|a| a.joints()))
        .transpose()?;
    if let Some(n) = length {
        anyhow::ensure!(
            n == args.joints.len(),
            "--joints names {} columns; the arm of --robot has {n} joints",
            args.joints.len()
        );
    }
    let columns = PoseColumns {
        stamp: args.pose.clone(),
        joints: args.joints.clone(),
        position: three("--position", &args.position)?,
        difference,
        sign,
        joint_scale: match args.joint_unit {
            AngleUnit::Deg => 1.0,
            AngleUnit::Rad => 180.0 / std::f64::consts::PI,
        },
        length_scale: match args.length_unit {
            LengthUnit::Mm => 1.0,
            LengthUnit::M => 1000.0,
        },
        channels: args.channels.clone(),
    };
    let poses = import_arm_poses(&args.from, &columns)?;
    poses.write(&args.out)?;
    println!(
        "wrote {} ({} poses, {} joints{}) from {}",
        args.out.display(),
        poses.poses.len(),
        args.joints.len(),
        if poses.channels.is_empty() {
            String::new()
        } else {
            format!(", channels {}", poses.channels.join(","))
        },
        args.from.display()
    );
    Ok(())
}
