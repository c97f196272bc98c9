//! `iastgcn import`: a tracker export (any CSV with a header) into a serial arm's pose
//! file, its columns mapped by name (docs/arms.md "Importing tracker exports").

use std::path::PathBuf;

use clap::{Args, ValueEnum};

use iastgcn::data::arm_import::orientation::{read_transform, EulerFrame, EulerOrder};
use iastgcn::data::arm_import::{
    import_arm_poses, Difference, OrientationColumns, PoseColumns, RowOrder, SdColumns, TimeColumn,
    TimeFormat,
};
use iastgcn::robot::arm::Arm;

#[derive(Clone, Copy, ValueEnum)]
pub enum Delimiter {
    /// From the header line.
    Auto,
    Comma,
    Semicolon,
    Tab,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum DecimalMark {
    /// From the cells: a comma-separated file has points; otherwise what the numbers show.
    Auto,
    Point,
    Comma,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum Frame {
    /// Each turn about the axis as already turned: R = R1·R2·R3.
    Intrinsic,
    /// Each turn about the fixed frame's axis: R = R3·R2·R1.
    Extrinsic,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum Order {
    /// The export's order.
    File,
    /// Sorted by the --time column.
    Time,
}

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
    /// The measured orientation as three Euler angles, columns in the order of
    /// --euler-order's axes.
    #[arg(long, value_delimiter = ',', requires_all = ["euler_order", "euler_frame"], conflicts_with = "quaternion")]
    pub euler: Vec<String>,
    /// The axes of the --euler columns' turns, e.g. xyz, zyx or zyz.
    #[arg(long)]
    pub euler_order: Option<String>,
    /// Whether the Euler turns are about the turned axes (intrinsic) or the fixed ones.
    #[arg(long, value_enum)]
    pub euler_frame: Option<Frame>,
    /// The measured orientation as a unit quaternion, columns named x,y,z,w.
    #[arg(long, value_delimiter = ',')]
    pub quaternion: Vec<String>,
    /// Unit of the Euler angle columns and of the orientation SDs.
    #[arg(long, value_enum, default_value = "deg")]
    pub angle_unit: AngleUnit,
    /// The reading's standard deviations: x,y,z (length unit), then with the orientation
    /// optionally its three angles' (angle unit).
    #[arg(long, value_delimiter = ',')]
    pub sd: Vec<String>,
    /// A 4×4 transform (mm, one row a line) from the measured frame to the tool point to
    /// write: the pose written is the measured pose times it. Needs the orientation.
    #[arg(long)]
    pub tool: Option<PathBuf>,
    /// Use the inverse of the --tool file's transform (a file that gives the measured
    /// frame in the tool point's).
    #[arg(long, requires = "tool")]
    pub invert_tool: bool,
    /// A time column; the pose file's first column becomes `time` (s).
    #[arg(long, conflicts_with = "pose")]
    pub time: Option<String>,
    /// How --time is written: `seconds`; a date and time as `yyyymmddhhmmss` or `iso`
    /// (2020-07-14T16:39:04), or a pattern in the time crate's format description such
    /// as "[day].[month].[year] [hour]:[minute]:[second]" (then the seconds since the
    /// earliest row).
    #[arg(long, default_value = "seconds", requires = "time")]
    pub time_format: String,
    /// The order of the rows written: the export's, or sorted by --time.
    #[arg(long, value_enum, default_value = "file")]
    pub order: Order,
    /// The separator between cells.
    #[arg(long, value_enum, default_value = "auto")]
    pub delimiter: Delimiter,
    /// The decimal mark of the numbers.
    #[arg(long, value_enum, default_value = "auto")]
    pub decimal: DecimalMark,
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
    let orientation = match (args.euler.is_empty(), args.quaternion.is_empty()) {
        (false, _) => Some(OrientationColumns::Euler {
            columns: three("--euler", &args.euler)?,
            order: EulerOrder::parse(args.euler_order.as_deref().unwrap_or_default())
                .map_err(|e| anyhow::anyhow!("--euler-order: {e}"))?,
            frame: match args.euler_frame {
                Some(Frame::Extrinsic) => EulerFrame::Extrinsic,
                _ => EulerFrame::Intrinsic,
            },
        }),
        (_, false) => Some(OrientationColumns::Quaternion {
            columns: <[String; 4]>::try_from(args.quaternion.clone()).map_err(|_| {
                anyhow::anyhow!(
                    "--quaternion: expected four columns x,y,z,w, got {}: {}",
                    args.quaternion.len(),
                    args.quaternion.join(",")
                )
            })?,
        }),
        _ => None,
    };
    let sd = match args.sd.len() {
        0 => None,
        3 | 6 => Some(SdColumns {
            position: three("--sd", &args.sd[..3])?,
            orientation: (args.sd.len() == 6)
                .then(|| three("--sd", &args.sd[3..]))
                .transpose()?,
        }),
        n => anyhow::bail!(
            "--sd: expected x,y,z or x,y,z,rx,ry,rz columns, got {n}: {}",
            args.sd.join(",")
        ),
    };
    let tool = match &args.tool {
        Some(path) => {
            let t = read_transform(path)?;
            Some(if args.invert_tool { t.inverse() } else { t })
        }
        None => None,
    };
    let columns = PoseColumns {
        stamp: args.pose.clone(),
        time: args.time.as_ref().map(|column| TimeColumn {
            column: column.clone(),
            format: TimeFormat::parse(&args.time_format),
        }),
        order: match args.order {
            Order::File => RowOrder::File,
            Order::Time => RowOrder::Time,
        },
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
        orientation,
        angle_scale: match args.angle_unit {
            AngleUnit::Deg => std::f64::consts::PI / 180.0,
            AngleUnit::Rad => 1.0,
        },
        sd,
        tool,
        delimiter: match args.delimiter {
            Delimiter::Auto => None,
            Delimiter::Comma => Some(b','),
            Delimiter::Semicolon => Some(b';'),
            Delimiter::Tab => Some(b'\t'),
        },
        decimal_comma: match args.decimal {
            DecimalMark::Auto => None,
            DecimalMark::Point => Some(false),
            DecimalMark::Comma => Some(true),
        },
        channels: args.channels.clone(),
    };
    let poses = import_arm_poses(&args.from, &columns)?;
    poses.write(&args.out)?;
    let (position_sd, orientation_sd) = poses.reading_sd_columns();
    println!(
        "wrote {} ({} poses, {} joints{}{}{}) from {}",
        args.out.display(),
        poses.poses.len(),
        args.joints.len(),
        if poses.oriented { ", orientation" } else { "" },
        match (position_sd, orientation_sd) {
            (true, true) => ", position and orientation SDs",
            (true, false) => ", position SDs",
            _ => "",
        },
        if poses.channels.is_empty() {
            String::new()
        } else {
            format!(", channels {}", poses.channels.join(","))
        },
        args.from.display()
    );
    Ok(())
}
