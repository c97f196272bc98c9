//! The identification Jacobian: how the tracker's measurement of the pad pose moves with
//! each geometric error parameter, at fixed joint inputs.
//!
//! Rows are the pose error twist in the tracker frame: position (mm) then attitude (rad,
//! `log(R' Rᵀ)`); columns follow [`ErrorParams::names`]. [`numeric`] differentiates the
//! full error kinematics (every parameter, including the parallel module's, where the
//! forward kinematics is a Newton solve); [`analytic_serial`] writes the serial module's,
//! the tool's and the tracker's columns in closed form (eq. 9), and the tests hold one
//! against the other.

use nalgebra::{DMatrix, Isometry3, Matrix3, Vector3};

use crate::robot::{mdh, ErrorParams, Joints, PlatformPose, Robot, RobotError, N_PARAMS};

/// The pad pose in the tracker frame for joint inputs `joints` (forward kinematics from
/// `guess`), as the tracker would measure it with no noise.
pub fn measured_pose(
    robot: &Robot,
    joints: &Joints,
    guess: PlatformPose,
) -> Result<Isometry3<f64>, RobotError> {
    let (_, pose) = robot.forward(joints, Some(guess))?;
    Ok(robot.tracker_from_base() * pose)
}

/// Twist taking `a` to `b` in the frame they are expressed in: `[p_b − p_a; log(R_b R_aᵀ)]`.
pub fn twist(a: &Isometry3<f64>, b: &Isometry3<f64>) -> [f64; 6] {
    let dp = b.translation.vector - a.translation.vector;
    let dr = (b.rotation * a.rotation.inverse()).scaled_axis();
    [dp.x, dp.y, dp.z, dr.x, dr.y, dr.z]
}

/// Step of the central difference for each parameter: 1e-6 of a millimetre or radian.
const STEP: f64 = 1e-6;

/// 6 × N_PARAMS Jacobian by central differences of the full error kinematics.
pub fn numeric(
    robot: &Robot,
    joints: &Joints,
    guess: PlatformPose,
) -> Result<DMatrix<f64>, RobotError> {
    let all: Vec<usize> = (0..N_PARAMS).collect();
    numeric_columns(robot, joints, guess, &all)
}

/// The columns `cols` of [`numeric`] (6 × `cols.len()`), for filters that estimate only
/// some parameters.
pub fn numeric_columns(
    robot: &Robot,
    joints: &Joints,
    guess: PlatformPose,
    cols: &[usize],
) -> Result<DMatrix<f64>, RobotError> {
    let mut j = DMatrix::zeros(6, cols.len());
    for (c, &k) in cols.iter().enumerate() {
        let at = |h: f64| -> Result<Isometry3<f64>, RobotError> {
            let mut e: ErrorParams = robot.errors.clone();
            e.values[k] += h;
            measured_pose(&robot.with_errors(e), joints, guess)
        };
        let d = twist(&at(-STEP)?, &at(STEP)?);
        for (r, v) in d.iter().enumerate() {
            j[(r, c)] = v / (2.0 * STEP);
        }
    }
    Ok(j)
}

fn rotation_column(
    j: &mut DMatrix<f64>,
    k: usize,
    axis: Vector3<f64>,
    origin: Vector3<f64>,
    pad: Vector3<f64>,
) {
    let v = axis.cross(&(pad - origin));
    j.fixed_view_mut::<3, 1>(0, k).copy_from(&v);
    j.fixed_view_mut::<3, 1>(3, k).copy_from(&axis);
}

fn translation_column(j: &mut DMatrix<f64>, k: usize, direction: Vector3<f64>) {
    j.fixed_view_mut::<3, 1>(0, k).copy_from(&direction);
}

/// The serial module's (MDH rows, eq. 9), the tool's and the tracker registration's
/// columns in closed form; the parallel module's columns are left at zero. `platform` is
/// the platform pose the joints produce (from forward kinematics).
pub fn analytic_serial(robot: &Robot, joints: &Joints, platform: &PlatformPose) -> DMatrix<f64> {
    let mut j = DMatrix::zeros(6, N_PARAMS);
    let tracker = robot.tracker_from_base();
    let mut frame = tracker * robot.platform_frame(platform);
    let pad = (tracker * robot.tool_pose(platform, &joints.head))
        .translation
        .vector;
    let first = ErrorParams::serial_indices().start;
    let g = &robot.geometry;
    for (jt, joint) in g.serial.joints.iter().enumerate() {
        let e = robot.errors.mdh(jt);
        let col = first + 4 * jt;
        let alpha = joint.alpha_deg.to_radians() + e.alpha;
        // Rx(α) about the x axis of the frame before this row.
        let x = frame.rotation * Vector3::x();
        rotation_column(&mut j, col, x, frame.translation.vector, pad);
        translation_column(&mut j, col + 1, x);
        // Rz(θ), Tz(d) act in the frame after Rx(α) Tx(a).
        let mid = frame * mdh(alpha, joint.a + e.a, 0.0, 0.0);
        let z = mid.rotation * Vector3::z();
        rotation_column(&mut j, col + 2, z, mid.translation.vector, pad);
        translation_column(&mut j, col + 3, z);
        frame *= mdh(
            alpha,
            joint.a + e.a,
            joints.head[jt] + joint.theta_offset_deg.to_radians() + e.theta,
            joint.d + e.d,
        );
    }
    // The tool offset error is a translation in the tool frame.
    let tool = tracker * robot.tool_pose(platform, &joints.head);
    let t0 = ErrorParams::serial_indices().end - 3;
    for c in 0..3 {
        translation_column(&mut j, t0 + c, tool.rotation * Vector3::ith(c, 1.0));
    }
    // Registration Trans(dp)·exp(θ)·nominal: dp moves everything, θ turns about the
    // tracker origin (exactly, through the left Jacobian of SO(3) at the current θ).
    let (_, theta) = robot.errors.tracker();
    let tr = ErrorParams::tracker_indices().start;
    let left = so3_left_jacobian(&theta);
    let (dp, _) = robot.errors.tracker();
    for c in 0..3 {
        translation_column(&mut j, tr + c, Vector3::ith(c, 1.0));
        let axis = left.column(c).into_owned();
        rotation_column(&mut j, tr + 3 + c, axis, dp, pad);
    }
    j
}

/// Left Jacobian of SO(3): `exp(θ + δ) ≈ exp(J_l(θ) δ) exp(θ)`.
fn so3_left_jacobian(theta: &Vector3<f64>) -> Matrix3<f64> {
    let a = theta.norm();
    let k = theta.cross_matrix();
    if a < 1e-8 {
        return Matrix3::identity() + 0.5 * k;
    }
    Matrix3::identity() + (1.0 - a.cos()) / (a * a) * k + (a - a.sin()) / (a * a * a) * k * k
}
