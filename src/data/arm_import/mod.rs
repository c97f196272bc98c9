//! Importing a tracker export into a serial arm's pose file (docs/arms.md "Importing
//! tracker exports"): any CSV with a header, its columns mapped by name to the pose
//! file's (`data::arm_poses`). The measured position is either given directly or as a
//! reference point (e.g. the commanded one) plus or minus a difference column per axis,
//! the layout of exports that store "commanded minus measured". Joint angles in degrees
//! or radians, lengths in mm or m; the orientation as Euler angles in any convention or
//! a quaternion ([`orientation`]); a time column in any layout; a fixed tool transform;
//! the reading's standard deviations; `;`-separated files with decimal commas
//! ([`dialect`]); further columns become sensor channels.

pub mod dialect;
pub mod orientation;

use std::path::Path;

use nalgebra::{Isometry3, Point3, UnitQuaternion};

use self::dialect::{detect_decimal_comma, detect_delimiter, number, Dialect};
use self::orientation::{euler_rotation, quaternion_rotation, EulerFrame, EulerOrder};
use super::arm_poses::{parse_arm_poses, ArmPoses};
use super::recording::{file_err, DataError, Table};
use crate::robot::arm::{ArmPose, ReadingSd};

/// How the measured position is read from the position columns and, when given, a
/// difference per axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Difference {
    /// The position columns are the measured point.
    #[default]
    None,
    /// measured = position − difference (the file stores reference minus measured).
    Minus,
    /// measured = position + difference (the file stores measured minus reference).
    Plus,
}

/// How a time column is written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TimeFormat {
    /// A number of seconds, kept as it is.
    Seconds,
    /// A date and time in the `time` crate's format description, e.g.
    /// `[year][month][day][hour][minute][second]` for `20200714163904`; the pose file
    /// gets the seconds since the earliest row (the time of day taken as UTC, so a
    /// change of daylight saving time is not seen).
    Pattern(String),
}

impl TimeFormat {
    /// `seconds`; `yyyymmddhhmmss` (`20200714163904`); `iso` (`2020-07-14T16:39:04`);
    /// or a pattern in the `time` crate's format description.
    ///
    /// ```
    /// use iastgcn::data::arm_import::TimeFormat;
    ///
    /// assert_eq!(TimeFormat::parse("seconds"), TimeFormat::Seconds);
    /// assert_eq!(
    ///     TimeFormat::parse("yyyymmddhhmmss"),
    ///     TimeFormat::Pattern("[year][month][day][hour][minute][second]".into())
    /// );
    /// ```
    pub fn parse(text: &str) -> TimeFormat {
        match text {
            "seconds" => TimeFormat::Seconds,
            "yyyymmddhhmmss" => {
                TimeFormat::Pattern("[year][month][day][hour][minute][second]".into())
            }
            "iso" => TimeFormat::Pattern("[year]-[month]-[day]T[hour]:[minute]:[second]".into()),
            pattern => TimeFormat::Pattern(pattern.to_string()),
        }
    }
}

/// The time column of an export.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TimeColumn {
    /// Its name.
    pub column: String,
    /// How it is written.
    pub format: TimeFormat,
}

/// The order of the pose file's rows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RowOrder {
    /// The export's order; a time column that does not increase is refused.
    #[default]
    File,
    /// Sorted by the time column (stable), so that the poses follow the order in which
    /// they were measured where an export appended some rows out of time order.
    Time,
}

/// The orientation columns of an export and their convention.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OrientationColumns {
    /// Three Euler angles in column order, turning about `order`'s axes as `frame` says.
    Euler {
        /// The three columns.
        columns: [String; 3],
        /// The axis of each column's turn.
        order: EulerOrder,
        /// Intrinsic or extrinsic.
        frame: EulerFrame,
    },
    /// A unit quaternion, its columns named in the order x, y, z, w.
    Quaternion {
        /// The four columns.
        columns: [String; 4],
    },
}

/// The columns of the reading's standard deviations.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SdColumns {
    /// x, y, z of the position's SD (the length unit).
    pub position: [String; 3],
    /// The SDs of the three orientation angles (the angle unit), where given.
    pub orientation: Option<[String; 3]>,
}

