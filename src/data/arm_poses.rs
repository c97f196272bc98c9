//! The pose CSV of a serial arm (docs/arms.md "The pose file"): one measured pose a line.
//!
//! ```text
//! pose,q1,q2,…,qn,x,y,z[,rx,ry,rz][,sd_x,sd_y,sd_z[,sd_rx,sd_ry,sd_rz]][,channel,…]
//! ```
//!
//! `pose` (a number) or `time` (s) first, increasing; the joint values `q1…qn` in
//! degrees (revolute) or mm (prismatic), as many as the description has joints; the
//! measured tool position `x,y,z` in mm in the tracker's frame; optionally its
//! orientation `rx,ry,rz` (roll, pitch, yaw in degrees, R = Rz·Ry·Rx); optionally the
//! reading's standard deviations (`ReadingSd`: mm per axis, then degrees per angle where
//! the orientation is measured), each positive; then any number of further sensor
//! channels, named freely. Every cell is a finite number.

use std::path::Path;

use nalgebra::{Point3, UnitQuaternion};

use super::recording::{file_err, DataError, Table};
use crate::atomic;
use crate::robot::arm::{set_approach, ArmPose, ReadingSd};

/// The position SD columns of a pose file.
pub const POSITION_SD_COLUMNS: [&str; 3] = ["sd_x", "sd_y", "sd_z"];
/// The orientation SD columns.
pub const ORIENTATION_SD_COLUMNS: [&str; 3] = ["sd_rx", "sd_ry", "sd_rz"];

/// A pose file: its extra channels' names and its poses.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmPoses {
    /// `pose` or `time`: what the first column counts.
    pub stamp: String,
    /// Whether the file has the orientation columns.
    pub oriented: bool,
    /// Names of the further sensor channels, in file order.
    pub channels: Vec<String>,
    /// The poses, in file order.
    pub poses: Vec<ArmPose>,
}

/// Reads a pose file for an arm of `joints` joints; errors name file, line and column.
pub fn read_arm_poses(path: &Path, joints: usize) -> Result<ArmPoses, DataError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| file_err(&file, e.to_string()))?;
    parse_arm_poses(&text, &file, joints)
}

