//! The hybrid robot: nominal geometry (asset), 3-UPS/UP inverse and forward kinematics,
//! the serial MDH head, the full tool pose, and the Table I error parameters; and any
//! serial arm of the user's from its description file (`arm`); one reader of description
//! files for both (`Description`, keyed by their `kind`).
//!
//! CPU only (nalgebra). Units inside: mm and rad. The base frame's z axis points down,
//! towards the workpiece.

pub mod arm;
mod arm_load;
mod description;
mod errors;
mod geometry;
mod parallel;
mod serial;

pub use description::{Description, KINDS};
pub use errors::{ErrorParams, LimbErrors, MdhErrors, LIMB_PARAMS, LIMB_VECTORS, N_PARAMS};
pub use geometry::{Geometry, MdhJoint, DEFAULT_ASSET};
pub use parallel::{platform_frame, tilt, Limb, LimbConstants, PlatformPose};
pub use serial::mdh;

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// The text of a description file; the error names the file.
fn read_description(path: &std::path::Path) -> Result<String, RobotError> {
    std::fs::read_to_string(path).map_err(|e| RobotError::Asset {
        file: path.display().to_string(),
        message: e.to_string(),
    })
}

/// What can go wrong in the robot model, with the numbers that explain it.
#[derive(Debug, thiserror::Error)]
pub enum RobotError {
    /// A robot geometry asset that cannot be read or is invalid.
    #[error("{file}: {message}")]
    Asset {
        /// The asset's file name.
        file: String,
        /// What is wrong, naming the field.
        message: String,
    },
    /// A joint coordinate outside its range (tilt, extension, stroke or joint limit).
    #[error("{what} = {value:.6} is outside the workspace [{low:.6}, {high:.6}]")]
    OutsideWorkspace {
        /// The coordinate, with its unit.
        what: String,
        /// Its value, in that unit.
        value: f64,
        /// The lower end of its range.
        low: f64,
        /// The upper end of its range.
        high: f64,
    },
    /// The parallel module's forward kinematics (Newton) did not converge.
    #[error(
        "forward kinematics did not converge for limb lengths {lengths:?} mm: residual {residual:.3e} mm after {iterations} Newton steps"
    )]
    NoConvergence {
        /// The limb lengths asked for, mm.
        lengths: [f64; 3],
        /// The largest limb length residual left, mm.
        residual: f64,
        /// The Newton steps taken.
        iterations: usize,
    },
    /// The parallel module's forward kinematics met a singular Jacobian.
    #[error("forward kinematics hit a singular configuration at limb lengths {lengths:?} mm")]
    Singular {
        /// The limb lengths asked for, mm.
        lengths: [f64; 3],
    },
    /// The whole robot's inverse kinematics met a singular system.
    #[error("inverse kinematics hit a singular configuration for the tool at {target:?} mm")]
    SingularTool {
        /// The pad centre asked for, mm, base frame.
        target: [f64; 3],
    },
    /// No configuration puts the pad at the target with the tool axis within
    /// [`MAX_AXIS_DEVIATION`] of the one asked for.
    #[error(
        "the tool cannot reach {target:?} mm with the requested axis (residual {residual:.3e})"
    )]
    ToolUnreachable {
        /// The pad centre asked for, mm, base frame.
        target: [f64; 3],
        /// The larger of the position residual (mm) and the axis residual (mrad).
        residual: f64,
    },
}

impl crate::error::StageError for RobotError {}

/// Joint inputs of the whole robot: the three UPS actuator lengths (mm, nodes Q1–Q3) and
/// the two serial joint angles (rad, Q4–Q5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Joints {
    /// The three UPS actuator (limb) lengths, mm.
    pub limbs: [f64; 3],
    /// The two serial joint angles, rad: the revolution joint (continuous), then the tilt joint.
    pub head: [f64; 2],
}

