//! Graded EKF identification of the geometric errors (eq. 10–18, 38).
//!
//! Each stage (serial module with tool and tracker registration first, then the parallel
//! module) estimates its identifiable parameters with the EKF of eq. 12–16, run as an
//! iterated filter: every sweep restarts from the prior and processes all measurements,
//! linearised at the previous sweep's estimate, so the result does not depend on the
//! order of the measurements. Sweeps stop when Γ = ‖X̂_s − X̂_{s−1}‖ ≤ Γ_max (eq. 17).
//! Unidentifiable parameters stay at their prior (zero error).

use nalgebra::{DMatrix, DVector, Isometry3};

use super::jacobian::{numeric_columns, twist};
use crate::robot::{ErrorParams, Joints, PlatformPose, Robot, RobotError};

/// One calibration measurement: joint inputs and the tracker's pad pose (tracker frame).
#[derive(Clone, Copy, Debug)]
pub struct Measurement {
    /// The commanded joint inputs (limb lengths mm, head angles rad).
    pub joints: Joints,
    /// The tracker's pad pose, tracker frame.
    pub pose: Isometry3<f64>,
}

/// Settings of the identification.
#[derive(Clone, Debug)]
pub struct EkfConfig {
    /// Prior standard deviation of each parameter (mm or rad), in [`ErrorParams`] order.
    pub prior_sigma: Vec<f64>,
    /// Measurement noise of the position, one standard deviation per axis, mm.
    pub noise_position: f64,
    /// Measurement noise of the attitude, one standard deviation per axis, rad.
    pub noise_attitude: f64,
    /// Process noise variance per step (eq. 13); 0 for constant parameters.
    pub process_noise: f64,
    /// Termination threshold Γ of eq. 17, in mm / rad.
    pub gamma: f64,
    /// Sweeps at most of the final joint stage.
    pub max_sweeps: usize,
    /// Graded rounds (serial then parallel) at most.
    pub max_rounds: usize,
    /// Sweeps at most per graded stage: the graded pass only has to bring the joint stage
    /// close.
    pub graded_sweeps: usize,
    /// A parameter is identifiable when its scaled column keeps at least this fraction of
    /// the largest column's norm after removing the already selected ones.
    pub rank_tolerance: f64,
}

impl Default for EkfConfig {
    fn default() -> EkfConfig {
        EkfConfig {
            prior_sigma: default_prior_sigma(),
            // The laser tracker (7 µm, 1.5 mdeg per axis) averaged over 10 readings.
            noise_position: 7e-3 / 10f64.sqrt(),
            noise_attitude: 1.5e-3f64.to_radians() / 10f64.sqrt(),
            process_noise: 0.0,
            gamma: 1e-4,
            max_sweeps: 20,
            max_rounds: 2,
            graded_sweeps: 5,
            rank_tolerance: 1e-3,
        }
    }
}

/// Generous priors: what a manufacturer would promise, wider than any one machine.
pub fn default_prior_sigma() -> Vec<f64> {
    ErrorParams::names()
        .iter()
        .map(|n| {
            if n.starts_with("tracker.dp") {
                1.0
            } else if n.starts_with("tracker.theta") {
                2e-3
            } else if n.starts_with("serial") && (n.ends_with(".alpha") || n.ends_with(".theta")) {
                5e-3
            } else if n.contains("theta") {
                2e-3
            } else {
                0.3
            }
        })
        .collect()
}

/// What the identification found.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Estimated errors (zero where not identifiable): X_real = X_nom + δX (eq. 18).
    pub errors: ErrorParams,
    /// Indices of the identified parameters.
    pub identified: Vec<usize>,
    /// Posterior covariance over `identified` (mm², rad²).
    pub covariance: DMatrix<f64>,
    /// Condition number of the scaled identification Jacobian: serial stage, parallel
    /// stage, joint stage.
    pub condition: Vec<f64>,
    /// Per stage and round: sweeps used and the final Γ.
    pub stages: Vec<StageReport>,
}

/// How one EKF stage ended.
#[derive(Clone, Debug)]
pub struct StageReport {
    /// `serial`, `parallel` or `joint`.
    pub name: &'static str,
    /// The graded round, from 1 (the joint stage runs once, as round 1).
    pub round: usize,
    /// How many parameters the stage identified.
    pub parameters: usize,
    /// Sweeps used.
    pub sweeps: usize,
    /// The final Γ of eq. 17, mm / rad.
    pub gamma: f64,
}

