//! Calibration of any serial arm (docs/arms.md "Calibration"): the tracker registration
//! fitted first in closed form (Kabsch), then an identifiability analysis that keeps the
//! parameters the poses can tell apart and says why each other one stays nominal, then
//! Levenberg–Marquardt on the kept ones with the registration estimated jointly. With a
//! `[gravity]` section the joint compliances are parameters like the geometry's and are
//! fitted jointly with it (elastostatic calibration, docs/arms.md "Joint compliance").

use nalgebra::{DMatrix, DVector, Matrix3, Point3, Vector3};

use super::identify::identifiable;
use crate::robot::arm::{Arm, ArmPose, CalibrationRecord, JointKind, ParamKind};

/// How the arm calibration scales, selects and stops.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmCalibrationConfig {
    /// Scale of a length parameter in the identifiability analysis, mm.
    pub length_scale_mm: f64,
    /// Scale of an angle parameter, rad (1 mrad moves a point 1 mm at 1 m).
    pub angle_scale_rad: f64,
    /// Scale of a joint compliance, rad per N·m: a typical joint's (10 µrad/(N·m), a
    /// stiffness of 10⁵ N·m/rad), so that a joint whose gravity torque is too small to
    /// show a typical compliance (a wrist near the tool) is reported as having no
    /// effect instead of being fitted to an implausible value.
    pub compliance_scale_rad_per_nm: f64,
    /// A parameter is identifiable when its scaled column keeps at least this fraction
    /// of the largest column's norm after removing the already selected ones.
    pub rank_tolerance: f64,
    /// The tracker's position noise, mm (weights position residuals).
    pub position_sd_mm: f64,
    /// The orientation noise, rad (weights orientation residuals where measured).
    pub attitude_sd_rad: f64,
    /// Most Levenberg–Marquardt iterations.
    pub max_iterations: usize,
}

impl Default for ArmCalibrationConfig {
    fn default() -> ArmCalibrationConfig {
        ArmCalibrationConfig {
            length_scale_mm: 1.0,
            angle_scale_rad: 1e-3,
            compliance_scale_rad_per_nm: 1e-5,
            rank_tolerance: 1e-3,
            position_sd_mm: 0.015,
            attitude_sd_rad: 1e-4,
            max_iterations: 200,
        }
    }
}

/// Why an arm calibration could not run.
#[derive(Debug, thiserror::Error)]
pub enum ArmCalibrationError {
    /// A pose with another number of joint values than the arm has joints.
    #[error("pose {index}: {got} joint values for an arm of {want} joints")]
    WrongJoints {
        /// The pose's index, from 0.
        index: usize,
        /// Joint values it has.
        got: usize,
        /// Joints the arm has.
        want: usize,
    },
    /// A pose holds a NaN or infinite number.
    #[error("pose {index}: {what} is not finite")]
    NonFinite {
        /// The pose's index, from 0.
        index: usize,
        /// `a joint value` or `the measured position`.
        what: &'static str,
    },
    /// Too few distinct poses for the parameters the poses could identify.
    #[error("{poses} poses ({distinct} distinct) are too few for the {rank} parameters they identify: each distinct pose gives {per_pose} equations; need at least {min} distinct poses")]
    TooFew {
        /// Poses given.
        poses: usize,
        /// Poses at different joint values.
        distinct: usize,
        /// Parameters identifiable from them.
        rank: usize,
        /// Equations per pose (3 with positions only, 6 with orientation).
        per_pose: usize,
        /// The fewest distinct poses asked for.
        min: usize,
    },
    /// The description allows no parameter to be identified.
    #[error("the description's `identify` list leaves no parameter to identify")]
    NothingToIdentify,
}

impl crate::error::StageError for ArmCalibrationError {}

/// A parameter left at its nominal (or registered) value, and why.
#[derive(Clone, Debug, PartialEq)]
pub struct KeptNominal {
    /// Its name.
    pub name: String,
    /// Why: not in `identify`, no effect on the measurements, or redundant with named ones.
    pub reason: String,
}

