//! The digital twin of the polishing robot: the hidden-truth machine, the mirror and the
//! polishing paths, and (in later slices) its non-geometric error sources, sensors and
//! tracker. Imports `robot` only: the ground truth never peeks at the estimator.

mod mirror;
mod trajectory;
mod truth;

pub use mirror::Mirror;
pub use trajectory::{calibration_configurations, Path, PathKind, PathParams};
pub use truth::{draw_errors, ErrorScales};
