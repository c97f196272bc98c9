//! The running twin: a controller turns path targets into joint commands with *its*
//! model of the robot; the hidden-truth machine moves with its geometric errors and its
//! non-geometric sources; the sensors and the laser tracker report what they see.

use std::sync::Arc;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::machine::{Actual, Machine, MachineState};
use super::mirror::Mirror;
use super::noise::gaussian;
use super::sensors::{
    tracker_noise, Instruments, Scene, SensorRates, SensorSpecs, CHANNELS, SENSOR_CHANNELS,
};
use super::trajectory::{FeedPlan, Path, PathKind, PathParams};
use crate::robot::{Configuration, Joints, PlatformPose, Robot, RobotError, ToolTarget};

/// The twin's default mean feed along a path, mm/s.
pub const DEFAULT_FEED: f64 = 20.0;
/// The twin's default mean polishing force, N.
pub const DEFAULT_FORCE: f64 = 100.0;

/// Settings of one polishing run.
#[derive(Clone, Debug)]
pub struct SimConfig {
    /// Control period, s.
    pub dt: f64,
    /// Length of the run, s.
    pub duration: f64,
    /// The polishing path.
    pub path: PathKind,
    /// Its spacing, margin and placement on the part.
    pub path_params: PathParams,
    /// Mean feed along the path, mm/s.
    pub feed: f64,
    /// Relative amplitude of the dwell-time modulation of the feed.
    pub feed_variation: f64,
    /// A feed planned along the path (a dwell-time map turned into feed, the polishing
    /// stage's, docs/polishing.md): when set it replaces `feed` and `feed_variation`.
    pub feed_plan: Option<Arc<FeedPlan>>,
    /// Mean of the pneumatic polishing force, N.
    pub force_mean: f64,
    /// Standard deviation of the force (Ornstein–Uhlenbeck), N.
    pub force_sd: f64,
    /// Correlation time of the force, s.
    pub force_time_constant: f64,
    /// The instruments' specifications.
    pub sensors: SensorSpecs,
    /// Every how many ticks each sensor samples.
    pub rates: SensorRates,
    /// The run's seed: force, feed modulation, sensor noise and drift.
    pub seed: u64,
}

impl SimConfig {
    /// A run of `duration` seconds along `path` at the default placement, with the
    /// docs/twin.md defaults: 50 Hz control, 20 mm/s feed ±30 %, 100 ± 15 N force.
    ///
    /// ```
    /// use iastgcn::twin::{PathKind, SimConfig};
    ///
    /// let config = SimConfig::new(PathKind::Grid, 60.0, 7);
    /// assert_eq!(config.dt, 0.02);
    /// assert_eq!(config.steps(), 3000);
    /// ```
    pub fn new(path: PathKind, duration: f64, seed: u64) -> SimConfig {
        SimConfig {
            dt: 0.02,
            duration,
            path,
            path_params: PathParams::default(),
            feed: DEFAULT_FEED,
            feed_variation: 0.3,
            feed_plan: None,
            force_mean: DEFAULT_FORCE,
            force_sd: 15.0,
            force_time_constant: 20.0,
            sensors: SensorSpecs::default(),
            rates: SensorRates::default(),
            seed,
        }
    }

    /// The number of control ticks in the run.
    pub fn steps(&self) -> usize {
        (self.duration / self.dt).round() as usize
    }
}

/// What the twin knows and a real machine would not: for tests and diagnostics only,
/// never written to a recording.
#[derive(Clone, Copy, Debug)]
pub struct Hidden {
    /// Where the path wanted the pad (before any [`Correction`]).
    pub target: ToolTarget,
    /// Pad pose the controller's model expects for its command.
    pub commanded: Isometry3<f64>,
    /// Where the machine really was.
    pub actual: Actual,
    /// The contact force pressing the pad on the glass, N (what the force channel F reads
    /// through seal friction and valve lag).
    pub force: f64,
}

/// One control tick as the sensors saw it.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Run time of the tick, s, from 0.
    pub t: f64,
    /// Per [`CHANNELS`], `None` when that sensor had no sample at this tick (the planned
    /// motion is there every tick).
    pub channels: [Option<f64>; CHANNELS.len()],
    /// The tracker's measurement of the pad pose in its own frame.
    pub tracker: Option<Isometry3<f64>>,
    /// The tick's hidden truth.
    pub hidden: Hidden,
}