/// A robot: nominal geometry plus a set of geometric errors (zero for the nominal model,
/// a seeded draw for the twin's hidden truth, the estimate after calibration).
#[derive(Clone, Debug)]
pub struct Robot {
    /// The nominal geometry.
    pub geometry: Geometry,
    /// The geometric errors δX applied on top of it (Table I; docs/twin.md "Calibration file").
    pub errors: ErrorParams,
    limbs: [Limb; 3],
    /// Each limb's [`Limb::constants`], made with it.
    joints: [LimbConstants; 3],
}

impl Robot {
    /// A robot of `geometry` carrying `errors`.
    ///
    /// ```
    /// use iastgcn::robot::{ErrorParams, Geometry, Robot};
    ///
    /// let robot = Robot::new(Geometry::default_asset(), ErrorParams::zero());
    /// let lengths = robot.limb_lengths(&robot.home());
    /// robot.check_lengths(&lengths)?;
    /// # Ok::<(), iastgcn::robot::RobotError>(())
    /// ```
    pub fn new(geometry: Geometry, errors: ErrorParams) -> Robot {
        let b = geometry.base_points();
        let a = geometry.platform_points();
        let delta = geometry.parallel.shaft_length;
        let limbs = [0, 1, 2].map(|i| Limb {
            b: b[i],
            a0: a[i],
            delta,
            err: errors.limb(i),
        });
        Robot {
            geometry,
            errors,
            joints: limbs.map(|l| l.constants()),
            limbs,
        }
    }

    /// The error-free robot of the given geometry.
    pub fn nominal(geometry: Geometry) -> Robot {
        Robot::new(geometry, ErrorParams::zero())
    }

    /// The same geometry with other errors.
    pub fn with_errors(&self, errors: ErrorParams) -> Robot {
        Robot::new(self.geometry.clone(), errors)
    }

    /// Home: platform untilted in the middle of its extension, head at zero.
    pub fn home(&self) -> PlatformPose {
        let [lo, hi] = self.geometry.parallel.extension;
        PlatformPose {
            alpha: 0.0,
            beta: 0.0,
            w: 0.5 * (lo + hi),
        }
    }

    /// Platform frame in the base frame, with the platform errors Δr_A, θ_A.
    pub fn platform_frame(&self, p: &PlatformPose) -> Isometry3<f64> {
        let (dr, theta) = self.errors.platform();
        let err = Isometry3::from_parts(
            Translation3::from(dr),
            UnitQuaternion::from_scaled_axis(theta),
        );
        err * platform_frame(p)
    }

    /// Inverse kinematics of the parallel module (closed form per limb): the actuator
    /// lengths that put the platform at `p`.
    pub fn limb_lengths(&self, p: &PlatformPose) -> [f64; 3] {
        let frame = self.platform_frame(p);
        [0, 1, 2].map(|i| self.limbs[i].length_with(&frame, &self.joints[i]))
    }

    /// Fails when `p` leaves the UP joint's tilt range or the slide's extension range.
    pub fn check_platform(&self, p: &PlatformPose) -> Result<(), RobotError> {
        let g = &self.geometry.parallel;
        let t = g.tilt_limit_deg.to_radians();
        check("platform tilt alpha (rad)", p.alpha, [-t, t])?;
        check("platform tilt beta (rad)", p.beta, [-t, t])?;
        check("UP limb extension w (mm)", p.w, g.extension)
    }

    /// Fails when an actuator length leaves its stroke.
    pub fn check_lengths(&self, lengths: &[f64; 3]) -> Result<(), RobotError> {
        for (i, &l) in lengths.iter().enumerate() {
            check(
                &format!("limb {} length (mm)", i + 1),
                l,
                self.geometry.parallel.stroke,
            )?;
        }
        Ok(())
    }

