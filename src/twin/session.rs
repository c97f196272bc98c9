//! What a recording came from: a sidecar `<recording>.run.toml` beside each simulated CSV
//! names its path and placement, seed, machine, controller and the machine's state at
//! its start (docs/twin.md "Sessions"), so that anyone can tell which runs share data.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::trajectory::{PathKind, PathParams};

/// The provenance of one simulated run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// `grid`, `fermat`, `hilbert`, `rosette` or `calibration`.
    pub path: String,
    /// Rotation of the pattern on the part about the mirror axis, deg.
    pub rotation_deg: f64,
    /// Whether the pattern is walked from its other end.
    pub reverse: bool,
    /// Length of the run, s (0 for a calibration set).
    pub seconds: f64,
    /// Seed of the run: force, feed modulation, sensor noise and drift.
    pub seed: u64,
    /// Seed of the machine: geometric errors, non-geometric sources, sensor mounting.
    pub machine_seed: u64,
    /// The model the controller drives with: `nominal` or the calibration file.
    pub controller: String,
    /// `cold` (the session's first run) or `warm` (after earlier runs of the session).
    pub start: String,
    /// Session time at the run's start, s.
    pub session_clock_s: f64,
    /// Temperature rise of each screw above ambient at the run's start, K.
    pub screw_rise_k: [f64; 3],
}

impl RunInfo {
    /// A polishing run's info (`start` and the temperatures filled in by the caller).
    pub fn polishing(kind: PathKind, params: &PathParams, seconds: f64, seed: u64) -> RunInfo {
        RunInfo {
            path: kind.name().into(),
            rotation_deg: params.rotation_deg,
            reverse: params.reverse,
            seconds,
            seed,
            machine_seed: 1,
            controller: "nominal".into(),
            start: "cold".into(),
            session_clock_s: 0.0,
            screw_rise_k: [0.0; 3],
        }
    }

    /// A calibration measurement set with run seed `seed` on the default machine, measured
    /// cold under the nominal controller.
    pub fn calibration(seed: u64) -> RunInfo {
        RunInfo {
            path: "calibration".into(),
            rotation_deg: 0.0,
            reverse: false,
            seconds: 0.0,
            seed,
            machine_seed: 1,
            controller: "nominal".into(),
            start: "cold".into(),
            session_clock_s: 0.0,
            screw_rise_k: [0.0; 3],
        }
    }

    /// The sidecar's path for a recording at `csv`: `<csv without .csv>.run.toml`.
    pub fn sidecar(csv: &Path) -> PathBuf {
        csv.with_extension("run.toml")
    }

    /// Writes the sidecar of the recording at `csv` (atomically).
    pub fn write(&self, csv: &Path) -> std::io::Result<()> {
        crate::atomic::write(&Self::sidecar(csv), self.to_toml()?.as_bytes())
    }

    /// The sidecar's text.
    pub fn to_toml(&self) -> std::io::Result<String> {
        toml::to_string(self).map_err(std::io::Error::other)
    }

    /// Reads the sidecar of the recording at `csv`; the error names the file.
    pub fn read(csv: &Path) -> Result<RunInfo, String> {
        let path = Self::sidecar(csv);
        let text =
            std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
    }
}