/// Which column of the export is what.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseColumns {
    /// The pose number column (increasing); `None` numbers the rows 1, 2, … (or takes
    /// the time column).
    pub stamp: Option<String>,
    /// A time column: the pose file's stamp becomes `time` (s).
    pub time: Option<TimeColumn>,
    /// The order of the rows written.
    pub order: RowOrder,
    /// One column per joint, in chain order.
    pub joints: Vec<String>,
    /// x, y, z of the measured point, or of the reference point the difference applies to.
    pub position: [String; 3],
    /// x, y, z of the difference, with `sign`; empty with [`Difference::None`].
    pub difference: Option<[String; 3]>,
    /// How the difference applies.
    pub sign: Difference,
    /// Degrees per unit of the joint columns (1 for degrees, 180/π for radians; prismatic
    /// joints take mm per unit, see `length_scale`).
    pub joint_scale: f64,
    /// Millimetres per unit of the position and difference columns (1 for mm, 1000 for m).
    pub length_scale: f64,
    /// The measured orientation, where the export has it.
    pub orientation: Option<OrientationColumns>,
    /// Radians per unit of the Euler angle columns and of the orientation SDs (π/180 for
    /// degrees, 1 for radians).
    pub angle_scale: f64,
    /// The reading's standard deviations, where the export has them.
    pub sd: Option<SdColumns>,
    /// A fixed transform from the measured frame to the tool point the pose file should
    /// hold (the flange in a probe's frame, say): the pose written is the measured pose
    /// times this. Needs the orientation.
    pub tool: Option<Isometry3<f64>>,
    /// The separator between cells; `None` detects it from the header line.
    pub delimiter: Option<u8>,
    /// Whether numbers use the decimal comma; `None` detects it from the cells.
    pub decimal_comma: Option<bool>,
    /// Further columns kept as sensor channels, under their own names.
    pub channels: Vec<String>,
}

impl Default for PoseColumns {
    /// No column named; degrees, mm, detected separator and decimal mark.
    fn default() -> PoseColumns {
        PoseColumns {
            stamp: None,
            time: None,
            order: RowOrder::File,
            joints: Vec::new(),
            position: Default::default(),
            difference: None,
            sign: Difference::None,
            joint_scale: 1.0,
            length_scale: 1.0,
            orientation: None,
            angle_scale: std::f64::consts::PI / 180.0,
            sd: None,
            tool: None,
            delimiter: None,
            decimal_comma: None,
            channels: Vec::new(),
        }
    }
}

/// Reads an export at `path` with the mapping `columns` into a pose file's contents (the
/// result parses back as a pose file of `columns.joints.len()` joints).
pub fn import_arm_poses(path: &Path, columns: &PoseColumns) -> Result<ArmPoses, DataError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| file_err(&file, e.to_string()))?;
    parse_export(&text, &file, columns)
}

