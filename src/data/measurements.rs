//! Measured poses for calibration: a calibration set, or the tracked rows of a recording
//! (the motor encoders Q1–Q5 as the joint inputs), as [`Measurement`]s.

use std::path::Path;

use super::{expected_channels, read_calibration_set, tracker_pose, DataError, Recording};
use crate::calibrate::Measurement;
use crate::graph::Graph;
use crate::robot::Joints;

/// Joint inputs from mm, mm, mm, deg, deg.
fn joints(q: [f64; 5]) -> Joints {
    Joints {
        limbs: [q[0], q[1], q[2]],
        head: [q[3].to_radians(), q[4].to_radians()],
    }
}

/// The measurements of a calibration set (docs/twin.md "File formats").
pub fn read_measurements(path: &Path) -> Result<Vec<Measurement>, DataError> {
    Ok(read_calibration_set(path)?
        .iter()
        .map(|r| Measurement {
            joints: joints(r.joints),
            pose: tracker_pose(&r.pose),
        })
        .collect())
}

/// The rows of a recording that have both the tracker and Q1–Q5, as measurements.
pub fn recording_measurements(path: &Path) -> Result<Vec<Measurement>, DataError> {
    let channels = expected_channels(&Graph::default_asset().nodes);
    let channels: Vec<&str> = channels.iter().map(String::as_str).collect();
    let rec = Recording::read(path, &channels, 1)?;
    let file = path.display().to_string();
    let q =
        crate::graph::HYBRID_JOINT_INPUTS.map(|name| rec.channels.iter().position(|c| c == name));
    let Some(q) = q.into_iter().collect::<Option<Vec<usize>>>() else {
        return Err(DataError::File {
            file,
            message: "the recording has no Q1-Q5 columns".into(),
        });
    };
    let out: Vec<Measurement> = rec
        .rows
        .iter()
        .filter_map(|r| {
            let values: Option<Vec<f64>> = q.iter().map(|&c| r.values[c]).collect();
            Some(Measurement {
                joints: joints(values?.try_into().ok()?),
                pose: tracker_pose(&r.tracker?),
            })
        })
        .collect();
    if out.is_empty() {
        return Err(DataError::File {
            file,
            message: "no row has both the tracker and Q1-Q5".into(),
        });
    }
    Ok(out)
}