    /// Fails when a serial joint leaves its range.
    pub fn check_head(&self, head: &[f64; 2]) -> Result<(), RobotError> {
        for (j, (&q, joint)) in head.iter().zip(&self.geometry.serial.joints).enumerate() {
            let what = format!("serial joint {} ({}) angle (rad)", j + 1, joint.name);
            let range = match joint.limits_deg {
                Some([lo, hi]) => [lo.to_radians(), hi.to_radians()],
                None => [f64::MIN, f64::MAX],
            };
            check(&what, q, range)?;
        }
        Ok(())
    }

    /// Forward kinematics of the parallel module: Newton on the limb lengths, started at
    /// `guess` (home when `None`); the result is checked against the workspace.
    pub fn platform_from_lengths(
        &self,
        lengths: [f64; 3],
        guess: Option<PlatformPose>,
    ) -> Result<PlatformPose, RobotError> {
        self.check_lengths(&lengths)?;
        let target = Vector3::from(lengths);
        let mut x = guess.unwrap_or_else(|| self.home()).to_vector();
        let f = |x: &Vector3<f64>| {
            Vector3::from(self.limb_lengths(&PlatformPose::from_vector(x))) - target
        };
        let max_iter = 30;
        let mut r = f(&x);
        for _ in 0..max_iter {
            if r.amax() < 1e-11 {
                let p = PlatformPose::from_vector(&x);
                self.check_platform(&p)?;
                return Ok(p);
            }
            let mut j = Matrix3::zeros();
            for k in 0..3 {
                // Central differences: rad steps for the tilts, mm for the extension.
                let h = if k < 2 { 1e-7 } else { 1e-5 };
                let mut xp = x;
                let mut xm = x;
                xp[k] += h;
                xm[k] -= h;
                j.set_column(k, &((f(&xp) - f(&xm)) / (2.0 * h)));
            }
            let step = parallel::newton_step(&j, &r).ok_or(RobotError::Singular { lengths })?;
            x -= step;
            if !x.iter().all(|v| v.is_finite()) || x[0].abs() > 1.5 || x[1].abs() > 1.5 {
                break;
            }
            r = f(&x);
        }
        Err(RobotError::NoConvergence {
            lengths,
            residual: r.amax(),
            iterations: max_iter,
        })
    }

    /// Platform frame → the frame each serial joint's MDH row ends in (its z axis is the
    /// joint's axis), with the errors.
    fn serial_frames(&self, head: &[f64; 2]) -> [Isometry3<f64>; 2] {
        let mut t = Isometry3::identity();
        let mut out = [Isometry3::identity(); 2];
        for (j, joint) in self.geometry.serial.joints.iter().enumerate() {
            let e = self.errors.mdh(j);
            t *= mdh(
                joint.alpha_deg.to_radians() + e.alpha,
                joint.a + e.a,
                head[j] + joint.theta_offset_deg.to_radians() + e.theta,
                joint.d + e.d,
            );
            out[j] = t;
        }
        out
    }

    /// Platform frame → tool frame (pad centre, z along the tool axis) through the MDH
    /// rows of the head and the tool, with their errors.
    pub fn head_transform(&self, head: &[f64; 2]) -> Isometry3<f64> {
        let tool = &self.geometry.tool;
        let t = self.serial_frames(head)[1]
            * mdh(
                tool.alpha_deg.to_radians(),
                tool.a,
                tool.theta_deg.to_radians(),
                tool.d,
            );
        t * Translation3::from(self.errors.tool())
    }

    /// Each serial joint's axis in the base frame, as (a point on it, its unit direction).
    pub fn joint_axes(
        &self,
        p: &PlatformPose,
        head: &[f64; 2],
    ) -> [(Point3<f64>, Vector3<f64>); 2] {
        let platform = self.platform_frame(p);
        self.serial_frames(head).map(|f| {
            let t = platform * f;
            (t * Point3::origin(), t.rotation * Vector3::z())
        })
    }