/// The result of an arm calibration.
#[derive(Clone, Debug)]
pub struct ArmCalibration {
    /// The nominal arm with its registration fitted (Kabsch): the `initial` model.
    pub registered: Arm,
    /// The calibrated arm.
    pub arm: Arm,
    /// Indices (in [`Arm::values`]) of the identified parameters.
    pub identified: Vec<usize>,
    /// Standard deviation of each identified parameter (mm or rad), from the residual.
    pub sd: Vec<f64>,
    /// The other parameters and why they were left alone.
    pub kept: Vec<KeptNominal>,
    /// Condition number of the scaled Jacobian of the identified parameters.
    pub condition: f64,
    /// RMS position residual on the fitted poses, registered nominal → calibrated, mm.
    pub rms_before_mm: f64,
    /// RMS position residual after calibration, mm.
    pub rms_after_mm: f64,
    /// Levenberg–Marquardt iterations run.
    pub iterations: usize,
    /// Poses fitted.
    pub poses: usize,
}

impl ArmCalibration {
    /// What a calibrated description file records of this calibration.
    pub fn record(&self) -> CalibrationRecord {
        let names = self.arm.names();
        CalibrationRecord {
            poses: self.poses,
            identified: self.identified.iter().map(|&i| names[i].clone()).collect(),
            kept_nominal: self
                .kept
                .iter()
                .map(|k| format!("{}: {}", k.name, k.reason))
                .collect(),
            rms_before_mm: self.rms_before_mm,
            rms_after_mm: self.rms_after_mm,
        }
    }
}

/// Orientation errors (degrees) of `arm`'s prediction at each pose with a measured
/// orientation: the angle of the rotation between predicted and measured.
pub fn arm_orientation_errors(arm: &Arm, poses: &[ArmPose]) -> Vec<f64> {
    poses
        .iter()
        .filter_map(|p| {
            p.orientation
                .map(|q| arm.measured_pose(p).rotation.angle_to(&q).to_degrees())
        })
        .collect()
}

/// Position errors (mm) of `arm`'s prediction at each pose.
pub fn arm_position_errors(arm: &Arm, poses: &[ArmPose]) -> Vec<f64> {
    poses
        .iter()
        .map(|p| (arm.measured_position(p) - p.position).norm())
        .collect()
}

fn check_poses(arm: &Arm, poses: &[ArmPose]) -> Result<(), ArmCalibrationError> {
    for (index, p) in poses.iter().enumerate() {
        if p.joints.len() != arm.joints() {
            return Err(ArmCalibrationError::WrongJoints {
                index,
                got: p.joints.len(),
                want: arm.joints(),
            });
        }
        if !p.joints.iter().all(|q| q.is_finite()) {
            return Err(ArmCalibrationError::NonFinite {
                index,
                what: "a joint value",
            });
        }
        if !p.position.coords.iter().all(|v| v.is_finite()) {
            return Err(ArmCalibrationError::NonFinite {
                index,
                what: "the measured position",
            });
        }
    }
    Ok(())
}

/// `arm` with the base transform that best maps its tool points onto the measured
/// ones (Kabsch: least squares over rotation and translation), and, where every pose
/// has a measured orientation and the tool's rotation may be identified, the tool's
/// rotation that best maps the predicted orientations onto the measured ones (the
/// chordal mean of the offsets): a probe mounted at any angle, even half a turn from the
/// description's, starts the fit within reach.
pub fn register(arm: &Arm, poses: &[ArmPose]) -> Arm {
    let based = register_base(arm, poses);
    let names = arm.names();
    let o = 5 * arm.joints() + 6;
    let tool_free = (o + 3..o + 6).all(|i| arm.may_identify(&names[i]));
    if !tool_free || poses.is_empty() || poses.iter().any(|p| p.orientation.is_none()) {
        return based;
    }
    // The offset of each measured orientation from the predicted one, in the tool's
    // frame; their chordal mean (the rotation nearest their sum) turns the tool.
    let mut sum = Matrix3::zeros();
    for p in poses {
        if let Some(q) = p.orientation {
            let offset = based.measured_pose(p).rotation.inverse() * q;
            sum += offset.to_rotation_matrix().into_inner();
        }
    }
    let svd = sum.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return based;
    };
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let mean = nalgebra::UnitQuaternion::from_matrix(&(u * d * v_t));
    let turned = based.tool().rotation * mean;
    let (roll, pitch, yaw) = turned.euler_angles();
    let mut values = based.values.clone();
    values[o + 3..o + 6].copy_from_slice(&[roll, pitch, yaw]);
    based.with_values(values)
}