/// Why the identification failed.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// Forward kinematics failed at a measurement's joint inputs.
    #[error(transparent)]
    Kinematics(#[from] RobotError),
    /// The measurement set cannot identify what a richer set could.
    #[error("{measurements} measurements (distinct poses: {distinct}) are too few: the {stage} stage identifies only {rank} of {needed} parameters it could with a richer set (need at least {min} distinct poses; a pose measured again adds no equation)")]
    TooFew {
        /// `serial`, `parallel` or `joint`.
        stage: &'static str,
        /// How many measurements were given.
        measurements: usize,
        /// How many of them were taken at different joint inputs.
        distinct: usize,
        /// How many of the stage's parameters the set identifies.
        rank: usize,
        /// How many parameters the stage has.
        needed: usize,
        /// The fewest poses the identified parameters need.
        min: usize,
    },
    /// A measurement holds a NaN or infinite value.
    #[error("measurement {index}: {what} is not finite")]
    NonFinite {
        /// The measurement's index, from 0.
        index: usize,
        /// `a joint input` or `the measured pose`.
        what: &'static str,
    },
    /// The filter's estimate blew up or its innovation covariance became singular.
    #[error("the EKF diverged in the {stage} stage at sweep {sweep}: {why}")]
    Diverged {
        /// `serial`, `parallel` or `joint`.
        stage: &'static str,
        /// The sweep it diverged in, from 1.
        sweep: usize,
        /// What went wrong.
        why: String,
    },
}

impl crate::error::StageError for CalibrationError {}

/// Predicted measurement and platform pose for each measurement under `robot`.
fn predict(
    robot: &Robot,
    ms: &[Measurement],
    guesses: &mut [PlatformPose],
) -> Result<Vec<Isometry3<f64>>, RobotError> {
    ms.iter()
        .zip(guesses.iter_mut())
        .map(|(m, g)| {
            let (p, pose) = robot.forward(&m.joints, Some(*g))?;
            *g = p;
            Ok(robot.tracker_from_base() * pose)
        })
        .collect()
}

