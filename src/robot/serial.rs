//! The serial 2R head in modified Denavit–Hartenberg form (eq. 7) and the CCOS tool.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// `Rx(α) Tx(a) Rz(θ) Tz(d)` of eq. 7.
pub fn mdh(alpha: f64, a: f64, theta: f64, d: f64) -> Isometry3<f64> {
    let rx = Isometry3::from_parts(
        Translation3::new(a, 0.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), alpha),
    );
    let rz = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, d),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta),
    );
    // A rotation about x leaves a translation along x unchanged (and likewise for z), so
    // Rx(α)·Tx(a) and Rz(θ)·Tz(d) are each one isometry.
    rx * rz
}
