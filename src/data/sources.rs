//! Where a run's data comes from: recordings, the calibration they are labelled under,
//! and (optionally) other graph and robot assets than the embedded ones. Loading them
//! gives the inputs of [`Dataset::build_normalized`], and of prediction on recordings.

use std::path::PathBuf;

use super::{expected_channels, Dataset, FeatureConfig, Normalization, Recording};
use super::{SplitMode, WindowConfig};
use crate::calibrate::file;
use crate::error::Result;
use crate::graph::Graph;
use crate::robot::{Geometry, Robot};

/// The files of a run's data.
#[derive(Clone, Debug)]
pub struct DataSources {
    /// Recordings (CSV, docs/twin.md "File formats").
    pub recordings: Vec<PathBuf>,
    /// Calibration file: labels are the residuals under this calibrated model.
    pub calibration: PathBuf,
    /// Sensor graph asset (the embedded assets/graph.toml when `None`).
    pub graph: Option<PathBuf>,
    /// Robot geometry asset (the embedded assets/robot.toml when `None`).
    pub robot: Option<PathBuf>,
}

/// The loaded sources: the graph, the calibrated robot and the named recordings.
pub struct Inputs {
    /// The sensor graph.
    pub graph: Graph,
    /// The calibrated robot: the model the labels are computed under (eq. 19).
    pub robot: Robot,
    /// Each recording with its name (its path as given).
    pub recordings: Vec<(String, Recording)>,
}

impl DataSources {
    /// `recordings` labelled under `calibration`, with the embedded graph and robot.
    ///
    /// ```
    /// use iastgcn::data::DataSources;
    ///
    /// let sources = DataSources::new(
    ///     vec!["grid.csv".into(), "fermat.csv".into()],
    ///     "calibration.toml".into(),
    /// );
    /// assert_eq!(sources.recordings.len(), 2);
    /// assert!(sources.graph.is_none() && sources.robot.is_none());
    /// let geometry = sources.geometry()?; // the embedded assets/robot.toml
    /// assert_eq!(geometry.parallel.base_radius, 450.0);
    /// # Ok::<(), iastgcn::error::Error>(())
    /// ```
    pub fn new(recordings: Vec<PathBuf>, calibration: PathBuf) -> DataSources {
        DataSources {
            recordings,
            calibration,
            graph: None,
            robot: None,
        }
    }

    /// The robot geometry (the embedded asset unless [`DataSources::robot`] names one).
    pub fn geometry(&self) -> Result<Geometry> {
        Ok(Geometry::load_or_default(self.robot.as_deref())?)
    }

    /// The twin machine the recordings were taken on, from their `.run.toml` sidecars
    /// (`machine_seed`): the held-out session of an evaluation runs on the same machine.
    /// Recordings without a sidecar say nothing (the twin's default machine, 1, when none
    /// has one); sidecars that name different machines are an error naming both files.
    pub fn machine_seed(&self) -> Result<u64> {
        let mut found: Option<(u64, &PathBuf)> = None;
        for path in &self.recordings {
            if !crate::twin::RunInfo::sidecar(path).exists() {
                continue;
            }
            let info = crate::twin::RunInfo::read(path).map_err(crate::error::Error::Invalid)?;
            match found {
                Some((seed, first)) if seed != info.machine_seed => {
                    return Err(crate::error::Error::Invalid(format!(
                        "{}: recorded on twin machine {}, but {} on machine {seed}; the \
                         recordings of one evaluation come from one machine",
                        path.display(),
                        info.machine_seed,
                        first.display()
                    )))
                }
                Some(_) => {}
                None => found = Some((info.machine_seed, path)),
            }
        }
        Ok(found.map_or(1, |(seed, _)| seed))
    }

    /// The sensor graph: the given asset, or the embedded one for a model predicting
    /// `look_ahead` ticks ahead ([`Graph::default_for`]).
    pub fn graph(&self, look_ahead: usize) -> Result<Graph> {
        Ok(Graph::load_or_default(self.graph.as_deref(), look_ahead)?)
    }

    /// Graph ([`DataSources::graph`] for `window`'s look-ahead), calibrated robot and the
    /// recordings, read with the graph's channels and rows enough for one labelled window
    /// each.
    pub fn load(&self, window: &WindowConfig) -> Result<Inputs> {
        let graph = self.graph(window.look_ahead)?;
        // A window's T rows and the rows up to its label.
        let rows = window.length + window.look_ahead;
        let robot = file::calibrated_robot(self.geometry()?, &self.calibration)?;
        let channels = expected_channels(&graph.nodes);
        let channels: Vec<&str> = channels.iter().map(String::as_str).collect();
        let recordings = self
            .recordings
            .iter()
            .map(|p| {
                Ok((
                    p.display().to_string(),
                    Recording::read(p, &channels, rows)?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Inputs {
            graph,
            robot,
            recordings,
        })
    }

    /// The dataset of these sources, standardised with `fixed` (a model's statistics)
    /// or with its own training split's.
    pub fn dataset(
        &self,
        window: &WindowConfig,
        mode: SplitMode,
        fixed: Option<&Normalization>,
    ) -> Result<(Graph, Dataset)> {
        let inputs = self.load(window)?;
        let data = Dataset::build_normalized(
            &inputs.recordings,
            &inputs.graph,
            &inputs.robot,
            &FeatureConfig::default(),
            window,
            mode,
            fixed,
        )?;
        Ok((inputs.graph, data))
    }
}