/// Parses a pose file's text (`file` names it in errors).
///
/// ```
/// use iastgcn::data::arm_poses::parse_arm_poses;
///
/// let text = "pose,q1,q2,x,y,z,temp_c\n1,10,20,500.5,20,300,21.5\n2,15,25,490,30,310,21.6\n";
/// let file = parse_arm_poses(text, "poses.csv", 2)?;
/// assert_eq!(file.channels, ["temp_c"]);
/// assert_eq!(file.poses[1].joints, [15.0, 25.0]);
///
/// let err = parse_arm_poses(text, "poses.csv", 3).unwrap_err();
/// assert!(err.to_string().contains("q3"), "{err}");
/// # Ok::<(), iastgcn::data::DataError>(())
/// ```
pub fn parse_arm_poses(text: &str, file: &str, joints: usize) -> Result<ArmPoses, DataError> {
    let table = Table::parse(text, file)?;
    let header = &table.header;
    let rule = format!(
        "the header must start pose (or time),q1,…,q{joints},x,y,z, then optionally rx,ry,rz, sd_x,sd_y,sd_z (and sd_rx,sd_ry,sd_rz with the orientation) and further channels"
    );
    table.check_unique(0)?;
    let mut expected: Vec<String> = vec!["pose".into()];
    expected.extend((1..=joints).map(|i| format!("q{i}")));
    expected.extend(["x", "y", "z"].map(String::from));
    if header.len() < expected.len() {
        return Err(file_err(
            file,
            format!(
                "{} columns, fewer than the {} the arm's {joints} joints need; {rule}",
                header.len(),
                expected.len()
            ),
        ));
    }
    for (i, want) in expected.iter().enumerate() {
        let ok = header[i] == *want || (i == 0 && header[i] == "time");
        if !ok {
            let hint = if i > joints && header[i].starts_with('q') {
                " (the description has fewer joints than the file)".to_string()
            } else if i <= joints && header[i] == "x" {
                format!(" (the description has {joints} joints, the file fewer)")
            } else {
                String::new()
            };
            let want = if i == 0 {
                "\"pose\" or \"time\"".to_string()
            } else {
                format!("{want:?}")
            };
            return Err(table.at(
                1,
                i,
                format!(
                    "column {} is {:?} where {want} belongs{hint}; {rule}",
                    i + 1,
                    header[i]
                ),
            ));
        }
    }
    let mut next = expected.len();
    if let Some(extra) = header.get(next).filter(|h| is_joint_column(h)) {
        return Err(table.at(
            1,
            next,
            format!("column {extra:?}: the description has {joints} joints, the file more"),
        ));
    }
    let oriented = header.get(next).is_some_and(|h| h == "rx");
    if oriented {
        for (k, want) in ["rx", "ry", "rz"].iter().enumerate() {
            if header.get(next + k).map(String::as_str) != Some(want) {
                return Err(table.at(
                    1,
                    next + k,
                    format!("the orientation columns are rx,ry,rz together; {rule}"),
                ));
            }
        }
        next += 3;
    }
    let group = |at: usize, names: [&str; 3]| -> Result<bool, DataError> {
        if header.get(at).map(String::as_str) != Some(names[0]) {
            return Ok(false);
        }
        for (k, want) in names.iter().enumerate() {
            if header.get(at + k).map(String::as_str) != Some(want) {
                return Err(table.at(
                    1,
                    at + k,
                    format!("the columns {} go together; {rule}", names.join(",")),
                ));
            }
        }
        Ok(true)
    };
    let position_sd = group(next, POSITION_SD_COLUMNS)?.then_some(next);
    if position_sd.is_some() {
        next += 3;
    }
    let orientation_sd = group(next, ORIENTATION_SD_COLUMNS)?.then_some(next);
    if let Some(at) = orientation_sd {
        if position_sd.is_none() || !oriented {
            return Err(table.at(
                1,
                at,
                format!(
                    "sd_rx,sd_ry,sd_rz need the orientation and sd_x,sd_y,sd_z before them; {rule}"
                ),
            ));
        }
        next += 3;
    }
    let channels: Vec<String> = header[next..].to_vec();
    if let Some(i) = channels.iter().position(|c| c.is_empty()) {
        return Err(table.at(1, next + i, "a channel column without a name"));
    }
    let mut poses = Vec::with_capacity(table.rows.len());
    for (line, v) in table.rows.iter().map(|r| r.0).zip(stamped_rows(&table)?) {
        let sd = |at: usize| -> Result<[f64; 3], DataError> {
            if let Some(k) = (at..at + 3).find(|&k| v[k] <= 0.0) {
                return Err(table.at(
                    line,
                    k,
                    format!("a standard deviation must be positive, got {}", v[k]),
                ));
            }
            Ok([v[at], v[at + 1], v[at + 2]])
        };
        let reading_sd = match position_sd {
            Some(at) => Some(ReadingSd {
                position_mm: sd(at)?,
                orientation_deg: orientation_sd.map(sd).transpose()?,
            }),
            None => None,
        };
        let p = 1 + joints;
        let orientation = oriented.then(|| {
            let [r, pi, y] = [v[p + 3], v[p + 4], v[p + 5]].map(f64::to_radians);
            UnitQuaternion::from_euler_angles(r, pi, y)
        });
        poses.push(ArmPose {
            stamp: v[0],
            joints: v[1..p].to_vec(),
            position: Point3::new(v[p], v[p + 1], v[p + 2]),
            orientation,
            channels: v[next..].to_vec(),
            reading_sd,
            approach: Vec::new(),
        });
    }
    set_approach(&mut poses);
    if poses.is_empty() {
        return Err(file_err(file, "no poses"));
    }
    Ok(ArmPoses {
        stamp: header[0].clone(),
        oriented,
        channels,
        poses,
    })
}

/// Every row's cells as finite numbers, the first column strictly increasing.
fn stamped_rows(table: &Table) -> Result<Vec<Vec<f64>>, DataError> {
    let mut rows = Vec::with_capacity(table.rows.len());
    let mut last = f64::NEG_INFINITY;
    for (line, cells) in &table.rows {
        let mut v = Vec::with_capacity(cells.len());
        for (c, cell) in cells.iter().enumerate() {
            v.push(
                table
                    .number(*line, c, cell)?
                    .ok_or_else(|| table.at(*line, c, "empty cell"))?,
            );
        }
        if v[0] <= last {
            return Err(table.at(
                *line,
                0,
                format!(
                    "{} = {} does not increase (the line before has {last})",
                    table.header[0], v[0]
                ),
            ));
        }
        last = v[0];
        rows.push(v);
    }
    Ok(rows)
}

fn is_joint_column(h: &str) -> bool {
    h.strip_prefix('q')
        .is_some_and(|n| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()))
}

