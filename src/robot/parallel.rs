//! The 3-UPS/UP parallel module: platform frame, limb model with the Table I errors,
//! closed-form inverse kinematics and Newton forward kinematics.
//!
//! Platform coordinates are the passive UP limb's joints: tilt `alpha` about the base x
//! axis, then `beta` about the rotated y axis (its universal joint), and the extension `w`
//! of its slide. The platform centre is at `w · R e` with `R = Rx(alpha) Ry(beta)`.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, Vector3};

use super::errors::LimbErrors;

/// Pose of the moving platform in the UP limb's joint coordinates (rad, rad, mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlatformPose {
    /// Tilt of the UP joint about the base x axis, rad.
    pub alpha: f64,
    /// Tilt of the UP joint about the rotated y axis, rad.
    pub beta: f64,
    /// Extension of the UP limb's slide (base joint to platform centre), mm.
    pub w: f64,
}

impl PlatformPose {
    /// The pose as `[alpha, beta, w]`.
    pub fn to_vector(self) -> Vector3<f64> {
        Vector3::new(self.alpha, self.beta, self.w)
    }

    /// The pose from `[alpha, beta, w]`.
    pub fn from_vector(v: &Vector3<f64>) -> PlatformPose {
        PlatformPose {
            alpha: v.x,
            beta: v.y,
            w: v.z,
        }
    }
}

pub(crate) fn e() -> Vector3<f64> {
    Vector3::z()
}

/// `exp(θ̂)`: the rotation of a small attitude-error vector.
pub(crate) fn rot(theta: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::new(*theta)
}

/// Orientation of the platform, `Rx(alpha) Ry(beta)`.
pub fn tilt(alpha: f64, beta: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), alpha)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), beta)
}

/// Nominal platform frame (before platform errors): `R = Rx Ry`, centre `w R e`.
pub fn platform_frame(p: &PlatformPose) -> Isometry3<f64> {
    let r = tilt(p.alpha, p.beta);
    Isometry3::from_parts(Translation3::from(p.w * (r * e())), r.into())
}

/// [`HookeJoint::angles`] of `v` for the joint error `between`.
#[cfg(test)]
fn hooke_angles(v: &Vector3<f64>, between: &Rotation3<f64>) -> (f64, f64) {
    HookeJoint::new(between).angles(v)
}

/// A Hooke joint's attitude error `err` and what its angles need of it alone (`r`,
/// `ψ`): made once per limb of a robot ([`LimbConstants`]), not at each length.
#[derive(Clone, Copy, Debug)]
struct HookeJoint {
    m: Matrix3<f64>,
    r: f64,
    psi: f64,
}

impl HookeJoint {
    fn new(between: &Rotation3<f64>) -> HookeJoint {
        let m = *between.matrix();
        let (c0, c2) = (m[(0, 0)], m[(0, 2)]);
        HookeJoint {
            m,
            r: c0.hypot(c2),
            psi: c2.atan2(c0),
        }
    }

    /// Angles of a two-axis Hooke joint `Rx(φ1) · err · Ry(φ2)` that point `e` along the unit
    /// vector `v`, where `err` is the attitude error between the axes. Exact and closed form:
    /// `Rx` keeps the x component, so `[err · Ry(φ2) e]_x = v_x` is `r · sin(φ2 + ψ) = v_x`
    /// with `(r cos ψ, r sin ψ) = (err₀₀, err₀₂)`; φ1 is then the signed angle from
    /// `err · Ry(φ2) e` to `v` about x. Of the two solutions it takes the one near zero (the
    /// joint's working range, |φ2 + ψ| < 90°), which for `err = I` is `φ2 = asin v_x`,
    /// `φ1 = atan2(−v_y, v_z)`. (It replaced Gauss–Newton steps with a finite-difference
    /// Jacobian that made the twin spend nine tenths of its time here; the test below checks
    /// the equation and agreement with those steps.)
    fn angles(&self, v: &Vector3<f64>) -> (f64, f64) {
        let m = &self.m;
        let phi2 = (v.x / self.r).clamp(-1.0, 1.0).asin() - self.psi;
        let (s, c) = phi2.sin_cos();
        // w = err · Ry(φ2) e = s · err[:, 0] + c · err[:, 2]; only its y and z matter now.
        let (wy, wz) = (s * m[(1, 0)] + c * m[(1, 2)], s * m[(2, 0)] + c * m[(2, 2)]);
        let phi1 = (wy * v.z - wz * v.y).atan2(wy * v.y + wz * v.z);
        (phi1, phi2)
    }
}