    /// Tool pose in the base frame for a platform pose and head angles.
    pub fn tool_pose(&self, p: &PlatformPose, head: &[f64; 2]) -> Isometry3<f64> {
        self.platform_frame(p) * self.head_transform(head)
    }

    /// Full forward kinematics from joint inputs: the platform pose (Newton from `guess`)
    /// and the tool pose in the base frame.
    pub fn forward(
        &self,
        joints: &Joints,
        guess: Option<PlatformPose>,
    ) -> Result<(PlatformPose, Isometry3<f64>), RobotError> {
        self.check_head(&joints.head)?;
        let p = self.platform_from_lengths(joints.limbs, guess)?;
        Ok((p, self.tool_pose(&p, &joints.head)))
    }

    /// Pose of the base frame in the laser tracker's frame, with the registration error.
    pub fn tracker_from_base(&self) -> Isometry3<f64> {
        let (dp, theta) = self.errors.tracker();
        let err = Isometry3::from_parts(
            Translation3::from(dp),
            UnitQuaternion::from_scaled_axis(theta),
        );
        err * self.geometry.tracker_from_base()
    }
}

fn check(what: &str, value: f64, [low, high]: [f64; 2]) -> Result<(), RobotError> {
    if value.is_finite() && (low..=high).contains(&value) {
        Ok(())
    } else {
        Err(RobotError::OutsideWorkspace {
            what: what.to_string(),
            value,
            low,
            high,
        })
    }
}

/// Weight of the tool-axis residual (mm per rad) in [`Robot::solve_tool`].
const AXIS_WEIGHT: f64 = 1.0;
/// Largest tool-axis deviation (rad) [`Robot::solve_tool`] accepts where the exact axis is
/// out of reach.
pub const MAX_AXIS_DEVIATION: f64 = 0.01;

/// A configuration of the whole robot in its joint coordinates: the platform pose (UP
/// limb joints) and the two head angles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Configuration {
    /// The parallel module's pose: the UP joint's tilts and the slide's extension.
    pub platform: PlatformPose,
    /// The serial joint angles, rad (revolution, tilt).
    pub head: [f64; 2],
}

impl Configuration {
    fn to_array(self) -> [f64; 5] {
        let p = self.platform;
        [p.alpha, p.beta, p.w, self.head[0], self.head[1]]
    }

    fn from_array(x: &[f64; 5]) -> Configuration {
        Configuration {
            platform: PlatformPose {
                alpha: x[0],
                beta: x[1],
                w: x[2],
            },
            head: [x[3], x[4]],
        }
    }
}

/// Where the tool should be: pad centre (mm, base frame) and the unit tool axis. The spin
/// about the axis is free (the pad rotates anyway), which leaves five coordinates for the
/// robot's five joints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolTarget {
    /// The pad centre, mm, base frame.
    pub position: Vector3<f64>,
    /// The unit tool axis, base frame.
    pub axis: Vector3<f64>,
}

impl Robot {
    /// Inverse kinematics of the whole robot: the configuration that puts the pad centre
    /// at `target.position` with the tool axis along `target.axis`, by Gauss–Newton from
    /// `guess` (the previous step of a path keeps the solution branch continuous). The
    /// result is checked against every joint range, the limb strokes included.
    pub fn solve_tool(
        &self,
        target: &ToolTarget,
        guess: &Configuration,
    ) -> Result<(Configuration, [f64; 3]), RobotError> {
        let first = self.solve_tool_from(target, guess);
        if first.is_ok() {
            return first;
        }
        // A guess on or near the head's singularity (tilt about 0) cannot tell which way
        // to tilt, and an axis asked to tilt the other way from one tick to the next (a
        // correction near the vertex) needs the revolution angle half a turn round: try
        // tilting from four revolution angles, keeping the first that converges.
        for k in 0..4 {
            let mut g = *guess;
            g.head = [guess.head[0] + k as f64 * std::f64::consts::FRAC_PI_2, 0.02];
            if let Ok(found) = self.solve_tool_from(target, &g) {
                return Ok(found);
            }
        }
        first
    }