/// A pose correction the controller subtracts from the target before inverse kinematics:
/// the position moves by −dp (mm, base frame) and the tool axis turns by the rotation −dr
/// (rotation vector, rad, base frame). A residual dp = p_actual − p_target with dr the
/// rotation taking the target axis to the actual one is thus cancelled to first order.
/// The component of dr along the tool axis has no effect: a [`ToolTarget`] leaves the
/// spin about the axis free.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Correction {
    /// Position correction, mm, base frame.
    pub dp: Vector3<f64>,
    /// Attitude correction, rotation vector, rad, base frame.
    pub dr: Vector3<f64>,
}

impl Correction {
    /// The target the controller solves for: `target` moved by −dp, its axis turned by −dr.
    /// A zero correction returns `target` bit for bit.
    pub fn apply(&self, target: &ToolTarget) -> ToolTarget {
        let axis = if self.dr == Vector3::zeros() {
            target.axis
        } else {
            UnitQuaternion::from_scaled_axis(-self.dr) * target.axis
        };
        ToolTarget {
            position: target.position - self.dp,
            axis,
        }
    }
}

/// How far `actual` is from `target`: the pad-centre distance ‖p_actual − p_target‖ in µm
/// and the angle between the actual tool axis (the pose's z axis, as
/// [`Robot::solve_tool`] and [`Robot::tool_pose`] define it) and the target axis in mdeg.
pub fn pose_error(target: &ToolTarget, actual: &Isometry3<f64>) -> (f64, f64) {
    let position = (actual.translation.vector - target.position).norm() * 1e3;
    let axis = actual.rotation * Vector3::z();
    let goal = target.axis.normalize();
    // atan2 keeps full precision for small angles, where acos of the dot product does not.
    let angle = axis.cross(&goal).norm().atan2(axis.dot(&goal));
    (position, angle.to_degrees() * 1e3)
}

/// A polishing run: call [`Simulation::step`] until it returns `None`.
pub struct Simulation<'a> {
    machine: &'a Machine,
    controller: &'a Robot,
    mirror: Mirror,
    config: SimConfig,
    path: Path,
    rng: ChaCha8Rng,
    state: MachineState,
    start_clock: f64,
    instruments: Instruments,
    k: usize,
    arc: f64,
    force: f64,
    phases: [f64; 2],
    command: Configuration,
    platform: PlatformPose,
    last_target: Option<Vector3<f64>>,
    correction: Correction,
    /// Ticks whose corrected target the controller could not reach.
    unreachable: usize,
    /// The force channel's latest reading, N.
    force_reading: Option<f64>,
}