/// What [`Limb::ends`] needs of the limb's joint errors and of the platform frame's
/// rotation, which stay the same over the passes of one [`Limb::length`].
struct Fixed<'c> {
    joints: &'c LimbConstants,
    ra: Rotation3<f64>,
    ra_inv: Rotation3<f64>,
}

/// What a limb's length needs of its joint errors alone (their rotations and the Hooke
/// joints' constants): the same for every pose, so [`super::Robot`] makes them once per
/// limb ([`Limb::constants`]) and [`Limb::length_with`] reads them.
#[derive(Clone, Copy, Debug)]
pub struct LimbConstants {
    rb: Rotation3<f64>,
    rb_inv: Rotation3<f64>,
    base_joint: HookeJoint,
    rta: Rotation3<f64>,
    rta_inv: Rotation3<f64>,
    rm: Rotation3<f64>,
    platform_joint: HookeJoint,
}

/// One UPS limb with its errors: base joint centre `b`, platform joint centre `a0`
/// (platform frame), shaft length `delta`.
#[derive(Clone, Copy, Debug)]
pub struct Limb {
    /// Base joint centre b_i, mm, base frame.
    pub b: Vector3<f64>,
    /// Platform joint centre a_0i, mm, platform frame.
    pub a0: Vector3<f64>,
    /// Nominal length δ of the composite joint's connection shaft, mm.
    pub delta: f64,
    /// The limb's geometric errors.
    pub err: LimbErrors,
}

impl Limb {
    /// The limb axis end points (base side, platform side) for limb direction `u`.
    ///
    /// Base side (eq. 2, right): `b + Δb + exp(θ_B) Rx(φ1) Δn`, where the Hooke angles
    /// satisfy `exp(θ_B) Rx(φ1) exp(θ_N) Ry(φ2) e = u`. Platform side (eq. 2, left):
    /// `r_A + R_A (a0 + Δa) + R_A exp(θ_A) Rx(ψ1) [Δm + exp(θ_M) Ry(ψ2) (−(δ+Δδ) e + ΔS)]`
    /// with `exp(θ_A) Rx(ψ1) exp(θ_M) Ry(ψ2) e = R_Aᵀ u`. θ_N and θ_M only redistribute the
    /// free joint angles, so their effect on the pose is second order (and the calibration
    /// finds them unidentifiable).
    fn ends(
        &self,
        frame: &Isometry3<f64>,
        fixed: &Fixed,
        u: &Vector3<f64>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let er = &self.err;
        let f = fixed.joints;
        let (ra, ra_inv) = (&fixed.ra, &fixed.ra_inv);
        let (p1, _) = f.base_joint.angles(&(f.rb_inv * u));
        let bottom =
            self.b + er.db + f.rb * Rotation3::from_axis_angle(&Vector3::x_axis(), p1) * er.dn;
        let local = f.rta_inv * (ra_inv * u);
        let (q1, q2) = f.platform_joint.angles(&local);
        let shaft = f.rm
            * Rotation3::from_axis_angle(&Vector3::y_axis(), q2)
            * (-(self.delta + er.d_shaft) * e() + er.ds);
        let top = frame.translation.vector
            + ra * (self.a0 + er.da)
            + ra * f.rta * Rotation3::from_axis_angle(&Vector3::x_axis(), q1) * (er.dm + shaft);
        (bottom, top)
    }

    /// The rotations and Hooke constants of the limb's joint errors.
    pub fn constants(&self) -> LimbConstants {
        let er = &self.err;
        let rb = rot(&er.theta_b);
        let rta = rot(&er.theta_a);
        let rm = rot(&er.theta_m);
        LimbConstants {
            rb,
            rb_inv: rb.inverse(),
            base_joint: HookeJoint::new(&rot(&er.theta_n)),
            rta,
            rta_inv: rta.inverse(),
            rm,
            platform_joint: HookeJoint::new(&rm),
        }
    }

