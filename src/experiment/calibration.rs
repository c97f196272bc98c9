//! Geometric calibration from measurement files, with the error before and after on
//! poses the fit never saw: the hybrid machine's EKF and a serial arm's
//! Levenberg–Marquardt. `iastgcn calibrate` prints what these return; the Python
//! package returns it as dictionaries.

use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::calibrate::arm::{
    arm_orientation_errors, arm_position_errors, calibrate_arm, ArmCalibration,
    ArmCalibrationConfig,
};
use crate::calibrate::{
    self, file, hold_out, hold_out_block, hold_out_random, pose_errors, Calibration, EkfConfig,
};
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
    /// Some poses of the file are held out of the fit and scored.
    HoldOut(HoldOut),
    /// Every pose is fitted; the poses of this separate file are scored.
    TestFile(PathBuf),
}

/// Which poses of a measurement file are held out of the fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HoldOut {
    /// Every how many poses one is held out (0: none; the fitted poses are then scored,
    /// an optimistic figure).
    Every(usize),
    /// The poses from `from_percent` to `to_percent` of the file's order: a stretch of
    /// time (the last 30 %: 70 to 100), or a slab of a grid swept in slabs.
    Block {
        /// Where the block starts, per cent of the poses.
        from_percent: f64,
        /// Where it ends.
        to_percent: f64,
    },
    /// `percent` per cent of the poses, drawn at random with `seed`.
    Random {
        /// How many, per cent of the poses.
        percent: f64,
        /// The draw's seed: the same seed holds out the same poses.
        seed: u64,
    },
}

impl HoldOut {
    /// The positions, in the file's order, of a block from `from_percent` to `to_percent`
    /// of `len` poses (rounded to the nearest pose).
    pub fn block_range(len: usize, from_percent: f64, to_percent: f64) -> Range<usize> {
        let at = |p: f64| ((p / 100.0 * len as f64).round() as usize).min(len);
        at(from_percent)..at(to_percent)
    }

    /// `(fit, held out)` of `all`, each in the file's order. A block outside 0–100 % or
    /// a random share outside 0–100 % is refused.
    pub fn split<T: Clone>(&self, all: &[T]) -> Result<(Vec<T>, Vec<T>)> {
        match *self {
            HoldOut::Every(every) => Ok(hold_out(all, every)),
            HoldOut::Block {
                from_percent,
                to_percent,
            } => {
                let stretch = (0.0..100.0).contains(&from_percent)
                    && from_percent < to_percent
                    && to_percent <= 100.0;
                if !stretch {
                    return Err(Error::Invalid(format!(
                        "the held-out block runs from {from_percent} to {to_percent} % of the poses: \
                         it must be a stretch within 0 to 100 %"
                    )));
                }
                let block = Self::block_range(all.len(), from_percent, to_percent);
                Ok(hold_out_block(all, block))
            }
            HoldOut::Random { percent, seed } => {
                if !(percent > 0.0 && percent < 100.0) {
                    return Err(Error::Invalid(format!(
                        "{percent} % of the poses held out at random: it must be above 0 and below 100"
                    )));
                }
                let count = (percent / 100.0 * all.len() as f64).round() as usize;
                Ok(hold_out_random(all, count, seed))
            }
        }
    }

    /// What a table calls the held-out poses: "held out", "held out, 70–100 % of the
    /// order", "held out at random (30 %, seed 1)".
    pub fn label(&self) -> String {
        match *self {
            HoldOut::Every(_) => "held out".into(),
            HoldOut::Block {
                from_percent,
                to_percent,
            } => format!("held out, {from_percent}–{to_percent} % of the order"),
            HoldOut::Random { percent, seed } => {
                format!("held out at random ({percent} %, seed {seed})")
            }
        }
    }
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
        Scoring::HoldOut(h) => h.split(&all)?,
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
        Scoring::HoldOut(HoldOut::Every(_)) => {
            both(format!("held-out poses ({})", held.len()), &held)?
        }
        Scoring::HoldOut(h) => both(format!("{} ({})", h.label(), held.len()), &held)?,
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
    /// The data file, every pose in its order (fitted and held out).
    pub file: crate::data::arm_poses::ArmPoses,
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
        Scoring::HoldOut(h) => h.split(&file.poses)?,
        Scoring::TestFile(test) => (
            file.poses.clone(),
            read_arm_poses(test, nominal.joints())?.poses,
        ),
    };
    let held_label = match scoring {
        Scoring::HoldOut(h) => format!("{} ({})", h.label(), held.len()),
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
            Scoring::HoldOut(h) => h.label(),
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
        file,
    })
}
