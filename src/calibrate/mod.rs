//! Geometric calibration on the CPU: the identification Jacobian (and, in later slices,
//! identifiability, the graded EKF and residual extraction). Imports `robot` only.

pub mod jacobian;