/// [`import_arm_poses`] on the export's text (`file` names it in errors).
///
/// ```
/// use iastgcn::data::arm_import::{parse_export, Difference, PoseColumns};
///
/// let text = "step,x_t,y_t,z_t,x_dif,y_dif,z_dif,j1,j2\n0,100,0,50,1,2,-1,10,20\n";
/// let columns = PoseColumns {
///     stamp: Some("step".into()),
///     joints: vec!["j1".into(), "j2".into()],
///     position: ["x_t", "y_t", "z_t"].map(String::from),
///     difference: Some(["x_dif", "y_dif", "z_dif"].map(String::from)),
///     sign: Difference::Minus,
///     ..PoseColumns::default()
/// };
/// let poses = parse_export(text, "export.csv", &columns)?;
/// assert_eq!(poses.poses[0].position.coords.as_slice(), [99.0, -2.0, 51.0]);
///
/// // A `;`-separated export with decimal commas, detected.
/// let text = "j1;j2;x;y;z\n10,5;20;0,5;1;2\n";
/// let columns = PoseColumns {
///     joints: vec!["j1".into(), "j2".into()],
///     position: ["x", "y", "z"].map(String::from),
///     ..PoseColumns::default()
/// };
/// let poses = parse_export(text, "export.csv", &columns)?;
/// assert_eq!((poses.poses[0].joints[0], poses.poses[0].position.x), (10.5, 0.5));
/// # Ok::<(), iastgcn::data::DataError>(())
/// ```
pub fn parse_export(text: &str, file: &str, columns: &PoseColumns) -> Result<ArmPoses, DataError> {
    check_mapping(file, columns)?;
    let delimiter = detect_delimiter(text, file, columns.delimiter)?;
    let table = Table::parse_delimited(text, file, delimiter, false)?;
    let find = |name: &str| {
        table.header.iter().position(|h| h == name).ok_or_else(|| {
            file_err(
                file,
                format!(
                    "no column {name:?}; the header has {}",
                    table.header.join(&(delimiter as char).to_string())
                ),
            )
        })
    };
    let find_all = |names: &[String]| names.iter().map(|c| find(c)).collect::<Result<Vec<_>, _>>();
    let stamp = columns.stamp.as_deref().map(find).transpose()?;
    let time = columns.time.as_ref().map(|t| find(&t.column)).transpose()?;
    let joints = find_all(&columns.joints)?;
    let position = find_all(&columns.position)?;
    let difference = find_all(columns.difference.as_ref().map_or(&[][..], |d| &d[..]))?;
    let angles = find_all(match &columns.orientation {
        Some(OrientationColumns::Euler { columns, .. }) => &columns[..],
        Some(OrientationColumns::Quaternion { columns }) => &columns[..],
        None => &[],
    })?;
    let sd_position = find_all(columns.sd.as_ref().map_or(&[][..], |s| &s.position[..]))?;
    let sd_orientation = find_all(
        columns
            .sd
            .as_ref()
            .and_then(|s| s.orientation.as_ref())
            .map_or(&[][..], |o| &o[..]),
    )?;
    let channels = find_all(&columns.channels)?;
    // The decimal mark is judged on the numbers read (a time column is not a number).
    let numeric: Vec<usize> = stamp
        .iter()
        .chain(time.iter().filter(|_| {
            columns
                .time
                .as_ref()
                .is_some_and(|t| t.format == TimeFormat::Seconds)
        }))
        .chain(&joints)
        .chain(&position)
        .chain(&difference)
        .chain(&angles)
        .chain(&sd_position)
        .chain(&sd_orientation)
        .chain(&channels)
        .copied()
        .collect();
    let dialect = Dialect {
        delimiter,
        decimal_comma: detect_decimal_comma(&table, delimiter, &numeric, columns.decimal_comma)?,
    };
    let times = match (&columns.time, time) {
        (Some(t), Some(c)) => Some(read_times(&table, dialect, c, &t.format)?),
        _ => None,
    };
    let sign = match columns.sign {
        Difference::Minus => -1.0,
        Difference::Plus | Difference::None => 1.0,
    };
    let mut rows: Vec<(u64, ArmPose)> = Vec::with_capacity(table.rows.len());
    for (row, (line, cells)) in table.rows.iter().enumerate() {
        let value = |c: usize| {
            number(&table, dialect, *line, c, &cells[c])?
                .ok_or_else(|| table.at(*line, c, "empty cell"))
        };
        let values = |cs: &[usize]| {
            cs.iter()
                .map(|&c| value(c))
                .collect::<Result<Vec<f64>, _>>()
        };
        let mut p = [0.0; 3];
        for (axis, v) in p.iter_mut().enumerate() {
            *v = value(position[axis])?;
            if let Some(&d) = difference.get(axis) {
                *v += sign * value(d)?;
            }
            *v *= columns.length_scale;
        }
        let angle = values(&angles)?;
        let orientation = match &columns.orientation {
            Some(OrientationColumns::Euler { order, frame, .. }) => {
                let a = [angle[0], angle[1], angle[2]].map(|v| v * columns.angle_scale);
                Some(euler_rotation(a, *order, *frame))
            }
            Some(OrientationColumns::Quaternion { .. }) => Some(
                quaternion_rotation([angle[0], angle[1], angle[2], angle[3]])
                    .map_err(|e| table.at(*line, angles[0], e))?,
            ),
            None => None,
        };
        let mut reading_sd = None;
        if !sd_position.is_empty() {
            let positive = |cs: &[usize], scale: f64| -> Result<[f64; 3], DataError> {
                let mut out = [0.0; 3];
                for (o, &c) in out.iter_mut().zip(cs) {
                    let v = value(c)?;
                    if v <= 0.0 {
                        return Err(table.at(
                            *line,
                            c,
                            format!("a standard deviation must be positive, got {v}"),
                        ));
                    }
                    *o = v * scale;
                }
                Ok(out)
            };
            reading_sd = Some(ReadingSd {
                position_mm: positive(&sd_position, columns.length_scale)?,
                orientation_deg: (!sd_orientation.is_empty())
                    .then(|| positive(&sd_orientation, columns.angle_scale.to_degrees()))
                    .transpose()?,
            });
        }
        let mut pose = ArmPose {
            stamp: match (stamp, &times) {
                (Some(c), _) => value(c)?,
                (None, Some(t)) => t[row],
                (None, None) => (row + 1) as f64,
            },
            joints: values(&joints)?
                .into_iter()
                .map(|q| q * columns.joint_scale)
                .collect(),
            position: Point3::from(p),
            orientation,
            channels: values(&channels)?,
            reading_sd,
            approach: Vec::new(),
        };
        if let (Some(tool), Some(q)) = (&columns.tool, pose.orientation) {
            apply_tool(&mut pose, q, tool);
        }
        rows.push((*line, pose));
    }
    if columns.order == RowOrder::Time {
        rows.sort_by(|a, b| a.1.stamp.total_cmp(&b.1.stamp));
    }
    if let (Some(t), Some(c)) = (&columns.time, time) {
        check_time_order(&table, c, &t.column, &rows)?;
    }
    let imported = ArmPoses {
        stamp: if columns.time.is_some() {
            "time"
        } else {
            "pose"
        }
        .into(),
        oriented: columns.orientation.is_some(),
        channels: columns.channels.clone(),
        poses: rows.into_iter().map(|(_, p)| p).collect(),
    };
    // What the pose-file reader refuses (a stamp that does not increase, a channel named
    // like a pose column, no poses), refused here too, naming the export.
    parse_arm_poses(&imported.to_csv(), file, columns.joints.len()).map_err(|e| {
        file_err(
            file,
            format!("the imported poses are not a valid pose file: {e}"),
        )
    })
}

