//! Geometric calibration on the CPU: the identification Jacobian, identifiability, the
//! graded iterated EKF, the calibration file and residual extraction. Imports `robot`
//! only.

pub mod arm;
pub mod file;
pub mod identify;
pub mod jacobian;
pub mod residual;
pub mod scoring;

pub use identify::{
    calibrate, default_prior_sigma, Calibration, CalibrationError, EkfConfig, Measurement,
    StageReport,
};
pub use residual::residual;
pub use scoring::{
    hold_out, hold_out_block, hold_out_random, pose_errors, random_positions, split_where,
};
