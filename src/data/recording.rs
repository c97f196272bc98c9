//! The recording CSV of docs/twin.md: `t`, one column per sensor channel, then the laser
//! tracker's pose `x,y,z` (mm) and `rx,ry,rz` (rotation vector, rad). Empty cells mean
//! "no sample at this tick" (slower sensors, the tracker between its samples).
//!
//! Also the calibration measurement set: commanded joint inputs `q1..q3` (mm), `q4,q5`
//! (deg) and the measured pose per row.
//!
//! Readers reject bad input with `file:line:column` and never drop anything silently. The
//! writers end every line with a newline, so a file whose last line has none was cut
//! short and is refused (`file:line: the file ends inside this line ...`).

use std::fmt::Write as _;
use std::path::Path;

use crate::atomic;
use crate::twin::PLAN_CHANNELS;

/// The tracker's columns, in order.
pub const TRACKER_COLUMNS: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];
/// The joint-input columns of a calibration set.
pub const JOINT_COLUMNS: [&str; 5] = ["q1", "q2", "q3", "q4", "q5"];

/// What went wrong reading or writing a data file, and where.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A problem with the file as a whole (cannot be read, bad header, too short).
    #[error("{file}: {message}")]
    File {
        /// The file's path.
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A problem with one line as a whole (a truncated last line).
    #[error("{file}:{line}: {message}")]
    Line {
        /// The file's path.
        file: String,
        /// The line, from 1 (the header is line 1).
        line: u64,
        /// What is wrong.
        message: String,
    },
    /// A problem at one cell or line.
    #[error("{file}:{line}:{column}: {message}")]
    At {
        /// The file's path.
        file: String,
        /// The line, from 1 (the header is line 1).
        line: u64,
        /// The header name of the cell at fault.
        column: String,
        /// What is wrong.
        message: String,
    },
}

impl crate::error::StageError for DataError {}

pub(super) fn file_err(file: &str, message: impl Into<String>) -> DataError {
    DataError::File {
        file: file.to_string(),
        message: message.into(),
    }
}

/// The tracker columns `[x, y, z, rx, ry, rz]` (mm, rotation vector in rad) as a pose.
pub fn tracker_pose(p: &[f64; 6]) -> nalgebra::Isometry3<f64> {
    nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(p[0], p[1], p[2]),
        nalgebra::UnitQuaternion::from_scaled_axis(nalgebra::Vector3::new(p[3], p[4], p[5])),
    )
}

/// A pose as the tracker columns `[x, y, z, rx, ry, rz]`.
pub fn tracker_columns(pose: &nalgebra::Isometry3<f64>) -> [f64; 6] {
    let (v, r) = (pose.translation.vector, pose.rotation.scaled_axis());
    [v.x, v.y, v.z, r.x, r.y, r.z]
}

/// The sensor columns a recording must have for `nodes`: the graph's nodes, the joint
/// inputs Q1–Q5 the labels need, and the polishing force F.
pub fn expected_channels(nodes: &[String]) -> Vec<String> {
    let mut c = nodes.to_vec();
    for extra in ["Q1", "Q2", "Q3", "Q4", "Q5", "F"] {
        if !c.iter().any(|n| n == extra) {
            c.push(extra.to_string());
        }
    }
    c
}

/// One tick of a recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Run time, s.
    pub t: f64,
    /// One entry per [`Recording::channels`]; `None` where the sensor had no sample.
    pub values: Vec<Option<f64>>,
    /// Tracker pose `[x, y, z, rx, ry, rz]` when it measured at this tick.
    pub tracker: Option<[f64; 6]>,
}

/// A recording: channel names and rows in time order.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// The sensor column names, in file order (without `t` and the tracker's columns).
    pub channels: Vec<String>,
    /// One row per control tick, in time order.
    pub rows: Vec<Row>,
}

fn cell(out: &mut String, v: Option<f64>) {
    out.push(',');
    if let Some(v) = v {
        // Rust's shortest round-trip formatting: the file reads back bit for bit.
        // invariant: writing to a String cannot fail.
        write!(out, "{v}").expect("writing to a String");
    }
}

