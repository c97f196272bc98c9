//! Geometric calibration from measurement files, with the error before and after on
//! poses the fit never saw: the hybrid machine's EKF and a serial arm's
//! Levenberg–Marquardt. `iastgcn calibrate` prints what these return; the Python
//! package returns it as dictionaries.

use std::path::{Path, PathBuf};

use crate::calibrate::arm::{
    arm_orientation_errors, arm_position_errors, calibrate_arm, ArmCalibration,
    ArmCalibrationConfig,
};
use crate::calibrate::{self, file, hold_out, pose_errors, Calibration, EkfConfig};
use crate::data::arm_poses::read_arm_poses;
use crate::data::{read_measurements, recording_measurements};
use crate::error::{Error, Result};
use crate::robot::arm::Arm;
use crate::robot::{Geometry, Robot};
use crate::stats::Summary;
use crate::twin::RunInfo;

/// How the poses of a measurement file are scored.
#[derive(Clone, Debug)]
pub enum Scoring {
    /// Every how many poses one is held out of the fit (0: none; the fitted poses are
    /// then scored, an optimistic figure).
    HoldOutEvery(usize),
    /// Every pose is fitted; the poses of this separate file are scored.
    TestFile(PathBuf),
}

/// One row of the before/after table: a set of poses under one model.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ErrorRow {
    /// The poses ("held-out poses (16)", a recording's file name); empty on the row
    /// that continues the one above.
    pub label: String,
    /// The model: "initial" (nominal) or "calibrated".
    pub stage: String,
    /// Position error, µm; `None` without poses.
    pub position: Option<Summary>,
    /// Attitude error, mdeg; `None` without poses or for a position-only tracker.
    pub attitude: Option<Summary>,
}

/// `: NAME` of a test file, for a row label.
pub fn test_name(path: &Path) -> String {
    path.file_name()
        .map_or(String::new(), |n| format!(": {}", n.to_string_lossy()))
}

/// The hybrid machine's calibration and its scores.
#[derive(Debug)]
pub struct HybridCalibration {
    /// What the EKF identified.
    pub calibration: Calibration,
    /// Poses fitted.
    pub fitted: usize,
    /// The twin machine the set was measured on, from its sidecar, when it has one.
    pub machine_seed: Option<u64>,
    /// Before/after on the scored poses, then on each recording.
    pub rows: Vec<ErrorRow>,
}

impl HybridCalibration {
    /// Writes the calibration file (TOML) to `out`, atomically.
    pub fn save(&self, out: &Path) -> Result<()> {
        file::save_from(out, &self.calibration, self.fitted, self.machine_seed)?;
        Ok(())
    }
}

/// EKF calibration of the hybrid machine `geometry` from the measurement set at
/// `measurements`, scored as `scoring` says and on each of `recordings` (their tracker
/// poses). Every file is read and every score computed before anything is returned, so
/// a bad recording fails the call with nothing written.
pub fn calibrate_hybrid(
    geometry: Geometry,
    measurements: &Path,
    scoring: &Scoring,
    recordings: &[PathBuf],
) -> Result<HybridCalibration> {
    let nominal = Robot::nominal(geometry);
    // The set's sidecar names the twin machine it was measured on; the file keeps it so
    // that an evaluation on another machine can warn.
    let machine_seed = if RunInfo::sidecar(measurements).exists() {
        Some(
            RunInfo::read(measurements)
                .map_err(Error::Invalid)?
                .machine_seed,
        )
    } else {
        None
    };
    let all = read_measurements(measurements)?;
    let (fit, held) = match scoring {
        Scoring::TestFile(test) => (all, read_measurements(test)?),
        Scoring::HoldOutEvery(every) => hold_out(&all, *every),
    };
    let cal = calibrate::calibrate(&nominal, &fit, &EkfConfig::default()).map_err(|e| {
        Error::from(e).context(format!("calibrating from {}", measurements.display()))
    })?;
    let recordings = recordings
        .iter()
        .map(|p| Ok((p, recording_measurements(p)?)))
        .collect::<Result<Vec<_>>>()?;
    let calibrated = nominal.with_errors(cal.errors.clone());
    let mut rows = Vec::new();
    let mut both = |label: String, poses: &[_]| -> Result<()> {
        for (stage, robot) in [("initial", &nominal), ("calibrated", &calibrated)] {
            let (p, a) = pose_errors(robot, poses)?;
            rows.push(ErrorRow {
                label: if stage == "initial" {
                    label.clone()
                } else {
                    String::new()
                },
                stage: stage.into(),
                position: Summary::of(&p),
                attitude: Summary::of(&a),
            });
        }
        Ok(())
    };
    match scoring {
        // Nothing held out: the fitted poses (the filter saw them) rather than no table.
        _ if held.is_empty() => both(format!("fitted poses ({})", fit.len()), &fit)?,
        Scoring::TestFile(t) => both(format!("test file ({}){}", held.len(), test_name(t)), &held)?,
        Scoring::HoldOutEvery(_) => both(format!("held-out poses ({})", held.len()), &held)?,
    }
    for (path, poses) in &recordings {
        let label = path
            .file_name()
            .map_or("recording".into(), |n| n.to_string_lossy().into_owned());
        both(label, poses)?;
    }
    Ok(HybridCalibration {
        calibration: cal,
        fitted: fit.len(),
        machine_seed,
        rows,
    })
}

