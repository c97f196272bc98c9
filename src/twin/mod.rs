//! The digital twin of the polishing robot: the hidden-truth machine (geometric errors
//! and non-geometric sources), the mirror and polishing paths, the sensors and the laser
//! tracker, and the simulation that runs them. Imports `robot` only: the ground truth
//! never peeks at the estimator.

pub mod arm;
mod machine;
mod mirror;
mod noise;
pub mod retrace;
pub mod sensors;
pub mod session;
mod simulate;
pub mod sources;
mod trajectory;
mod truth;

pub use machine::{located, Actual, Machine, MachineState, SourceTerms};
pub use mirror::Mirror;
pub use noise::gaussian;
pub use sensors::{
    Installation, Instruments, Scene, SensorRates, SensorSpecs, CHANNELS, CHANNEL_UNITS,
    PLAN_CHANNELS, SENSOR_CHANNELS,
};
pub use session::{Conditions, PathOrder, Placement, PlannedSession, Recipe, RunInfo};
pub use simulate::{
    measure_calibration, pose_error, CalibrationMeasurement, Correction, Hidden, Sample, SimConfig,
    Simulation, DEFAULT_FEED, DEFAULT_FORCE,
};
pub use sources::Day;
pub use trajectory::{calibration_configurations, FeedPlan, Path, PathKind, PathParams};
pub use truth::{draw_errors, draw_machine, draw_nongeometric, ErrorScales};