impl Recording {
    /// The CSV text (deterministic: the same recording gives the same bytes).
    pub fn to_csv(&self) -> String {
        let mut out = String::from("t");
        for c in self
            .channels
            .iter()
            .map(String::as_str)
            .chain(TRACKER_COLUMNS)
        {
            out.push(',');
            out.push_str(c);
        }
        out.push('\n');
        for r in &self.rows {
            // invariant: writing to a String cannot fail.
            write!(out, "{}", r.t).expect("writing to a String");
            for &v in &r.values {
                cell(&mut out, v);
            }
            for k in 0..6 {
                cell(&mut out, r.tracker.map(|p| p[k]));
            }
            out.push('\n');
        }
        out
    }

    /// Writes the CSV atomically (temporary file, then rename).
    pub fn write(&self, path: &Path) -> Result<(), DataError> {
        atomic::write(path, self.to_csv().as_bytes())
            .map_err(|e| file_err(&path.display().to_string(), e.to_string()))
    }

    /// Reads a recording whose sensor columns must be exactly `channels` (any order in
    /// the file; returned in file order), besides which the twin's planned-motion columns
    /// ([`PLAN_CHANNELS`]) may be there, with at least `min_rows` rows.
    pub fn read(path: &Path, channels: &[&str], min_rows: usize) -> Result<Recording, DataError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| file_err(&file, e.to_string()))?;
        Recording::parse(&text, &file, channels, min_rows)
    }

    /// Parses CSV text; `file` names the source in errors.
    pub fn parse(
        text: &str,
        file: &str,
        channels: &[&str],
        min_rows: usize,
    ) -> Result<Recording, DataError> {
        let table = Table::parse(text, file)?;
        let header = &table.header;
        if header.first().map(String::as_str) != Some("t") {
            return Err(table.at(
                1,
                0,
                format!(
                    "the first column must be `t` (time in seconds), not {:?}{}",
                    header[0],
                    arm_hint(header)
                ),
            ));
        }
        table.check_unique(1)?;
        let n = header.len();
        // The tracker's six columns end the header; anything after them is extra.
        let tracker_at = (1..n.saturating_sub(5)).find(|&i| {
            header[i..i + 6]
                .iter()
                .map(String::as_str)
                .eq(TRACKER_COLUMNS)
        });
        let Some(tracker_at) = tracker_at else {
            let rule = "the last six columns must be the tracker pose x,y,z,rx,ry,rz";
            if let Some(c) = TRACKER_COLUMNS
                .iter()
                .find(|c| !header.iter().any(|h| h == *c))
            {
                return Err(file_err(
                    file,
                    format!("missing tracker column {c:?}: {rule}"),
                ));
            }
            // All six are there, but not side by side in order: name the first cell that
            // breaks the run starting at `x`.
            let x = header.iter().position(|h| h == "x").unwrap_or(0);
            let Some(i) = (x..n).find(|&i| header[i] != TRACKER_COLUMNS[(i - x).min(5)]) else {
                // The run from `x` reaches the end in order but is short: the rest of the
                // tracker's columns stand before it.
                let i = (1..x)
                    .find(|&i| TRACKER_COLUMNS.contains(&header[i].as_str()))
                    .unwrap_or(x);
                return Err(table.at(
                    1,
                    i,
                    format!(
                        "column {} is {:?}, before the tracker's x: {rule}",
                        i + 1,
                        header[i]
                    ),
                ));
            };
            return Err(table.at(
                1,
                i,
                format!(
                    "column {} is {:?} where {:?} belongs: {rule}",
                    i + 1,
                    header[i],
                    TRACKER_COLUMNS[(i - x).min(5)]
                ),
            ));
        };
        if tracker_at + 6 < n {
            let i = tracker_at + 6;
            return Err(table.at(
                1,
                i,
                format!(
                    "unexpected column {:?} (column {}) after the tracker's rz: the last six \
                     columns must be the tracker pose x,y,z,rx,ry,rz",
                    header[i],
                    i + 1
                ),
            ));
        }
        let sensor_cols = &header[1..n - 6];
        for (i, c) in sensor_cols.iter().enumerate() {
            // The twin's planned-motion columns may always be there: a graph without
            // them as nodes leaves them unread.
            if !channels.contains(&c.as_str()) && !PLAN_CHANNELS.contains(&c.as_str()) {
                return Err(table.at(
                    1,
                    i + 1,
                    format!(
                        "unexpected column {c:?} (column {}); expected channels: {}",
                        i + 2,
                        channels.join(",")
                    ),
                ));
            }
        }
        if let Some(missing) = channels
            .iter()
            .find(|c| !sensor_cols.iter().any(|s| s == *c))
        {
            return Err(file_err(file, format!("missing column {missing:?}")));
        }
        let mut rows = Vec::with_capacity(table.rows.len());
        let mut last_t = f64::NEG_INFINITY;
        for (line, cells) in &table.rows {
            let t = table
                .number(*line, 0, &cells[0])?
                .ok_or_else(|| table.at(*line, 0, "time is empty"))?;
            if t <= last_t {
                return Err(table.at(
                    *line,
                    0,
                    format!("time goes backwards or repeats: {t} after {last_t}"),
                ));
            }
            last_t = t;
            let values = (1..n - 6)
                .map(|c| table.number(*line, c, &cells[c]))
                .collect::<Result<Vec<_>, _>>()?;
            let pose = (n - 6..n)
                .map(|c| table.number(*line, c, &cells[c]))
                .collect::<Result<Vec<_>, _>>()?;
            let tracker = match pose.iter().filter(|v| v.is_some()).count() {
                0 => None,
                6 => {
                    // invariant: this arm counted six present values.
                    let p = [0, 1, 2, 3, 4, 5].map(|k| pose[k].expect("all six present"));
                    table.check_rotation(*line, n - 3, &p)?;
                    Some(p)
                }
                _ => {
                    // invariant: this arm has 1 to 5 of the six present, so one is empty.
                    let c = (0..6).find(|&k| pose[k].is_none()).expect("one is empty");
                    return Err(table.at(
                        *line,
                        n - 6 + c,
                        "the tracker pose is incomplete: give all six values or none",
                    ));
                }
            };
            rows.push(Row { t, values, tracker });
        }
        if rows.len() < min_rows {
            return Err(file_err(
                file,
                format!(
                    "{} rows, but at least {min_rows} are needed (one window)",
                    rows.len()
                ),
            ));
        }
        Ok(Recording {
            channels: sensor_cols.to_vec(),
            rows,
        })
    }
}