    /// The actuator reading `l` that realises the platform `frame`: the axis length minus
    /// the drive's zero error Δl (the true rod is `l + Δl`).
    pub fn length(&self, frame: &Isometry3<f64>) -> f64 {
        self.length_with(frame, &self.constants())
    }

    /// [`Limb::length`] with the limb's [`Limb::constants`] made beforehand: the same
    /// bits.
    pub fn length_with(&self, frame: &Isometry3<f64>, joints: &LimbConstants) -> f64 {
        let a_nominal = frame.translation.vector + frame.rotation * self.a0;
        let mut u = (a_nominal - self.b).normalize();
        // The ends move with u only through offsets of a fraction of a millimetre on a
        // limb of most of a metre: each pass shrinks the error by ~1e-3, five are exact.
        let mut axis = Vector3::zeros();
        let ra = frame.rotation.to_rotation_matrix();
        let fixed = Fixed {
            joints,
            ra,
            ra_inv: ra.inverse(),
        };
        for _ in 0..5 {
            let (bottom, top) = self.ends(frame, &fixed, &u);
            axis = top - bottom;
            u = axis.normalize();
        }
        axis.norm() - self.err.d_length
    }
}

/// Solves the 3×3 Newton step `J d = r`; `None` when `J` is singular.
pub(crate) fn newton_step(j: &Matrix3<f64>, r: &Vector3<f64>) -> Option<Vector3<f64>> {
    j.lu().solve(r)
}

#[cfg(test)]
mod tests {
    use super::{e, hooke_angles, rot};
    use nalgebra::{Matrix2, Matrix3x2, Rotation3, Vector3};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn joint(p1: f64, between: &Rotation3<f64>, p2: f64) -> Vector3<f64> {
        Rotation3::from_axis_angle(&Vector3::x_axis(), p1)
            * between
            * Rotation3::from_axis_angle(&Vector3::y_axis(), p2)
            * e()
    }

    /// The iteration the closed form replaced: the `err = I` solution, then three
    /// Gauss–Newton steps with a central-difference Jacobian.
    fn gauss_newton(v: &Vector3<f64>, between: &Rotation3<f64>) -> (f64, f64) {
        let mut phi2 = v.x.clamp(-1.0, 1.0).asin();
        let mut phi1 = (-v.y).atan2(v.z);
        for _ in 0..3 {
            let r = joint(phi1, between, phi2) - v;
            let h = 1e-7;
            let j = Matrix3x2::from_columns(&[
                (joint(phi1 + h, between, phi2) - joint(phi1 - h, between, phi2)) / (2.0 * h),
                (joint(phi1, between, phi2 + h) - joint(phi1, between, phi2 - h)) / (2.0 * h),
            ]);
            let jtj: Matrix2<f64> = j.transpose() * j;
            let d = jtj.try_inverse().unwrap() * (j.transpose() * r);
            phi1 -= d.x;
            phi2 -= d.y;
        }
        (phi1, phi2)
    }

    #[test]
    fn hooke_angles_solve_the_joint_exactly_and_match_the_iteration() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for case in 0..2000 {
            // Joint errors up to 3 mrad per axis (the twin's are below 1), directions
            // over ±60° of both joint angles.
            let theta = Vector3::from_fn(|_, _| rng.random_range(-3e-3..3e-3));
            let between = rot(&theta);
            let (a1, a2) = (rng.random_range(-1.05..1.05), rng.random_range(-1.05..1.05));
            let v = joint(a1, &between, a2);
            let (p1, p2) = hooke_angles(&v, &between);
            let miss = (joint(p1, &between, p2) - v).norm();
            assert!(miss < 1e-14, "case {case}: the joint misses v by {miss:e}");
            assert!(
                (p1 - a1).abs() < 1e-12 && (p2 - a2).abs() < 1e-12,
                "case {case}"
            );
            let (g1, g2) = gauss_newton(&v, &between);
            assert!(
                (p1 - g1).abs() < 1e-9 && (p2 - g2).abs() < 1e-9,
                "case {case}: closed form ({p1}, {p2}), iteration ({g1}, {g2})"
            );
        }
        // Exactly along a joint axis limit the closed form clamps instead of failing.
        let (p1, p2) = hooke_angles(&Vector3::x(), &Rotation3::identity());
        assert!(p1.is_finite() && (p2 - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }
}
