//! The digital twin of the polishing robot: the hidden-truth machine (geometric errors
//! and non-geometric sources), the mirror and polishing paths, the sensors and the laser
//! tracker, and the simulation that runs them. Imports `robot` only: the ground truth
//! never peeks at the estimator.

mod mirror;
pub mod sensors;
pub mod session;
mod simulate;
pub mod sources;
mod trajectory;
mod truth;

pub use mirror::Mirror;
pub use sensors::{
    Installation, Instruments, Scene, SensorRates, SensorSpecs, CHANNELS, CHANNEL_UNITS,
};
pub use session::RunInfo;
pub use simulate::{
    measure_calibration, pose_error, Actual, CalibrationMeasurement, Correction, Hidden, Machine,
    MachineState, Sample, SimConfig, Simulation, SourceTerms,
};
pub use trajectory::{calibration_configurations, Path, PathKind, PathParams};
pub use truth::{draw_errors, draw_machine, draw_nongeometric, gaussian, ErrorScales};