/// Greedy column selection (pivoted Gram–Schmidt) on the prior-scaled Jacobian: the
/// parameters whose effects are independent of those already chosen.
pub(crate) fn identifiable(j: &DMatrix<f64>, tolerance: f64) -> (Vec<usize>, f64) {
    let mut basis: Vec<DVector<f64>> = Vec::new();
    let mut chosen = Vec::new();
    let max_norm = (0..j.ncols())
        .map(|c| j.column(c).norm())
        .fold(0.0, f64::max);
    if max_norm == 0.0 {
        return (chosen, f64::INFINITY);
    }
    let mut residual: Vec<DVector<f64>> =
        (0..j.ncols()).map(|c| j.column(c).into_owned()).collect();
    loop {
        let (best, norm) = residual
            .iter()
            .enumerate()
            .filter(|(c, _)| !chosen.contains(c))
            .map(|(c, r)| (c, r.norm()))
            .fold((usize::MAX, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        if best == usize::MAX || norm < tolerance * max_norm {
            break;
        }
        let q = &residual[best] / norm;
        for r in residual.iter_mut() {
            let d = q.dot(r);
            *r -= &q * d;
        }
        basis.push(q);
        chosen.push(best);
    }
    chosen.sort_unstable();
    let sub = DMatrix::from_fn(j.nrows(), chosen.len(), |r, c| j[(r, chosen[c])]);
    let sv = sub.svd(false, false).singular_values;
    let cond = sv.max() / sv.min().max(f64::MIN_POSITIVE);
    (chosen, cond)
}

/// Calibrates `nominal` from `measurements` (graded: serial module, then parallel).
pub fn calibrate(
    nominal: &Robot,
    measurements: &[Measurement],
    config: &EkfConfig,
) -> Result<Calibration, CalibrationError> {
    for (i, m) in measurements.iter().enumerate() {
        let finite = m
            .joints
            .limbs
            .iter()
            .chain(&m.joints.head)
            .all(|v| v.is_finite());
        if !finite {
            return Err(CalibrationError::NonFinite {
                index: i,
                what: "a joint input",
            });
        }
        let p = m.pose.translation.vector;
        if !(p.iter().all(|v| v.is_finite())
            && m.pose.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return Err(CalibrationError::NonFinite {
                index: i,
                what: "the measured pose",
            });
        }
    }
    let serial: Vec<usize> = ErrorParams::serial_indices()
        .chain(ErrorParams::tracker_indices())
        .collect();
    let parallel: Vec<usize> = ErrorParams::parallel_indices().collect();
    let stages: [(&'static str, Vec<usize>); 2] = [("serial", serial), ("parallel", parallel)];
    let mut estimate = ErrorParams::zero();
    let mut guesses: Vec<PlatformPose> = vec![nominal.home(); measurements.len()];
    // Identifiability at the prior (nominal) linearisation point, per stage.
    let mut selected: Vec<Vec<usize>> = Vec::new();
    let mut condition = Vec::new();
    for (name, cols) in &stages {
        let (chosen, cond) = select(
            nominal,
            &estimate,
            measurements,
            &mut guesses,
            cols,
            config,
            name,
        )?;
        selected.push(chosen);
        condition.push(cond);
    }
    // The joint set is chosen at the same (prior) point, so it depends on the poses
    // only, never on the measured values or their order.
    let all: Vec<usize> = stages.iter().flat_map(|(_, c)| c.iter().copied()).collect();
    let (identified, cond) = select(
        nominal,
        &estimate,
        measurements,
        &mut guesses,
        &all,
        config,
        "joint",
    )?;
    condition.push(cond);
    let mut reports = Vec::new();
    for round in 1..=config.max_rounds {
        let before = estimate.values.clone();
        for (s, (name, _)) in stages.iter().enumerate() {
            let graded = EkfConfig {
                max_sweeps: config.graded_sweeps,
                ..config.clone()
            };
            let (sweeps, gamma, _) = ekf_stage(
                nominal,
                measurements,
                &selected[s],
                &graded,
                &mut estimate,
                &mut guesses,
                name,
            )?;
            reports.push(StageReport {
                name,
                round,
                parameters: selected[s].len(),
                sweeps,
                gamma,
            });
        }
        let change = before
            .iter()
            .zip(&estimate.values)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        if change <= config.gamma {
            break;
        }
    }
    // The graded estimate is the starting point of one joint stage over both modules:
    // the modules' parameters are correlated (a platform tilt and a head twist both turn
    // the pad), so only a joint pass converges fully and gives an honest covariance.
    for k in all.iter().filter(|k| !identified.contains(k)) {
        estimate.values[*k] = 0.0; // not identifiable together: back to the prior
    }
    let (sweeps, gamma, covariance) = ekf_stage(
        nominal,
        measurements,
        &identified,
        config,
        &mut estimate,
        &mut guesses,
        "joint",
    )?;
    reports.push(StageReport {
        name: "joint",
        round: 1,
        parameters: identified.len(),
        sweeps,
        gamma,
    });
    Ok(Calibration {
        errors: estimate,
        identified,
        covariance,
        condition,
        stages: reports,
    })
}

/// How many of `measurements` were taken at different joint inputs (closer than 1 µm
/// or 1 µrad counts as the same pose).
pub fn distinct_poses(measurements: &[Measurement]) -> usize {
    let key = |m: &Measurement| {
        let j = &m.joints;
        [
            j.limbs[0],
            j.limbs[1],
            j.limbs[2],
            j.head[0] * 1e3,
            j.head[1] * 1e3,
        ]
        .map(|v| (v * 1e3).round() as i64)
    };
    let mut keys: Vec<[i64; 5]> = measurements.iter().map(key).collect();
    keys.sort_unstable();
    keys.dedup();
    keys.len()
}

/// The identifiable subset of `cols`, linearised at `estimate`, and its condition number.
fn select(
    nominal: &Robot,
    estimate: &ErrorParams,
    measurements: &[Measurement],
    guesses: &mut [PlatformPose],
    cols: &[usize],
    config: &EkfConfig,
    name: &'static str,
) -> Result<(Vec<usize>, f64), CalibrationError> {
    let robot = nominal.with_errors(estimate.clone());
    predict(&robot, measurements, guesses)?;
    let mut stacked = DMatrix::zeros(6 * measurements.len(), cols.len());
    for (i, m) in measurements.iter().enumerate() {
        let j = numeric_columns(&robot, &m.joints, guesses[i], cols)?;
        for c in 0..cols.len() {
            for r in 0..6 {
                // Rows scaled by the noise, columns by the prior: a dimensionless problem.
                let noise = if r < 3 {
                    config.noise_position
                } else {
                    config.noise_attitude
                };
                stacked[(6 * i + r, c)] = j[(r, c)] * config.prior_sigma[cols[c]] / noise;
            }
        }
    }
    let (chosen, cond) = identifiable(&stacked, config.rank_tolerance);
    // Each distinct pose gives 6 equations (the same pose measured again adds none);
    // ask for a margin beyond the bare count.
    let min = chosen.len().div_ceil(6) + 2;
    let distinct = distinct_poses(measurements);
    if distinct < min || chosen.is_empty() {
        return Err(CalibrationError::TooFew {
            stage: name,
            measurements: measurements.len(),
            distinct,
            rank: chosen.len(),
            needed: cols.len(),
            min,
        });
    }
    Ok((chosen.iter().map(|&c| cols[c]).collect(), cond))
}

/// One stage: iterated EKF sweeps over all measurements for the parameters `params`,
/// the others held at `estimate`. Returns sweeps used, final Γ and the posterior
/// covariance.
fn ekf_stage(
    nominal: &Robot,
    ms: &[Measurement],
    params: &[usize],
    config: &EkfConfig,
    estimate: &mut ErrorParams,
    guesses: &mut [PlatformPose],
    stage: &'static str,
) -> Result<(usize, f64, DMatrix<f64>), CalibrationError> {
    let n = params.len();
    let p0 = DMatrix::from_diagonal(&DVector::from_iterator(
        n,
        params.iter().map(|&k| config.prior_sigma[k].powi(2)),
    ));
    let r = DMatrix::from_diagonal(&DVector::from_iterator(
        6,
        (0..6).map(|i| {
            if i < 3 {
                config.noise_position
            } else {
                config.noise_attitude
            }
            .powi(2)
        }),
    ));
    let q = DMatrix::identity(n, n) * config.process_noise;
    let mut lin = DVector::from_iterator(n, params.iter().map(|&k| estimate.values[k]));
    let mut gamma = f64::INFINITY;
    let mut covariance = p0.clone();
    let mut first_gamma = None;
    for sweep in 1..=config.max_sweeps {
        let robot = nominal.with_errors(estimate.clone());
        let predicted = predict(&robot, ms, guesses)?;
        // Eq. 12–16 from the prior, each measurement linearised at `lin`.
        let mut x = DVector::zeros(n);
        let mut p = p0.clone();
        for (i, m) in ms.iter().enumerate() {
            let j = numeric_columns(&robot, &m.joints, guesses[i], params)?;
            let y = DVector::from_row_slice(&twist(&predicted[i], &m.pose));
            p += &q; // eq. 13
            let innovation = y - &j * (&x - &lin);
            let s = &j * &p * j.transpose() + &r;
            let s_inv = s.try_inverse().ok_or_else(|| CalibrationError::Diverged {
                stage,
                sweep,
                why: format!("singular innovation covariance at measurement {i}"),
            })?;
            let k = &p * j.transpose() * s_inv; // eq. 14
            x += &k * innovation; // eq. 15
            let ikj = DMatrix::identity(n, n) - &k * &j;
            // Eq. 16 in Joseph form: the same covariance, kept symmetric and positive.
            p = &ikj * &p * ikj.transpose() + &k * &r * k.transpose();
        }
        if !x.iter().all(|v| v.is_finite()) {
            return Err(CalibrationError::Diverged {
                stage,
                sweep,
                why: "the estimate is not finite".to_string(),
            });
        }
        gamma = (&x - &lin).norm(); // eq. 17
        let first = *first_gamma.get_or_insert(gamma);
        if sweep > 3 && gamma > 10.0 * first.max(config.gamma) {
            return Err(CalibrationError::Diverged {
                stage,
                sweep,
                why: format!("Γ grew from {first:.3e} to {gamma:.3e}"),
            });
        }
        for (c, &k) in params.iter().enumerate() {
            estimate.values[k] = x[c];
        }
        lin = x;
        covariance = p;
        if gamma <= config.gamma {
            return Ok((sweep, gamma, covariance));
        }
    }
    Ok((config.max_sweeps, gamma, covariance))
}