/// The position error (µm) and, where the poses have orientation, the orientation error
/// (mdeg) of `arm`'s prediction over `poses`; `None` without poses.
pub fn arm_error_summaries(
    arm: &Arm,
    poses: &[crate::robot::arm::ArmPose],
) -> (Option<Summary>, Option<Summary>) {
    let um: Vec<f64> = arm_position_errors(arm, poses)
        .iter()
        .map(|e| e * 1e3)
        .collect();
    let mdeg: Vec<f64> = arm_orientation_errors(arm, poses)
        .iter()
        .map(|e| e * 1e3)
        .collect();
    (Summary::of(&um), Summary::of(&mdeg))
}

/// A serial arm's calibration and its scores.
#[derive(Debug)]
pub struct SerialCalibration {
    /// Registration, identified parameters, their SD, what was kept nominal.
    pub calibration: ArmCalibration,
    /// Poses held out or in the test file.
    pub scored: usize,
    /// Before/after position error on the fitted poses, then on the scored ones.
    pub rows: Vec<ErrorRow>,
    /// The first line of the calibrated description file: what was fitted from where.
    pub header: String,
}

impl SerialCalibration {
    /// The calibrated description file (TOML with its calibration record).
    pub fn description_toml(&self) -> Result<String> {
        let c = &self.calibration;
        let text = c.arm.to_toml(Some(c.record())).map_err(Error::Invalid)?;
        Ok(format!("{}{text}", self.header))
    }

    /// Writes the calibrated description to `out`, atomically.
    pub fn save(&self, out: &Path) -> Result<()> {
        let text = self.description_toml()?;
        crate::atomic::write(out, text.as_bytes()).map_err(|e| Error::io(out, e))
    }
}

/// Registration, identifiability and Levenberg–Marquardt of the serial arm `nominal`
/// from its pose file `data`, scored as `scoring` says.
pub fn calibrate_serial(
    nominal: &Arm,
    data: &Path,
    scoring: &Scoring,
) -> Result<SerialCalibration> {
    let file = read_arm_poses(data, nominal.joints())?;
    let (fit, held) = match scoring {
        Scoring::HoldOutEvery(every) => hold_out(&file.poses, *every),
        Scoring::TestFile(test) => (
            file.poses.clone(),
            read_arm_poses(test, nominal.joints())?.poses,
        ),
    };
    let held_label = match scoring {
        Scoring::HoldOutEvery(_) => format!("held out ({})", held.len()),
        Scoring::TestFile(test) => format!("test ({}){}", held.len(), test_name(test)),
    };
    let cal = calibrate_arm(nominal, &fit, &ArmCalibrationConfig::default()).map_err(|e| {
        Error::from(e).context(format!(
            "calibrating {} from {}",
            nominal.spec.name,
            data.display()
        ))
    })?;
    let header = format!(
        "# {} calibrated by iastgcn from {} ({} poses fitted, {} {}).\n",
        nominal.spec.name,
        data.display(),
        fit.len(),
        held.len(),
        match scoring {
            Scoring::HoldOutEvery(_) => "held out".to_string(),
            Scoring::TestFile(t) => format!("scored from {}", t.display()),
        }
    );
    let mut rows = Vec::new();
    for (label, poses) in [
        (format!("fitted ({})", fit.len()), &fit),
        (held_label, &held),
    ] {
        if poses.is_empty() {
            continue;
        }
        for (stage, arm) in [
            ("initial (nominal, registered)", &cal.registered),
            ("calibrated", &cal.arm),
        ] {
            let (position, attitude) = arm_error_summaries(arm, poses);
            rows.push(ErrorRow {
                label: if stage == "calibrated" {
                    String::new()
                } else {
                    label.clone()
                },
                stage: stage.into(),
                position,
                attitude,
            });
        }
    }
    Ok(SerialCalibration {
        calibration: cal,
        scored: held.len(),
        rows,
        header,
    })
}
