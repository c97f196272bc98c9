//! Residual pose errors after calibration (eq. 19): δT_ng = T_M · T_cg⁻¹, as the 6-D label
//! of docs/model.md.

use nalgebra::Isometry3;

use crate::robot::{Joints, PlatformPose, Robot, RobotError};

/// Residual of one measurement under the calibrated `model`: position `p_M − p_cg` (µm)
/// and attitude `log(R_M R_cgᵀ)` as a rotation vector (mdeg), both in the base frame.
/// `measured` is the tracker's pose (tracker frame), mapped to the base frame with the
/// model's registration; `joints` are the actual inputs (encoders). Returns the platform
/// pose too, to warm-start the next call.
pub fn residual(
    model: &Robot,
    joints: &Joints,
    measured: &Isometry3<f64>,
    guess: Option<PlatformPose>,
) -> Result<([f64; 6], PlatformPose), RobotError> {
    let (platform, cg) = model.forward(joints, guess)?;
    let m = model.tracker_from_base().inverse() * measured;
    let dp = (m.translation.vector - cg.translation.vector) * 1e3;
    let dr = (m.rotation * cg.rotation.inverse())
        .scaled_axis()
        .map(|v| v.to_degrees() * 1e3);
    Ok(([dp.x, dp.y, dp.z, dr.x, dr.y, dr.z], platform))
}
