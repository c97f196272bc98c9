//! The hidden-truth machine: its geometry with errors, its non-geometric sources and how
//! its instruments are mounted; the state those sources carry from run to run; and where
//! the machine's tool really is for a given command.

use nalgebra::{Isometry3, Point3, Translation3, Vector3};

use super::sensors::Installation;
use super::sources::{
    compliance, Backlash, Day, LimbGive, LostMotion, NonGeometric, Thermal, ThermalGrowth, ToolLoad,
};
use crate::robot::{Joints, PlatformPose, Robot, RobotError};

/// The hidden-truth machine: geometry with its errors, its non-geometric sources, and how
/// its instruments were mounted.
#[derive(Clone, Debug)]
pub struct Machine {
    /// The true robot: the nominal geometry with the drawn geometric errors.
    pub robot: Robot,
    /// The non-geometric error sources that act (docs/twin.md "Error sources").
    pub nongeometric: NonGeometric,
    /// How the instruments were mounted, fixed for the life of the machine.
    pub sensors: Installation,
}

/// The dynamic state of a machine's non-geometric sources (temperatures, which side of
/// its play each drive rests on, screw wear) and the session clock. It carries over from
/// one run to the next of a session: [`Simulation::resume`](super::Simulation::resume) starts from it,
/// [`Simulation::machine_state`](super::Simulation::machine_state) hands it on, [`MachineState::idle`] lets time pass.
#[derive(Clone, Debug)]
pub struct MachineState {
    lost_motion: Option<LostMotion>,
    backlash: Option<Backlash>,
    thermal: Option<Thermal>,
    /// Seconds since the session began (the ambient drift follows it).
    pub clock: f64,
}

impl MachineState {
    /// Leaves the machine at rest for `seconds`: the screws cool, the drives keep the
    /// side of their play they rest on.
    pub fn idle(&mut self, seconds: f64) {
        if let Some(th) = &mut self.thermal {
            th.idle(seconds);
        }
        self.clock += seconds;
    }

    /// This state with only the sources that `sources` has (for a copy of the machine with
    /// some sources switched off).
    pub fn keeping(&self, sources: &NonGeometric) -> MachineState {
        MachineState {
            lost_motion: self
                .lost_motion
                .clone()
                .filter(|_| sources.lost_motion.is_some()),
            backlash: self.backlash.clone().filter(|_| sources.backlash.is_some()),
            thermal: self.thermal.clone().filter(|_| sources.thermal.is_some()),
            clock: self.clock,
        }
    }

    /// Temperature rise of each screw above ambient, K (zero without thermal growth).
    pub fn screw_rise(&self) -> [f64; 3] {
        self.thermal.as_ref().map_or([0.0; 3], Thermal::rise)
    }

    /// Ambient temperature offset at session time `t`, K (zero without thermal growth).
    pub fn ambient(&self, t: f64) -> f64 {
        self.thermal.as_ref().map_or(0.0, |th| th.ambient(t))
    }
}

/// Every non-geometric error term of one tick, as the twin applied it (hidden truth: for
/// the error budget, diagnostics and tests, never written to a recording).
#[derive(Clone, Copy, Debug)]
pub struct SourceTerms {
    /// Ball-screw lost motion per limb, mm.
    pub lost_motion: [f64; 3],
    /// Thermal growth per limb (screw and tube parts), mm.
    pub thermal: ThermalGrowth,
    /// Stretch and joint clearance per limb, mm.
    pub give: LimbGive,
    /// Gear backlash per serial joint, rad.
    pub backlash: [f64; 2],
    /// Gear transmission error per serial joint, rad.
    pub transmission: [f64; 2],
    /// Gear wind-up under the load per serial joint, rad.
    pub windup: [f64; 2],
    /// Deflection of the pad under the polishing load (base frame, at the pad).
    pub tip: Isometry3<f64>,
}

impl Default for SourceTerms {
    fn default() -> SourceTerms {
        SourceTerms {
            lost_motion: [0.0; 3],
            thermal: ThermalGrowth::default(),
            give: LimbGive::default(),
            backlash: [0.0; 2],
            transmission: [0.0; 2],
            windup: [0.0; 2],
            tip: Isometry3::identity(),
        }
    }
}

/// Where the machine really is after one control tick.
#[derive(Clone, Copy, Debug)]
pub struct Actual {
    /// The true platform pose, after lost motion, thermal growth and limb give.
    pub platform: PlatformPose,
    /// True rod lengths (mm) and load-side joint angles (rad).
    pub joints: Joints,
    /// True pad pose in the base frame, deflections included.
    pub pose: Isometry3<f64>,
    /// The non-geometric terms applied this tick (hidden truth).
    pub terms: SourceTerms,
}