/// The base transform of [`register`].
fn register_base(arm: &Arm, poses: &[ArmPose]) -> Arm {
    let o = 5 * arm.joints();
    let mut local = arm.values.clone();
    local[o..o + 6].copy_from_slice(&[0.0; 6]);
    let at_origin = arm.with_values(local.clone());
    let model: Vec<Point3<f64>> = poses
        .iter()
        .map(|p| at_origin.measured_position(p))
        .collect();
    let measured: Vec<Point3<f64>> = poses.iter().map(|p| p.position).collect();
    let n = poses.len().max(1) as f64;
    let mc = model.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let sc = measured.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut h = Matrix3::zeros();
    for (m, s) in model.iter().zip(&measured) {
        h += (m.coords - mc) * (s.coords - sc).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return arm.clone();
    };
    let mut d = Matrix3::identity();
    if (v_t.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v_t.transpose() * d * u.transpose();
    let rotation = nalgebra::UnitQuaternion::from_matrix(&r);
    let t = sc - rotation * mc;
    let (roll, pitch, yaw) = rotation.euler_angles();
    local[o..o + 6].copy_from_slice(&[t.x, t.y, t.z, roll, pitch, yaw]);
    arm.with_values(local)
}

/// Weighted residuals (measured − predicted) of every pose under `values`: each
/// reading's own standard deviations where it has them (`ArmPose::reading_sd`), else
/// the configuration's.
fn residuals(
    arm: &Arm,
    values: &[f64],
    poses: &[ArmPose],
    c: &ArmCalibrationConfig,
) -> DVector<f64> {
    let per = rows_per_pose(poses);
    let mut r = DVector::zeros(per * poses.len());
    for (i, p) in poses.iter().enumerate() {
        let pose = arm.tool_pose_from(&p.joints, &p.approach, values);
        let sd = p
            .reading_sd
            .map_or([c.position_sd_mm; 3], |s| s.position_mm);
        let e = (p.position.coords - pose.translation.vector).component_div(&Vector3::from(sd));
        r.fixed_rows_mut::<3>(per * i).copy_from(&e);
        if let Some(q) = p.orientation {
            let sd = p
                .reading_sd
                .and_then(|s| s.orientation_rad())
                .unwrap_or(c.attitude_sd_rad);
            let w = (pose.rotation.inverse() * q).scaled_axis() / sd;
            r.fixed_rows_mut::<3>(per * i + 3).copy_from(&w);
        }
    }
    r
}

fn rows_per_pose(poses: &[ArmPose]) -> usize {
    if poses.iter().all(|p| p.orientation.is_some()) {
        6
    } else {
        3
    }
}

/// Central-difference Jacobian of the residuals in the scaled parameters `cols`.
fn jacobian(
    arm: &Arm,
    values: &[f64],
    poses: &[ArmPose],
    cols: &[usize],
    scale: &[f64],
    c: &ArmCalibrationConfig,
) -> DMatrix<f64> {
    let rows = rows_per_pose(poses) * poses.len();
    let mut j = DMatrix::zeros(rows, cols.len());
    let h = 1e-4;
    for (k, &i) in cols.iter().enumerate() {
        let mut plus = values.to_vec();
        let mut minus = values.to_vec();
        plus[i] += h * scale[i];
        minus[i] -= h * scale[i];
        let d = (residuals(arm, &plus, poses, c) - residuals(arm, &minus, poses, c)) / (2.0 * h);
        j.set_column(k, &d);
    }
    j
}

fn distinct_poses(poses: &[ArmPose]) -> usize {
    let mut keys: Vec<Vec<u64>> = poses
        .iter()
        .map(|p| p.joints.iter().map(|q| q.to_bits()).collect())
        .collect();
    keys.sort_unstable();
    keys.dedup();
    keys.len()
}

/// What a new campaign fits again: where the tracker stands (`base.*`) and where the
/// tool sits on the flange (`tool.*`).
pub const PLACEMENT: [&str; 2] = ["base.*", "tool.*"];

/// Re-registers `calibrated` for a new campaign from a few of its `poses`: only the
/// tracker's and the tool's placement ([`PLACEMENT`]) are fitted, by the same
/// registration, identifiability analysis and Levenberg–Marquardt as
/// [`calibrate_arm`]; the kinematics, compliances and lost motions stay as calibrated.
/// The result's arm keeps `calibrated`'s own `identify` list (for a later full
/// calibration); its `kept` lists the placement parameters left alone, and why.
pub fn reregister(
    calibrated: &Arm,
    poses: &[ArmPose],
    c: &ArmCalibrationConfig,
) -> Result<ArmCalibration, ArmCalibrationError> {
    let mut spec = calibrated.spec.clone();
    spec.identify = Some(PLACEMENT.map(String::from).to_vec());
    let placement = Arm {
        spec,
        values: calibrated.values.clone(),
    };
    let mut fit = calibrate_arm(&placement, poses, c)?;
    for arm in [&mut fit.arm, &mut fit.registered] {
        arm.spec.identify.clone_from(&calibrated.spec.identify);
    }
    fit.kept.retain(|k| {
        PLACEMENT
            .iter()
            .any(|p| p.strip_suffix('*').is_some_and(|p| k.name.starts_with(p)))
    });
    Ok(fit)
}

/// Calibrates `nominal` from `poses`: registration, identifiability, Levenberg–Marquardt.
pub fn calibrate_arm(
    nominal: &Arm,
    poses: &[ArmPose],
    c: &ArmCalibrationConfig,
) -> Result<ArmCalibration, ArmCalibrationError> {
    check_poses(nominal, poses)?;
    let names = nominal.names();
    let o = 5 * nominal.joints();
    let base_free = (o..o + 6).all(|i| nominal.may_identify(&names[i]));
    let registered = if base_free {
        register(nominal, poses)
    } else {
        nominal.clone()
    };
    let scale: Vec<f64> = (0..names.len())
        .map(|i| match nominal.param_kind(i) {
            ParamKind::Length => c.length_scale_mm,
            ParamKind::Angle => c.angle_scale_rad,
            ParamKind::Compliance => c.compliance_scale_rad_per_nm,
        })
        .collect();
    let rigid_joint = |i: usize| {
        nominal.param_kind(i) == ParamKind::Compliance
            && nominal.spec.joint[i - o - 12].kind == JointKind::Prismatic
    };
    let allowed: Vec<usize> = (0..names.len())
        .filter(|&i| nominal.may_identify(&names[i]) && !rigid_joint(i))
        .collect();
    if allowed.is_empty() {
        return Err(ArmCalibrationError::NothingToIdentify);
    }
    let mut kept: Vec<KeptNominal> = (0..names.len())
        .filter(|i| !allowed.contains(i))
        .map(|i| KeptNominal {
            name: names[i].clone(),
            reason: if rigid_joint(i) {
                "a prismatic joint is taken as rigid".into()
            } else {
                "not in the description's identify list".into()
            },
        })
        .collect();
    // Identifiability at the registered nominal.
    let j = jacobian(&registered, &registered.values, poses, &allowed, &scale, c);
    let (chosen, condition) = identifiable(&j, c.rank_tolerance);
    let identified: Vec<usize> = chosen.iter().map(|&k| allowed[k]).collect();
    let largest = (0..j.ncols())
        .map(|k| j.column(k).norm())
        .fold(0.0, f64::max);
    let basis = DMatrix::from_fn(j.nrows(), chosen.len(), |r, k| j[(r, chosen[k])]);
    let basis_svd = basis.clone().svd(true, true);
    for (k, &i) in allowed.iter().enumerate() {
        if chosen.contains(&k) {
            continue;
        }
        let col = j.column(k).into_owned();
        let reason = if col.norm() < c.rank_tolerance * largest {
            "no effect on the measured poses".to_string()
        } else {
            // Which identified parameters explain its effect (least squares).
            let coef = basis_svd
                .solve(&col, 1e-12)
                .unwrap_or_else(|_| DVector::zeros(chosen.len()));
            let mut weight: Vec<(f64, usize)> = coef
                .iter()
                .enumerate()
                .map(|(m, w)| ((w * basis.column(m).norm()).abs(), chosen[m]))
                .collect();
            weight.sort_by(|a, b| b.0.total_cmp(&a.0));
            let with: Vec<String> = weight
                .iter()
                .take(2)
                .filter(|w| w.0 > 0.05 * col.norm())
                .map(|w| names[allowed[w.1]].clone())
                .collect();
            if with.is_empty() {
                "redundant with the identified parameters together".to_string()
            } else {
                format!("redundant with {}", with.join(" and "))
            }
        };
        kept.push(KeptNominal {
            name: names[i].clone(),
            reason,
        });
    }
    let per_pose = rows_per_pose(poses);
    let distinct = distinct_poses(poses);
    let min = identified.len().div_ceil(per_pose) + 2;
    if distinct < min {
        return Err(ArmCalibrationError::TooFew {
            poses: poses.len(),
            distinct,
            rank: identified.len(),
            per_pose,
            min,
        });
    }
    // Levenberg–Marquardt in the scaled parameters.
    let mut values = registered.values.clone();
    let mut r = residuals(&registered, &values, poses, c);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut jac = jacobian(&registered, &values, poses, &identified, &scale, c);
    while iterations < c.max_iterations {
        iterations += 1;
        let jtj = jac.transpose() * &jac;
        let g = jac.transpose() * &r;
        let mut step = None;
        for _ in 0..20 {
            let mut a = jtj.clone();
            for d in 0..a.nrows() {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
            }
            // r = measured − predicted, so J_pred = −jac and the step solves A δ = −Jᵀr.
            let Some(delta) = a.cholesky().map(|ch| ch.solve(&(-&g))) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = values.clone();
            for (k, &i) in identified.iter().enumerate() {
                trial[i] += delta[k] * scale[i];
            }
            let rt = residuals(&registered, &trial, poses, c);
            let ct = rt.norm_squared();
            if ct.is_finite() && ct < cost {
                step = Some((trial, rt, ct, delta.norm()));
                lambda = (lambda / 10.0).max(1e-12);
                break;
            }
            lambda *= 10.0;
        }
        let Some((trial, rt, ct, size)) = step else {
            break;
        };
        let gain = (cost - ct) / cost.max(f64::MIN_POSITIVE);
        values = trial;
        r = rt;
        cost = ct;
        if gain < 1e-12 || size < 1e-10 {
            break;
        }
        jac = jacobian(&registered, &values, poses, &identified, &scale, c);
    }
    let arm = registered.with_values(values);
    // Parameter SDs from the residual variance and (JᵀJ)⁻¹, back in mm / rad.
    let dof = (r.len() as f64 - identified.len() as f64).max(1.0);
    let variance = cost / dof;
    let jac = jacobian(&arm, &arm.values, poses, &identified, &scale, c);
    let sd = (jac.transpose() * &jac)
        .try_inverse()
        .map(|inv| {
            identified
                .iter()
                .enumerate()
                .map(|(k, &i)| (inv[(k, k)] * variance).max(0.0).sqrt() * scale[i])
                .collect()
        })
        .unwrap_or_else(|| vec![f64::INFINITY; identified.len()]);
    let rms = |a: &Arm| {
        let e = arm_position_errors(a, poses);
        (e.iter().map(|x| x * x).sum::<f64>() / e.len().max(1) as f64).sqrt()
    };
    Ok(ArmCalibration {
        rms_before_mm: rms(&registered),
        rms_after_mm: rms(&arm),
        registered,
        arm,
        identified,
        sd,
        kept,
        condition,
        iterations,
        poses: poses.len(),
    })
}
