//! The digital twin of the polishing robot: the hidden-truth machine and (in later
//! slices) its non-geometric error sources, sensors, tracker and trajectories.
//! Imports `robot` only: the ground truth never peeks at the estimator.

mod truth;

pub use truth::{draw_errors, ErrorScales};