impl Machine {
    /// The machine switched on cold at the start of a session on the calibration day.
    pub fn cold(&self) -> MachineState {
        self.cold_on(Day::CALIBRATION)
    }

    /// The machine switched on cold at the start of a session on `day` (its ambient).
    pub fn cold_on(&self, day: Day) -> MachineState {
        let ng = &self.nongeometric;
        MachineState {
            lost_motion: ng.lost_motion.map(LostMotion::new),
            backlash: ng.backlash.map(Backlash::new),
            thermal: ng.thermal.map(|p| Thermal::on(p, day)),
            clock: 0.0,
        }
    }

    /// Distance of each limb's nut from its screw's fixed bearing, mm.
    pub fn nut_travel(&self, lengths: &[f64; 3]) -> [f64; 3] {
        lengths.map(|l| (l - self.nongeometric.screw_origin).max(0.0))
    }

    /// One tick at session time `t`: the drives sit at `encoders`; returns the true state.
    /// `contact` = (tool axis, feed direction, force): the pad presses along the axis
    /// while it moves along the feed (`None` at rest).
    pub(super) fn drive(
        &self,
        state: &mut MachineState,
        t: f64,
        dt: f64,
        encoders: &Joints,
        contact: Option<(&Vector3<f64>, &Vector3<f64>, f64)>,
        guess: PlatformPose,
    ) -> Result<Actual, RobotError> {
        let mut terms = SourceTerms::default();
        if let Some(lm) = &mut state.lost_motion {
            terms.lost_motion = lm.step(encoders.limbs);
        }
        if let Some(th) = &mut state.thermal {
            terms.thermal = th.step(t, dt, encoders.limbs, self.nut_travel(&encoders.limbs));
        }
        if let Some(bl) = &mut state.backlash {
            terms.backlash = bl.step(encoders.head);
            terms.transmission = bl.transmission(encoders.head);
        }
        let grown = terms.thermal.total();
        let unloaded: [f64; 3] =
            [0, 1, 2].map(|i| encoders.limbs[i] + terms.lost_motion[i] + grown[i]);
        let mut rods = unloaded;
        let mut head = [0, 1].map(|j| encoders.head[j] + terms.backlash[j] + terms.transmission[j]);
        let mut platform = self.robot.platform_from_lengths(rods, Some(guess))?;
        let mut pose = self.robot.tool_pose(&platform, &head);
        if let Some(c) = &self.nongeometric.compliance {
            let still = Vector3::zeros();
            let (axis, feed_dir, force) = contact.unwrap_or((&still, &still, 0.0));
            let push = if force > 0.0 { *axis } else { Vector3::z() };
            // The give depends on the limb directions, which depend on the pose it
            // produces: two fixed-point passes are exact far below a nanometre.
            let b = self.robot.geometry.base_points();
            let a = self.robot.geometry.platform_points();
            for _ in 0..2 {
                let frame = self.robot.platform_frame(&platform);
                let u = [0, 1, 2]
                    .map(|i| (frame * Point3::from(a[i]) - Point3::from(b[i])).normalize());
                terms.give = compliance::limb_give(c, &u, &push, force);
                let give = terms.give.total();
                rods = [0, 1, 2].map(|i| unloaded[i] + give[i]);
                platform = self.robot.platform_from_lengths(rods, Some(platform))?;
            }
            // The gears wind up under the torque of the glass and the head's weight.
            let tool_axis = self.robot.tool_pose(&platform, &head).rotation * Vector3::z();
            let pad = Point3::from(pose.translation.vector);
            let load = ToolLoad::new(c, pad, &tool_axis, feed_dir, force);
            let axes = self.robot.joint_axes(&platform, &head);
            terms.windup = compliance::drive_windup(c, &axes, &load);
            head = [0, 1].map(|j| head[j] + terms.windup[j]);
            pose = self.robot.tool_pose(&platform, &head);
            if force > 0.0 {
                let d = compliance::tip_deflection(c, axis, feed_dir, force);
                terms.tip = d;
                pose = Isometry3::from_parts(
                    Translation3::from(pose.translation.vector + d.translation.vector),
                    d.rotation * pose.rotation,
                );
            }
        }
        Ok(Actual {
            platform,
            joints: Joints { limbs: rods, head },
            pose,
            terms,
        })
    }
}

/// The true pad pose in the frame where the part was located: the part is measured with
/// the tracker and handed to the controller through its registration, so the base frame
/// that matters is the controller's estimate, not the twin's true one. (Calibration
/// cannot tell a shift of the whole robot from one of the tracker's registration; scored
/// in the twin's true base frame, that unobservable shift would count as error, several
/// hundred µm on the demo machine.)
pub fn located(machine: &Machine, controller: &Robot, pose: &Isometry3<f64>) -> Isometry3<f64> {
    controller.tracker_from_base().inverse() * machine.robot.tracker_from_base() * pose
}