/// Refuses a mapping that cannot be read one way only.
fn check_mapping(file: &str, columns: &PoseColumns) -> Result<(), DataError> {
    let refuse = |message: &str| Err(file_err(file, message));
    if columns.joints.is_empty() {
        return refuse("the mapping names no joint column");
    }
    if (columns.sign == Difference::None) != columns.difference.is_none() {
        return refuse(
            "a difference needs its three columns and its sign (minus or plus), and only then",
        );
    }
    if columns.stamp.is_some() && columns.time.is_some() {
        return refuse(
            "a pose number column and a time column: the pose file's stamp is one of them",
        );
    }
    if columns.order == RowOrder::Time && columns.time.is_none() {
        return refuse("ordering the rows by time needs a time column");
    }
    if columns.tool.is_some() && columns.orientation.is_none() {
        return refuse(
            "a tool transform moves the measured pose, so it needs the orientation columns",
        );
    }
    if columns.sd.as_ref().is_some_and(|s| s.orientation.is_some()) && columns.orientation.is_none()
    {
        return refuse("orientation SD columns without orientation columns");
    }
    for (what, scale) in [
        ("joint scale", columns.joint_scale),
        ("length scale", columns.length_scale),
        ("angle scale", columns.angle_scale),
    ] {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(file_err(
                file,
                format!("the {what} must be positive, got {scale}"),
            ));
        }
    }
    Ok(())
}

/// Each row's time in seconds: as written, or since the earliest row for a date and
/// time pattern.
fn read_times(
    table: &Table,
    dialect: Dialect,
    c: usize,
    format: &TimeFormat,
) -> Result<Vec<f64>, DataError> {
    let mut times = Vec::with_capacity(table.rows.len());
    match format {
        TimeFormat::Seconds => {
            for (line, cells) in &table.rows {
                times.push(
                    number(table, dialect, *line, c, &cells[c])?
                        .ok_or_else(|| table.at(*line, c, "empty cell"))?,
                );
            }
        }
        TimeFormat::Pattern(pattern) => {
            let items = time::format_description::parse_borrowed::<2>(pattern)
                .map_err(|e| file_err(table.file, format!("time format {pattern:?}: {e}")))?;
            for (line, cells) in &table.rows {
                let at = time::PrimitiveDateTime::parse(&cells[c], &items).map_err(|e| {
                    table.at(
                        *line,
                        c,
                        format!("{:?} does not read as {pattern:?}: {e}", cells[c]),
                    )
                })?;
                let t = at.assume_utc();
                times.push(t.unix_timestamp() as f64 + f64::from(t.nanosecond()) * 1e-9);
            }
            let first = times.iter().copied().fold(f64::INFINITY, f64::min);
            for t in &mut times {
                *t -= first;
            }
        }
    }
    Ok(times)
}

/// Refuses two rows at one time, and, in file order, a time that goes back, naming the
/// lines.
fn check_time_order(
    table: &Table,
    c: usize,
    name: &str,
    rows: &[(u64, ArmPose)],
) -> Result<(), DataError> {
    for pair in rows.windows(2) {
        let ((before, a), (line, b)) = (&pair[0], &pair[1]);
        if b.stamp > a.stamp {
            continue;
        }
        let message = if b.stamp == a.stamp {
            format!(
                "the same time as line {before} ({name} gives both {} s)",
                a.stamp
            )
        } else {
            format!(
                "earlier than line {before} before it ({} s before): the rows are not in time \
                 order; order the rows by time, or number them in file order (no time column)",
                a.stamp - b.stamp
            )
        };
        return Err(table.at(*line, c, message));
    }
    Ok(())
}

/// Moves a measured pose (orientation `q`) to the tool point `tool` puts in its frame; the
/// position SD grows by the orientation SD over the tool's lever.
fn apply_tool(pose: &mut ArmPose, q: UnitQuaternion<f64>, tool: &Isometry3<f64>) {
    let moved = Isometry3::from_parts(pose.position.coords.into(), q) * tool;
    pose.position = Point3::from(moved.translation.vector);
    pose.orientation = Some(moved.rotation);
    if let Some(sd) = &mut pose.reading_sd {
        if let Some(angle) = sd.orientation_rad() {
            let lever = tool.translation.vector.norm() * angle;
            for v in &mut sd.position_mm {
                *v = v.hypot(lever);
            }
        }
    }
}
