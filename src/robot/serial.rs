//! Modified Denavit–Hartenberg links (eq. 7), shared by the hybrid's 2R head and CCOS
//! tool and by every serial arm's chain (`arm`), with Hayati's β for nearly parallel
//! axes: one link is `Rx(α) Ry(β) Tx(a) Rz(θ) Tz(d)`, [`mdh_link`] then [`mdh_motion`].

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// `Rx(α) Ry(β) Tx(a)`: from the previous joint's frame to this joint's axis.
pub fn mdh_link(alpha: f64, a: f64, beta: f64) -> Isometry3<f64> {
    let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), alpha);
    if beta == 0.0 {
        // A rotation about x leaves a translation along x as it is: Rx(α)·Tx(a) is one
        // isometry (and the plain MDH row of eq. 7 takes no β product).
        return Isometry3::from_parts(Translation3::new(a, 0.0, 0.0), rx);
    }
    let rot = rx * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), beta);
    Isometry3::from_parts(Translation3::from(rot * Vector3::new(a, 0.0, 0.0)), rot)
}

/// `Rz(θ) Tz(d)`: the motion about and along the joint's axis (likewise one isometry).
pub fn mdh_motion(theta: f64, d: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, d),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta),
    )
}

/// `Rx(α) Tx(a) Rz(θ) Tz(d)` of eq. 7 (β = 0).
pub fn mdh(alpha: f64, a: f64, theta: f64, d: f64) -> Isometry3<f64> {
    mdh_link(alpha, a, 0.0) * mdh_motion(theta, d)
}