/// A calibration measurement: commanded joint inputs (mm, mm, mm, deg, deg) and the
/// tracker's pose `[x, y, z, rx, ry, rz]`.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationRow {
    /// `q1`–`q3` (UPS limb lengths, mm), `q4`, `q5` (serial joint angles, deg).
    pub joints: [f64; 5],
    /// The tracker's pad pose `[x, y, z]` (mm) and `[rx, ry, rz]` (rotation vector, rad),
    /// tracker frame.
    pub pose: [f64; 6],
}

/// Writes a calibration set atomically.
pub fn write_calibration_set(path: &Path, rows: &[CalibrationRow]) -> Result<(), DataError> {
    atomic::write(path, calibration_set_csv(rows).as_bytes())
        .map_err(|e| file_err(&path.display().to_string(), e.to_string()))
}

/// A calibration set as CSV text (what [`write_calibration_set`] writes).
pub fn calibration_set_csv(rows: &[CalibrationRow]) -> String {
    let mut out = JOINT_COLUMNS
        .iter()
        .chain(&TRACKER_COLUMNS)
        .copied()
        .collect::<Vec<_>>()
        .join(",");
    out.push('\n');
    for r in rows {
        let cells: Vec<String> = r
            .joints
            .iter()
            .chain(&r.pose)
            .map(|v| format!("{v}"))
            .collect();
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

/// Reads a calibration set: columns q1..q5, x,y,z,rx,ry,rz, every cell a finite number.
pub fn read_calibration_set(path: &Path) -> Result<Vec<CalibrationRow>, DataError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| file_err(&file, e.to_string()))?;
    parse_calibration_set(&text, &file)
}