impl<'a> Simulation<'a> {
    /// Starts at the beginning of the path on a cold machine (the start of a session),
    /// the controller having moved there from home.
    pub fn new(
        machine: &'a Machine,
        controller: &'a Robot,
        mirror: Mirror,
        config: SimConfig,
    ) -> Result<Simulation<'a>, RobotError> {
        Simulation::resume(machine, controller, mirror, config, machine.cold())
    }

    /// Starts at the beginning of the path on a machine in `state` (warm from earlier
    /// runs of the session), the controller having moved there from wherever it was.
    pub fn resume(
        machine: &'a Machine,
        controller: &'a Robot,
        mirror: Mirror,
        config: SimConfig,
        state: MachineState,
    ) -> Result<Simulation<'a>, RobotError> {
        let path = Path::generate(config.path, &mirror, &config.path_params);
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let phases =
            [0, 1].map(|_| rand::RngExt::random_range(&mut rng, 0.0..std::f64::consts::TAU));
        let instruments = Instruments::new(config.sensors, machine.sensors, &mut rng);
        let [x, y] = path.at(0.0);
        let home = Configuration {
            platform: controller.home(),
            head: [0.0, 0.0],
        };
        let (command, _) = controller.solve_tool(&mirror.target(x, y), &home)?;
        Ok(Simulation {
            machine,
            controller,
            mirror,
            force: config.force_mean,
            path,
            rng,
            start_clock: state.clock,
            state,
            instruments,
            k: 0,
            arc: 0.0,
            phases,
            command,
            platform: command.platform,
            last_target: None,
            correction: Correction::default(),
            unreachable: 0,
            force_reading: None,
            config,
        })
    }

    /// The machine's state after the ticks run so far (to resume the session with).
    pub fn machine_state(&self) -> MachineState {
        let mut s = self.state.clone();
        s.clock = self.start_clock + self.k as f64 * self.config.dt;
        s
    }

    /// The path being polished.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The run's settings.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The correction applied from the next tick on (until set again): the controller
    /// solves its inverse kinematics for `c.apply(target)` instead of the path target.
    /// [`Hidden::target`] stays the path target, so errors are measured against it;
    /// [`Hidden::commanded`] is the pose the controller expects for its corrected command.
    /// The polishing force still presses along the path target's axis and feeds along the
    /// path. [`Correction::default`] (the start) leaves the run bit-identical to an
    /// uncorrected one.
    ///
    /// A corrected target the inverse kinematics cannot reach (near a singular head
    /// configuration, say) is dropped for that tick: the controller solves for the path
    /// target itself, as uncorrected, and counts the tick
    /// ([`Simulation::unreachable_corrections`]).
    pub fn set_correction(&mut self, c: Correction) {
        self.correction = c;
    }

    /// Ticks so far whose corrected target could not be reached (each ran uncorrected).
    pub fn unreachable_corrections(&self) -> usize {
        self.unreachable
    }

    /// Advances one control tick.
    pub fn step(&mut self) -> Option<Result<Sample, RobotError>> {
        if self.k >= self.config.steps() {
            return None;
        }
        if let Some(plan) = &self.config.feed_plan {
            if plan.walk_once && self.arc >= self.path.length() {
                return None;
            }
        }
        Some(self.tick())
    }

    /// The feed at run time `t` from the arc length reached so far, mm/s. Dwell-time
    /// polishing: the feed follows a plan, or breathes around its mean. Depends on nothing
    /// measured after the previous tick, so the controller knows the next tick's feed (the
    /// planned motion of [`PLAN_CHANNELS`](super::PLAN_CHANNELS)).
    fn feed(&self, t: f64) -> f64 {
        let arc = self.arc;
        let c = &self.config;
        match &c.feed_plan {
            // Force-compensated dwell: the latest force reading (the F channel), within
            // a factor of two of the reference.
            Some(plan) => match (plan.force_reference, self.force_reading) {
                (Some(f0), Some(f)) if f0 > 0.0 => plan.feed_at(arc) * (f / f0).clamp(0.5, 2.0),
                _ => plan.feed_at(arc),
            },
            None => {
                c.feed
                    * (1.0
                        + c.feed_variation
                            * (t / 7.0 + self.phases[0]).sin()
                            * (t / 23.0 + self.phases[1]).cos())
            }
        }
    }

    fn tick(&mut self) -> Result<Sample, RobotError> {
        let c = &self.config;
        let (dt, k) = (c.dt, self.k);
        let t = k as f64 * dt;
        if k > 0 {
            self.arc += self.feed(t) * dt;
        }
        // Pneumatic force: Ornstein–Uhlenbeck around its mean.
        let a = (-dt / c.force_time_constant).exp();
        self.force = c.force_mean
            + (self.force - c.force_mean) * a
            + gaussian(&mut self.rng, c.force_sd * (1.0 - a * a).sqrt());
        let [x, y] = self.path.at(self.arc);
        let target = self.mirror.target(x, y);
        let (command, lengths) = match self
            .controller
            .solve_tool(&self.correction.apply(&target), &self.command)
        {
            Ok(solved) => solved,
            Err(_) if self.correction != Correction::default() => {
                self.unreachable += 1;
                self.controller.solve_tool(&target, &self.command)?
            }
            Err(e) => return Err(e),
        };
        self.command = command;
        let encoders = Joints {
            limbs: lengths,
            head: command.head,
        };
        let feed_dir = match self.last_target {
            Some(p) if (target.position - p).norm() > 1e-9 => (target.position - p).normalize(),
            _ => Vector3::zeros(),
        };
        self.last_target = Some(target.position);
        let clock = self.start_clock + t;
        let actual = self.machine.drive(
            &mut self.state,
            clock,
            dt,
            &encoders,
            Some((&target.axis, &feed_dir, self.force)),
            self.platform,
        )?;
        self.platform = actual.platform;
        let commanded = self.controller.tool_pose(&command.platform, &command.head);
        let terms = &actual.terms;
        let scene = Scene {
            dt,
            encoder_lengths: encoders.limbs,
            encoder_angles: encoders.head,
            nut_error: [0, 1, 2]
                .map(|i| terms.lost_motion[i] + terms.thermal.screw[i] + terms.give.screw[i]),
            nut_travel: self.machine.nut_travel(&encoders.limbs),
            screw_rise: self.state.screw_rise(),
            ambient: self.state.ambient(clock),
            extension: actual.platform.w,
            commanded_extension: command.platform.w,
            joint_angles: actual.joints.head,
            pose: actual.pose,
            commanded,
            force: self.force,
        };
        let values = self.instruments.read(&scene, &mut self.rng);
        // Only the ticks at each sensor's rate are kept.
        let c = &self.config;
        let mut channels = [None; CHANNELS.len()];
        for (i, v) in values.into_iter().enumerate() {
            if (k as u32).is_multiple_of(c.rates.channel_every[i]) {
                channels[i] = Some(v);
            }
        }
        const FORCE: usize = SENSOR_CHANNELS - 1;
        debug_assert_eq!(CHANNELS[FORCE], "F");
        if let Some(f) = channels[FORCE] {
            self.force_reading = Some(f);
        }
        // The planned motion to the next tick: its feed from this tick's force reading,
        // as the next tick will compute it, along the path, corrections left out (they
        // come from measurements; the plan is the program).
        let next_arc = self.arc + self.feed(t + dt) * dt;
        let [nx, ny] = self.path.at(next_arc);
        let planned = (self.mirror.target(nx, ny).position - target.position) / dt;
        for (slot, v) in channels[SENSOR_CHANNELS..].iter_mut().zip(planned.iter()) {
            *slot = Some(*v);
        }
        let in_tracker = self.machine.robot.tracker_from_base() * actual.pose;
        let specs = c.sensors;
        let measured = tracker_noise(
            &mut self.rng,
            &in_tracker,
            specs.tracker_position,
            specs.tracker_attitude,
        );
        let tracker = (k as u32)
            .is_multiple_of(c.rates.tracker_every)
            .then_some(measured);
        self.k += 1;
        debug_assert_eq!(channels.len(), CHANNELS.len());
        Ok(Sample {
            t,
            channels,
            tracker,
            hidden: Hidden {
                target,
                commanded,
                actual,
                force: self.force,
            },
        })
    }
}

