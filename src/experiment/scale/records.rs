//! What a finished job records (`models/<job>.job.toml`: [`ScaleRecord`], a
//! [`PathScore`] per path) and the records of a folder.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::experiment::jobs::read_toml;

/// One path's scores of a job: the test split (the three training paths) and the
/// held-out run, against hidden truth, position µm and attitude mdeg.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PathScore {
    /// `grid`, `fermat`, `hilbert` or `rosette`.
    pub path: String,
    /// The held-out session of the run, from 0 ([`HeldOutConfig::session`]).
    #[serde(default)]
    pub session: usize,
    /// Test windows of the path's recording (0 for the rosette, never recorded).
    pub test_windows: usize,
    /// The model's test MAE (NaN for the rosette).
    pub test_mae: [f64; 2],
    /// Mean true pose error of the held-out run: nominal controller, calibrated, the
    /// true residual fed back (oracle), compensated by the model.
    pub initial: [f64; 2],
    /// Calibrated controller.
    pub calibrated: [f64; 2],
    /// The oracle.
    pub oracle: [f64; 2],
    /// Compensated by the model.
    pub compensated: [f64; 2],
    /// The model's open-loop prediction error along the uncompensated run: the mean
    /// distance of its predictions from the true residual (NaN in records written before
    /// it was measured).
    #[serde(default = "unmeasured")]
    pub open_loop: [f64; 2],
    /// Mean true error of the held-out run with the open-loop predictions fed forward as
    /// corrections, without their feedback (NaN in records written before it was
    /// measured).
    #[serde(default = "unmeasured")]
    pub replayed: [f64; 2],
}

pub(super) fn unmeasured() -> [f64; 2] {
    [f64::NAN; 2]
}

impl PathScore {
    /// Share of the calibrated error that compensation (or the oracle) removed, %.
    pub fn removed(&self, by: [f64; 2]) -> [f64; 2] {
        [0, 1].map(|i| 100.0 * (self.calibrated[i] - by[i]) / self.calibrated[i])
    }
}

/// What a finished job left.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleRecord {
    /// `<model>.min<m>.seed<k>`.
    pub name: String,
    /// The model.
    pub model: String,
    /// The training seed.
    pub seed: u64,
    /// Training data per path, minutes.
    pub minutes: f64,
    /// Training windows it trained on.
    pub train_windows: usize,
    /// Best validation loss (standardised) and its epoch, epochs run.
    pub best_val: f64,
    /// Its epoch.
    pub best_epoch: usize,
    /// Core epochs run.
    pub epochs: usize,
    /// Mean epoch time, s.
    pub epoch_seconds: f64,
    /// Where it trained.
    pub trained_on: String,
    /// Wall time of the job in the run that finished it, s.
    pub wall_seconds: f64,
    /// What refinement did, in a study that refines (empty otherwise).
    #[serde(default)]
    pub refinement: String,
    /// How its closed-loop data were made, in a closed-loop study (empty otherwise).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub closed_loop: String,
    /// Scores per path: grid, fermat, hilbert, rosette.
    pub paths: Vec<PathScore>,
}

impl ScaleRecord {
    pub(super) fn load(path: &Path) -> Result<ScaleRecord> {
        read_toml(path)
    }
}

/// The records of every job finished in the folder (by this study or an earlier call
/// with other sizes, seeds or models), by size, seed and name.
pub(super) fn records(out: &Path) -> Result<Vec<ScaleRecord>> {
    let dir = out.join("models");
    let mut records = Vec::new();
    for entry in std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))? {
        let path = entry.map_err(|e| Error::io(&dir, e))?.path();
        if path.to_string_lossy().ends_with(".job.toml") {
            records.push(ScaleRecord::load(&path)?);
        }
    }
    records.sort_by(|a, b| {
        (a.minutes, a.seed, &a.name)
            .partial_cmp(&(b.minutes, b.seed, &b.name))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    Ok(records)
}