/// Parses a calibration set's CSV text; `file` names the source in errors.
///
/// ```
/// use iastgcn::data::recording::parse_calibration_set;
///
/// let text = "q1,q2,q3,q4,q5,x,y,z,rx,ry,rz\n\
///             700,710,720,0,10,1500,-800,1100,3.1,0,0.5\n";
/// let rows = parse_calibration_set(text, "cal.csv")?;
/// assert_eq!(rows[0].joints, [700.0, 710.0, 720.0, 0.0, 10.0]);
///
/// let err = parse_calibration_set("q1,q2\n1,2\n", "bad.csv").unwrap_err();
/// assert!(err.to_string().starts_with("bad.csv: the header must be"));
///
/// // A file that stops inside its last line was cut short.
/// let err = parse_calibration_set(&text[..text.len() - 2], "cut.csv").unwrap_err();
/// assert!(err.to_string().starts_with("cut.csv:2: the file ends inside this line"));
/// # Ok::<(), iastgcn::data::DataError>(())
/// ```
pub fn parse_calibration_set(text: &str, file: &str) -> Result<Vec<CalibrationRow>, DataError> {
    let table = Table::parse(text, file)?;
    let expected: Vec<&str> = JOINT_COLUMNS
        .iter()
        .chain(&TRACKER_COLUMNS)
        .copied()
        .collect();
    let header = &table.header;
    let rule = format!("the header must be {}", expected.join(","));
    table.check_unique(0).map_err(|e| with_rule(e, &rule))?;
    if let Some(i) = header.iter().position(|h| !expected.contains(&h.as_str())) {
        return Err(table.at(
            1,
            i,
            format!(
                "unexpected column {:?} (column {}); {rule}{}",
                header[i],
                i + 1,
                arm_hint(header)
            ),
        ));
    }
    if let Some(missing) = expected.iter().find(|c| !header.iter().any(|h| h == *c)) {
        return Err(file_err(
            file,
            format!("{rule}: missing column {missing:?}"),
        ));
    }
    if let Some(i) = (0..header.len()).find(|&i| header[i] != expected[i]) {
        return Err(table.at(
            1,
            i,
            format!(
                "column {} is {:?} where {:?} belongs; {rule}",
                i + 1,
                header[i],
                expected[i]
            ),
        ));
    }
    let mut rows = Vec::with_capacity(table.rows.len());
    for (line, cells) in &table.rows {
        let mut v = [0.0; 11];
        for (c, x) in v.iter_mut().enumerate() {
            *x = table
                .number(*line, c, &cells[c])?
                .ok_or_else(|| table.at(*line, c, "empty cell"))?;
        }
        table.check_rotation(*line, 8, &[v[5], v[6], v[7], v[8], v[9], v[10]])?;
        rows.push(CalibrationRow {
            joints: [v[0], v[1], v[2], v[3], v[4]],
            pose: [v[5], v[6], v[7], v[8], v[9], v[10]],
        });
    }
    if rows.is_empty() {
        return Err(file_err(file, "no measurements"));
    }
    Ok(rows)
}

/// `e` with `rule` added to its message.
fn with_rule(e: DataError, rule: &str) -> DataError {
    match e {
        DataError::At {
            file,
            line,
            column,
            message,
        } => DataError::At {
            file,
            line,
            column,
            message: format!("{message}; {rule}"),
        },
        other => other,
    }
}

/// A parsed CSV: header and rows with their 1-based line numbers.
pub(super) struct Table<'a> {
    pub(super) file: &'a str,
    pub(super) header: Vec<String>,
    pub(super) rows: Vec<(u64, Vec<String>)>,
}