/// One static calibration measurement: the commanded joint inputs and the tracker's
/// measured pad pose (tracker frame).
#[derive(Clone, Copy, Debug)]
pub struct CalibrationMeasurement {
    /// The commanded joint inputs.
    pub joints: Joints,
    /// The tracker's pad pose, tracker frame, averaged over the repeats.
    pub measured: Isometry3<f64>,
    /// The true pad pose in the base frame (hidden; for tests).
    pub actual: Isometry3<f64>,
}

/// Limb speed of the moves between calibration poses, mm/s.
const CALIBRATION_SPEED: f64 = 10.0;
/// Time at rest at each calibration pose while the tracker measures, s.
const CALIBRATION_SETTLE: f64 = 30.0;

/// Drives the machine to each configuration (joint inputs from the nominal model of the
/// controller) and measures it at rest: no polishing force, the tracker's reading averaged
/// over `repeats` samples.
pub fn measure_calibration(
    machine: &Machine,
    controller: &Robot,
    configurations: &[Configuration],
    specs: &SensorSpecs,
    repeats: usize,
    seed: u64,
) -> Result<Vec<CalibrationMeasurement>, RobotError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut state = machine.cold();
    let mut guess = controller.home();
    let mut last = controller.limb_lengths(&guess);
    let mut t = 0.0;
    configurations
        .iter()
        .map(|c| {
            let joints = Joints {
                limbs: controller.limb_lengths(&c.platform),
                head: c.head,
            };
            // Move at the calibration speed, then settle while the tracker measures: the
            // screws warm during the move and cool during the wait, as on a real machine.
            let travel = (0..3)
                .map(|i| (joints.limbs[i] - last[i]).abs())
                .fold(0.0, f64::max);
            let moving = (travel / CALIBRATION_SPEED).max(1.0);
            t += moving;
            let moved = machine.drive(&mut state, t, moving, &joints, None, guess)?;
            t += CALIBRATION_SETTLE;
            let actual = machine.drive(
                &mut state,
                t,
                CALIBRATION_SETTLE,
                &joints,
                None,
                moved.platform,
            )?;
            last = joints.limbs;
            guess = actual.platform;
            let in_tracker = machine.robot.tracker_from_base() * actual.pose;
            // The mean of `repeats` readings: the noise shrinks by √repeats.
            let shrink = (repeats.max(1) as f64).sqrt();
            let measured = tracker_noise(
                &mut rng,
                &in_tracker,
                specs.tracker_position / shrink,
                specs.tracker_attitude / shrink,
            );
            Ok(CalibrationMeasurement {
                joints,
                measured,
                actual: actual.pose,
            })
        })
        .collect()
}