    fn solve_tool_from(
        &self,
        target: &ToolTarget,
        guess: &Configuration,
    ) -> Result<(Configuration, [f64; 3]), RobotError> {
        let axis = target.axis.normalize();
        // Residual: position (mm) and tool axis (rad × AXIS_WEIGHT). The light axis weight
        // matters only where no exact solution exists: a head whose axes are not quite
        // perpendicular cannot point its tool within a few mrad of the revolution axis,
        // and there position is kept and the axis gives way.
        let residual = |x: &[f64; 5]| -> nalgebra::SVector<f64, 6> {
            let c = Configuration::from_array(x);
            let t = self.tool_pose(&c.platform, &c.head);
            let dp = t.translation.vector - target.position;
            let dn = (t.rotation * Vector3::z() - axis) * AXIS_WEIGHT;
            nalgebra::SVector::<f64, 6>::from_column_slice(&[dp.x, dp.y, dp.z, dn.x, dn.y, dn.z])
        };
        let mut x = guess.to_array();
        let mut r = residual(&x);
        // Levenberg–Marquardt: the damping makes the head's singularity harmless (at tilt
        // 0 the revolution angle has no effect and JᵀJ is singular; the damped step leaves
        // it alone) and backs off whenever a step would not reduce the residual.
        let mut lambda = 1e-9;
        for _ in 0..100 {
            if r.amax() < 1e-11 {
                break;
            }
            let mut j = nalgebra::SMatrix::<f64, 6, 5>::zeros();
            for k in 0..5 {
                let h = if k == 2 { 1e-5 } else { 1e-7 };
                let (mut xp, mut xm) = (x, x);
                xp[k] += h;
                xm[k] -= h;
                j.set_column(k, &((residual(&xp) - residual(&xm)) / (2.0 * h)));
            }
            let jtj = j.transpose() * j;
            let jtr = j.transpose() * r;
            let scale = jtj.diagonal().max();
            let mut improved = false;
            while lambda < 1e3 {
                let mut damped = jtj;
                for k in 0..5 {
                    damped[(k, k)] += lambda * scale;
                }
                let step = damped.lu().solve(&jtr).ok_or(RobotError::SingularTool {
                    target: target.position.into(),
                })?;
                let mut trial = x;
                for k in 0..5 {
                    trial[k] -= step[k];
                }
                let rt = residual(&trial);
                if rt.norm() < r.norm() {
                    let gain = r.norm() - rt.norm();
                    improved = gain > 1e-14 * r.norm().max(1e-300);
                    x = trial;
                    r = rt;
                    lambda = (lambda / 3.0).max(1e-12);
                    break;
                }
                lambda *= 10.0;
            }
            // A least-squares optimum (no step reduces the residual any more).
            if !improved {
                break;
            }
        }
        let position_error = r.fixed_rows::<3>(0).norm();
        let axis_error = r.fixed_rows::<3>(3).norm() / AXIS_WEIGHT;
        if !(position_error < 1e-4 && axis_error < MAX_AXIS_DEVIATION) {
            return Err(RobotError::ToolUnreachable {
                target: target.position.into(),
                residual: position_error.max(axis_error * 1000.0),
            });
        }
        // Whole turns of the revolution joint give the same pose: keep the one nearest
        // the guess, so a path never makes its head spin needlessly.
        let turn = std::f64::consts::TAU;
        x[3] = guess.head[0] + (x[3] - guess.head[0] + 0.5 * turn).rem_euclid(turn) - 0.5 * turn;
        let c = Configuration::from_array(&x);
        self.check_platform(&c.platform)?;
        self.check_head(&c.head)?;
        let lengths = self.limb_lengths(&c.platform);
        self.check_lengths(&lengths)?;
        Ok((c, lengths))
    }
}
