//! The calibration file (TOML) that `calibrate` writes and later stages read: every
//! parameter's estimated error, which ones were identified, their covariance, and how the
//! filter ended.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::identify::Calibration;
use crate::robot::{ErrorParams, Geometry, Robot, N_PARAMS};

/// A calibration file that cannot be written, read or trusted.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct CalibrationFileError {
    /// The file's path.
    pub file: String,
    /// What is wrong, naming the field where it can.
    pub message: String,
}

impl crate::error::StageError for CalibrationFileError {}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StageFile {
    name: String,
    round: usize,
    parameters: usize,
    sweeps: usize,
    gamma: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibrationFile {
    /// Format version.
    version: u32,
    /// Number of measurement poses the filter used.
    measurements: usize,
    /// The twin machine the measurement set was taken on, when its sidecar said.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    machine_seed: Option<u64>,
    /// δX of eq. 18 for every parameter (mm, rad); zero where not identified.
    errors: BTreeMap<String, f64>,
    /// Identified parameters, their posterior σ and covariance (same order).
    identified: Vec<String>,
    sigma: Vec<f64>,
    covariance: Vec<Vec<f64>>,
    /// Condition numbers of the scaled identification Jacobian (serial, parallel, joint).
    condition: Vec<f64>,
    stages: Vec<StageFile>,
}

/// A calibration read back from its file.
#[derive(Clone, Debug)]
pub struct LoadedCalibration {
    /// δX for every parameter (mm, rad): the controller's model is the nominal geometry
    /// with these errors (eq. 18).
    pub errors: ErrorParams,
    /// Names of the identified parameters.
    pub identified: Vec<String>,
    /// Their posterior standard deviations (mm or rad), same order.
    pub sigma: Vec<f64>,
    /// How many measurement poses the filter used.
    pub measurements: usize,
    /// The twin machine the measurement set came from, when known (absent from files
    /// written before this field, and for sets without a `.run.toml` sidecar).
    pub machine_seed: Option<u64>,
}

impl LoadedCalibration {
    /// The calibrated controller's model: `geometry` with these errors (eq. 18).
    pub fn robot(&self, geometry: Geometry) -> Robot {
        Robot::new(geometry, self.errors.clone())
    }
}

/// Writes `cal` to `path` atomically, with no word on the machine it came from.
pub fn save(
    path: &Path,
    cal: &Calibration,
    measurements: usize,
) -> Result<(), CalibrationFileError> {
    save_from(path, cal, measurements, None)
}

/// Writes `cal` to `path` atomically, recording the twin machine its measurement set was
/// taken on (`machine_seed`), so that an evaluation on another machine can say so.
pub fn save_from(
    path: &Path,
    cal: &Calibration,
    measurements: usize,
    machine_seed: Option<u64>,
) -> Result<(), CalibrationFileError> {
    let names = ErrorParams::names();
    let file = CalibrationFile {
        version: 1,
        measurements,
        machine_seed,
        errors: names
            .iter()
            .cloned()
            .zip(cal.errors.values.iter().copied())
            .collect(),
        identified: cal.identified.iter().map(|&k| names[k].clone()).collect(),
        sigma: (0..cal.identified.len())
            .map(|i| cal.covariance[(i, i)].sqrt())
            .collect(),
        covariance: (0..cal.identified.len())
            .map(|i| {
                (0..cal.identified.len())
                    .map(|j| cal.covariance[(i, j)])
                    .collect()
            })
            .collect(),
        condition: cal.condition.clone(),
        stages: cal
            .stages
            .iter()
            .map(|s| StageFile {
                name: s.name.to_string(),
                round: s.round,
                parameters: s.parameters,
                sweeps: s.sweeps,
                gamma: s.gamma,
            })
            .collect(),
    };
    let err = |message: String| CalibrationFileError {
        file: path.display().to_string(),
        message,
    };
    let text = toml::to_string(&file).map_err(|e| err(e.to_string()))?;
    let text = format!(
        "# iastgcn geometric calibration: X_real = X_nom + δX (eq. 18), mm and rad.\n{text}"
    );
    crate::atomic::write(path, text.as_bytes()).map_err(|e| err(e.to_string()))
}

/// How many prior SDs (`identify::default_prior_sigma`) a loaded error value may be at
/// most: 300 mm for a length, 2 to 5 rad for an angle.
pub const PLAUSIBLE_PRIORS: f64 = 1000.0;

/// The calibrated controller's model: `geometry` with the errors of the calibration file
/// at `path` (eq. 18), through [`LoadedCalibration::robot`], as every stage builds it.
pub fn calibrated_robot(geometry: Geometry, path: &Path) -> Result<Robot, CalibrationFileError> {
    Ok(load(path)?.robot(geometry))
}

/// Reads a calibration file, checking names, sizes and values.
pub fn load(path: &Path) -> Result<LoadedCalibration, CalibrationFileError> {
    let name = path.display().to_string();
    let err = |message: String| CalibrationFileError {
        file: name.clone(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
    let f: CalibrationFile = toml::from_str(&text).map_err(|e| err(e.to_string()))?;
    if f.version != 1 {
        return Err(err(format!("unsupported version {}", f.version)));
    }
    let names = ErrorParams::names();
    let prior = super::identify::default_prior_sigma();
    let mut errors = ErrorParams::zero();
    for (k, v) in &f.errors {
        let i = names
            .iter()
            .position(|n| n == k)
            .ok_or_else(|| err(format!("unknown parameter {k:?} in [errors]")))?;
        if !v.is_finite() {
            return Err(err(format!("errors.{k:?} is not finite")));
        }
        // A value far beyond the identification's prior is no error a robot could have
        // (and would only fail later, blamed on the recording the robot cannot follow).
        let bound = PLAUSIBLE_PRIORS * prior[i];
        if v.abs() > bound {
            return Err(err(format!(
                "errors.{k:?} = {v:e}: beyond ±{bound} ({PLAUSIBLE_PRIORS} × its prior SD {} in mm or rad): not a geometric error of this robot",
                prior[i]
            )));
        }
        errors.values[i] = *v;
    }
    if f.errors.len() != N_PARAMS {
        let missing = names
            .iter()
            .find(|n| !f.errors.contains_key(*n))
            .cloned()
            .unwrap_or_default();
        return Err(err(format!(
            "[errors] has {} parameters, expected {N_PARAMS} (missing {missing:?})",
            f.errors.len()
        )));
    }
    if f.sigma.len() != f.identified.len() || f.covariance.len() != f.identified.len() {
        return Err(err(
            "identified, sigma and covariance differ in length".to_string()
        ));
    }
    if let Some(bad) = f.identified.iter().find(|n| !names.contains(n)) {
        return Err(err(format!("unknown identified parameter {bad:?}")));
    }
    for (i, (name, s)) in f.identified.iter().zip(&f.sigma).enumerate() {
        if !(s.is_finite() && *s >= 0.0) {
            return Err(err(format!(
                "sigma[{i}] (of {name}) = {s}: must be a finite number ≥ 0"
            )));
        }
    }
    // A condition number may be infinite (a rank-deficient Jacobian), never NaN.
    if let Some(i) = f.condition.iter().position(|c| c.is_nan() || *c < 0.0) {
        return Err(err(format!(
            "condition[{i}] = {}: must be a number ≥ 0 (inf for a singular Jacobian)",
            f.condition[i]
        )));
    }
    if let Some(s) = f
        .stages
        .iter()
        .find(|s| !(s.gamma.is_finite() && s.gamma >= 0.0))
    {
        return Err(err(format!(
            "stages: gamma = {} of stage {:?} (round {}): must be a finite number ≥ 0",
            s.gamma, s.name, s.round
        )));
    }
    for (i, row) in f.covariance.iter().enumerate() {
        if row.len() != f.identified.len() {
            return Err(err(format!(
                "covariance[{i}] has {} values, expected {} (one per identified parameter)",
                row.len(),
                f.identified.len()
            )));
        }
        if let Some(j) = row.iter().position(|v| !v.is_finite()) {
            return Err(err(format!(
                "covariance[{i}][{j}] = {}: must be finite",
                row[j]
            )));
        }
    }
    Ok(LoadedCalibration {
        errors,
        identified: f.identified,
        sigma: f.sigma,
        measurements: f.measurements,
        machine_seed: f.machine_seed,
    })
}