impl<'a> Table<'a> {
    pub(super) fn parse(text: &str, file: &'a str) -> Result<Table<'a>, DataError> {
        Table::parse_delimited(text, file, b',', true)
    }

    /// [`Table::parse`] with cells separated by `delimiter` (`;` or a tab in exports
    /// written for a locale whose decimal mark is the comma). Another program's export
    /// may end without a newline (`final_newline` false): its last line is then read as
    /// it is, a missing cell still refused.
    pub(super) fn parse_delimited(
        text: &str,
        file: &'a str,
        delimiter: u8,
        final_newline: bool,
    ) -> Result<Table<'a>, DataError> {
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .delimiter(delimiter)
            .from_reader(text.as_bytes());
        // Our writers end every line with a newline, so a file that stops inside its last
        // line was cut short (a copy or a write that did not finish).
        if final_newline && !text.is_empty() && !text.ends_with('\n') {
            return Err(DataError::Line {
                file: file.to_string(),
                line: text.matches('\n').count() as u64 + 1,
                message: "the file ends inside this line (no newline at the end): it looks \
                          truncated; if it is complete, end it with a newline"
                    .to_string(),
            });
        }
        let header: Vec<String> = reader
            .headers()
            .map_err(|e| file_err(file, e.to_string()))?
            .iter()
            .map(|h| h.trim().to_string())
            .collect();
        if header.iter().all(String::is_empty) {
            return Err(file_err(file, "empty file: no header"));
        }
        let mut rows = Vec::new();
        for record in reader.records() {
            let record = record.map_err(|e| match e.position() {
                Some(p) => match e.kind() {
                    csv::ErrorKind::UnequalLengths {
                        expected_len, len, ..
                    } => {
                        let (expected_len, len) = (*expected_len as usize, *len as usize);
                        let (column, detail) = if len > expected_len {
                            (
                                format!("#{}", expected_len + 1),
                                format!(
                                    "an extra cell (column {}) after the last column {:?}",
                                    expected_len + 1,
                                    header.last().map_or("", String::as_str)
                                ),
                            )
                        } else {
                            (
                                header
                                    .get(len)
                                    .cloned()
                                    .unwrap_or_else(|| format!("#{}", len + 1)),
                                format!("the cells from column {} on are missing", len + 1),
                            )
                        };
                        DataError::At {
                            file: file.to_string(),
                            line: p.line(),
                            column,
                            message: format!(
                                "{len} fields, but the header has {expected_len}: {detail}"
                            ),
                        }
                    }
                    _ => DataError::At {
                        file: file.to_string(),
                        line: p.line(),
                        column: "-".to_string(),
                        message: e.to_string(),
                    },
                },
                None => file_err(file, e.to_string()),
            })?;
            let line = record.position().map_or(0, |p| p.line());
            rows.push((line, record.iter().map(|c| c.trim().to_string()).collect()));
        }
        Ok(Table { file, header, rows })
    }

    pub(super) fn at(&self, line: u64, column: usize, message: impl Into<String>) -> DataError {
        DataError::At {
            file: self.file.to_string(),
            line,
            column: self
                .header
                .get(column)
                .cloned()
                .unwrap_or_else(|| format!("#{}", column + 1)),
            message: message.into(),
        }
    }

    /// An error at the first header name (from column `from`) that repeats an earlier one.
    pub(super) fn check_unique(&self, from: usize) -> Result<(), DataError> {
        for i in from..self.header.len() {
            let c = &self.header[i];
            if let Some(j) = self.header[from..i].iter().position(|h| h == c) {
                return Err(self.at(
                    1,
                    i,
                    format!(
                        "column {c:?} appears twice (columns {} and {})",
                        from + j + 1,
                        i + 1
                    ),
                ));
            }
        }
        Ok(())
    }

    /// An error at `rx` (column `rx`) of `line` when the rotation vector of the tracker
    /// pose `p` (`[x, y, z, rx, ry, rz]`) is too long to be turned into a rotation.
    fn check_rotation(&self, line: u64, rx: usize, p: &[f64; 6]) -> Result<(), DataError> {
        if nalgebra::Vector3::new(p[3], p[4], p[5]).norm().is_finite() {
            return Ok(());
        }
        Err(self.at(
            line,
            rx,
            format!(
                "the rotation vector ({}, {}, {}) is too long to be a rotation (its length overflows)",
                p[3], p[4], p[5]
            ),
        ))
    }

    /// A cell as a finite number, `None` when empty.
    pub(super) fn number(
        &self,
        line: u64,
        column: usize,
        cell: &str,
    ) -> Result<Option<f64>, DataError> {
        if cell.is_empty() {
            return Ok(None);
        }
        let v: f64 = cell
            .parse()
            .map_err(|_| self.at(line, column, format!("not a number: {cell:?}")))?;
        if !v.is_finite() {
            return Err(self.at(line, column, format!("not a finite number: {cell:?}")));
        }
        Ok(Some(v))
    }
}

/// A hint for a serial arm's pose file (docs/arms.md: first column `pose` or `time`)
/// given where the hybrid machine's recording or measurement set was expected.
fn arm_hint(header: &[String]) -> &'static str {
    match header.first().map(String::as_str) {
        Some("pose" | "time") => {
            "; this looks like a serial arm's pose file, which is read with the arm's \
             description (sources.robot, kind = \"serial\", docs/arms.md)"
        }
        _ => "",
    }
}