impl ArmPoses {
    /// The file's text (what [`parse_arm_poses`] reads back; numbers round-trip).
    pub fn to_csv(&self) -> String {
        let joints = self.poses.first().map_or(0, |p| p.joints.len());
        let mut header = vec![self.stamp.clone()];
        header.extend((1..=joints).map(|i| format!("q{i}")));
        header.extend(["x", "y", "z"].map(String::from));
        if self.oriented {
            header.extend(["rx", "ry", "rz"].map(String::from));
        }
        let (position_sd, orientation_sd) = self.reading_sd_columns();
        if position_sd {
            header.extend(POSITION_SD_COLUMNS.map(String::from));
        }
        if orientation_sd {
            header.extend(ORIENTATION_SD_COLUMNS.map(String::from));
        }
        header.extend(self.channels.iter().cloned());
        let mut out = header.join(",");
        out.push('\n');
        for p in &self.poses {
            let mut cells: Vec<String> = vec![p.stamp.to_string()];
            cells.extend(p.joints.iter().map(f64::to_string));
            cells.extend(p.position.coords.iter().map(f64::to_string));
            if self.oriented {
                let (r, pi, y) = p
                    .orientation
                    .unwrap_or_else(UnitQuaternion::identity)
                    .euler_angles();
                cells.extend([r, pi, y].map(|a| a.to_degrees().to_string()));
            }
            if let Some(sd) = p.reading_sd.filter(|_| position_sd) {
                cells.extend(sd.position_mm.map(|v| v.to_string()));
                if let Some(a) = sd.orientation_deg.filter(|_| orientation_sd) {
                    cells.extend(a.map(|v| v.to_string()));
                }
            }
            cells.extend(p.channels.iter().map(f64::to_string));
            out.push_str(&cells.join(","));
            out.push('\n');
        }
        out
    }

    /// Whether the file has the position SD columns (every pose has its reading's SD)
    /// and the orientation SD columns (every pose has them too, and the orientation).
    pub fn reading_sd_columns(&self) -> (bool, bool) {
        let all = |f: &dyn Fn(&ReadingSd) -> bool| {
            !self.poses.is_empty()
                && self
                    .poses
                    .iter()
                    .all(|p| p.reading_sd.as_ref().is_some_and(f))
        };
        let position = all(&|_| true);
        (
            position,
            position && self.oriented && all(&|s| s.orientation_deg.is_some()),
        )
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<(), DataError> {
        atomic::write(path, self.to_csv().as_bytes())
            .map_err(|e| file_err(&path.display().to_string(), e.to_string()))
    }
}

/// A list of desired tool points for corrected joint targets: `pose` (or `time`), `x, y,
/// z` (mm, tracker frame), then the sensor channels the models were trained with, as
/// they are expected at each pose.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmTargets {
    /// The file they came from (named in errors about a target).
    pub file: String,
    /// What the first column counts.
    pub stamp: String,
    /// Each target: stamp, point, channel values.
    pub targets: Vec<(f64, Point3<f64>, Vec<f64>)>,
}

/// Reads a target list whose channels must be `channels`; errors name file, line and
/// column.
pub fn read_arm_targets(path: &Path, channels: &[String]) -> Result<ArmTargets, DataError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| file_err(&file, e.to_string()))?;
    parse_arm_targets(&text, &file, channels)
}

/// Parses a target list (`file` names it in errors).
///
/// ```
/// use iastgcn::data::arm_poses::parse_arm_targets;
///
/// let t = parse_arm_targets("pose,x,y,z\n1,500,0,300\n", "t.csv", &[])?;
/// assert_eq!(t.targets[0].1.x, 500.0);
/// let err = parse_arm_targets("pose,x,y,z\n1,500,0,300\n", "t.csv", &["temp_c".into()]);
/// assert!(err.unwrap_err().to_string().contains("temp_c"));
/// # Ok::<(), iastgcn::data::DataError>(())
/// ```
pub fn parse_arm_targets(
    text: &str,
    file: &str,
    channels: &[String],
) -> Result<ArmTargets, DataError> {
    let table = Table::parse(text, file)?;
    let mut expected = vec!["pose".to_string(), "x".into(), "y".into(), "z".into()];
    expected.extend(channels.iter().cloned());
    let rule = format!(
        "the header must be {} (pose or time, the point, then the channels the models were trained with)",
        expected.join(",")
    );
    let header = &table.header;
    for (i, want) in expected.iter().enumerate() {
        let ok = header
            .get(i)
            .is_some_and(|h| h == want || (i == 0 && h == "time"));
        if !ok {
            return match header.get(i) {
                Some(h) => Err(table.at(
                    1,
                    i,
                    format!("column {} is {h:?} where {want:?} belongs; {rule}", i + 1),
                )),
                None => Err(file_err(file, format!("missing column {want:?}; {rule}"))),
            };
        }
    }
    if header.len() > expected.len() {
        let i = expected.len();
        return Err(table.at(1, i, format!("unexpected column {:?}; {rule}", header[i])));
    }
    let mut targets = Vec::with_capacity(table.rows.len());
    for v in stamped_rows(&table)? {
        targets.push((v[0], Point3::new(v[1], v[2], v[3]), v[4..].to_vec()));
    }
    if targets.is_empty() {
        return Err(file_err(file, "no targets"));
    }
    Ok(ArmTargets {
        file: file.to_string(),
        stamp: header[0].clone(),
        targets,
    })
}
