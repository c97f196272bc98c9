//! Importing a tracker export into a serial arm's pose file (docs/arms.md "Importing
//! tracker exports"): any CSV with a header, its columns mapped by name to the pose
//! file's (`data::arm_poses`). The measured position is either given directly or as a
//! reference point (e.g. the commanded one) plus or minus a difference column per axis,
//! the layout of exports that store "commanded minus measured". Joint angles in degrees
//! or radians, lengths in mm or m; further columns become sensor channels.

use std::path::Path;

use nalgebra::Point3;

use super::arm_poses::{parse_arm_poses, ArmPoses};
use super::recording::{file_err, DataError, Table};
use crate::robot::arm::ArmPose;

/// How the measured position is read from the position columns and, when given, a
/// difference per axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Difference {
    /// The position columns are the measured point.
    None,
    /// measured = position − difference (the file stores reference minus measured).
    Minus,
    /// measured = position + difference (the file stores measured minus reference).
    Plus,
}

/// Which column of the export is what.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseColumns {
    /// The pose number or time column (increasing); `None` numbers the rows 1, 2, ….
    pub stamp: Option<String>,
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
    /// Further columns kept as sensor channels, under their own names.
    pub channels: Vec<String>,
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
///     joint_scale: 1.0,
///     length_scale: 1.0,
///     channels: vec![],
/// };
/// let poses = parse_export(text, "export.csv", &columns)?;
/// assert_eq!(poses.poses[0].position.coords.as_slice(), [99.0, -2.0, 51.0]);
/// # Ok::<(), iastgcn::data::DataError>(())
/// ```
pub fn parse_export(text: &str, file: &str, columns: &PoseColumns) -> Result<ArmPoses, DataError> {
    if columns.joints.is_empty() {
        return Err(file_err(file, "the mapping names no joint column"));
    }
    if (columns.sign == Difference::None) != columns.difference.is_none() {
        return Err(file_err(
            file,
            "a difference needs its three columns and its sign (minus or plus), and only then",
        ));
    }
    for (what, scale) in [
        ("joint scale", columns.joint_scale),
        ("length scale", columns.length_scale),
    ] {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(file_err(
                file,
                format!("the {what} must be positive, got {scale}"),
            ));
        }
    }
    let table = Table::parse(text, file)?;
    let find = |name: &str| {
        table.header.iter().position(|h| h == name).ok_or_else(|| {
            file_err(
                file,
                format!(
                    "no column {name:?}; the header has {}",
                    table.header.join(",")
                ),
            )
        })
    };
    let stamp = columns.stamp.as_deref().map(find).transpose()?;
    let joints = columns
        .joints
        .iter()
        .map(|c| find(c))
        .collect::<Result<Vec<_>, _>>()?;
    let position = columns
        .position
        .iter()
        .map(|c| find(c))
        .collect::<Result<Vec<_>, _>>()?;
    let difference = match &columns.difference {
        Some(d) => d.iter().map(|c| find(c)).collect::<Result<Vec<_>, _>>()?,
        None => Vec::new(),
    };
    let channels = columns
        .channels
        .iter()
        .map(|c| find(c))
        .collect::<Result<Vec<_>, _>>()?;
    let sign = match columns.sign {
        Difference::Minus => -1.0,
        Difference::Plus | Difference::None => 1.0,
    };
    let mut poses = Vec::with_capacity(table.rows.len());
    for (row, (line, cells)) in table.rows.iter().enumerate() {
        let value = |c: usize| {
            table
                .number(*line, c, &cells[c])?
                .ok_or_else(|| table.at(*line, c, "empty cell"))
        };
        let mut p = [0.0; 3];
        for (axis, v) in p.iter_mut().enumerate() {
            *v = value(position[axis])?;
            if let Some(&d) = difference.get(axis) {
                *v += sign * value(d)?;
            }
            *v *= columns.length_scale;
        }
        poses.push(ArmPose {
            stamp: match stamp {
                Some(c) => value(c)?,
                None => (row + 1) as f64,
            },
            joints: joints
                .iter()
                .map(|&c| Ok(value(c)? * columns.joint_scale))
                .collect::<Result<_, DataError>>()?,
            position: Point3::from(p),
            orientation: None,
            channels: channels
                .iter()
                .map(|&c| value(c))
                .collect::<Result<_, _>>()?,
            approach: Vec::new(),
        });
    }
    let imported = ArmPoses {
        stamp: "pose".into(),
        oriented: false,
        channels: columns.channels.clone(),
        poses,
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
