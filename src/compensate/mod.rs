//! Online compensation: the predictor a controller embeds, fed with raw sensor values
//! ([`SensorPredictor`]); in the twin, the controller loop that runs it and corrects the
//! commanded pose (`online`), held-out runs and sessions (`held_out`), and the error
//! budget of a run by source (`budget`). The experiments that train models and score them this way live in [`crate::experiment`].

pub mod budget;
pub mod ensemble;
pub mod held_out;
pub mod online;
pub mod sensor_predictor;

pub use ensemble::{Ensemble, EnsembleFile, Interval, IntervalCalibration, Radius};
pub use sensor_predictor::SensorPredictor;
