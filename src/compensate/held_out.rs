//! Held-out runs in the twin: one polishing run at its held-out placement, the session it
//! belongs to (a machine warmed up first, idle between runs), and a single run prepared
//! from files for `compensate` and `budget`.

use std::path::PathBuf;

use super::online::{self, Feedback};
use crate::calibrate::file;
use crate::error::{ensure, Result};
use crate::robot::{Geometry, Robot};
use crate::twin::{
    draw_machine, Conditions, Machine, MachineState, PathKind, PathParams, SimConfig,
};

/// A held-out polishing run to compensate: its path and placement on the part, length,
/// seed, and the machine's state when it starts (warm from the session's earlier runs).
#[derive(Clone, Debug)]
pub struct HeldOut {
    /// The path.
    pub path: PathKind,
    /// Its placement on the part (usually [`PathParams::held_out`]).
    pub params: PathParams,
    /// Length of the run, s.
    pub seconds: f64,
    /// Seed of the run.
    pub seed: u64,
    /// The machine's state at the run's start.
    pub start: MachineState,
    /// The session's feed and force (its day is in `start`).
    pub conditions: Conditions,
}

impl HeldOut {
    /// The run's simulation settings.
    pub fn config(&self) -> SimConfig {
        let mut c = SimConfig::new(self.path, self.seconds, self.seed);
        c.path_params = self.params;
        self.conditions.apply(&mut c);
        c
    }

    /// The run on `machine` from its start under `controller`, corrected by `feedback`
    /// ([`online::run`]); `on_tick` sees the ticks done.
    pub fn run(
        &self,
        machine: &Machine,
        controller: &Robot,
        feedback: Feedback<'_>,
        on_tick: impl FnMut(usize),
    ) -> Result<online::RunResult> {
        online::run(
            machine,
            controller,
            self.config(),
            self.start.clone(),
            feedback,
            on_tick,
        )
    }
}

/// Seconds the machine stands idle between two runs of a session (the operator sets up
/// the next program).
pub const IDLE_BETWEEN_RUNS: f64 = 30.0;

/// A cold machine warmed by `seconds` of polishing (0: left cold) under `controller`,
/// then idle for [`IDLE_BETWEEN_RUNS`]: the start of a held-out session on the
/// calibration day at the default feed and force. The warm-up walks the raster turned a
/// quarter turn, which no scored run retraces.
pub fn warm_up(
    machine: &Machine,
    controller: &Robot,
    seconds: f64,
    seed: u64,
) -> Result<MachineState> {
    warm_up_on(machine, controller, seconds, seed, &Conditions::NOMINAL)
}

/// [`warm_up`] on the day of `conditions`, at its feed and force.
pub fn warm_up_on(
    machine: &Machine,
    controller: &Robot,
    seconds: f64,
    seed: u64,
    conditions: &Conditions,
) -> Result<MachineState> {
    let mut state = machine.cold_on(conditions.day);
    if seconds > 0.0 {
        let mut config = SimConfig::new(PathKind::Grid, seconds, seed);
        config.path_params.rotation_deg = 90.0;
        conditions.apply(&mut config);
        state = online::run(machine, controller, config, state, Feedback::None, |_| {})?.end;
        state.idle(IDLE_BETWEEN_RUNS);
    }
    Ok(state)
}

/// One held-out run of a session, described by its files and numbers.
#[derive(Clone, Debug)]
pub struct RunSpec {
    /// Calibration file: the controller's model.
    pub calibration: PathBuf,
    /// The path, at its held-out placement (never retracing a training recording).
    pub path: PathKind,
    /// Length, minutes (> 0).
    pub minutes: f64,
    /// Minutes of polishing that warm the machine up first (0: cold).
    pub warm_up_minutes: f64,
    /// Seed of the run.
    pub seed: u64,
    /// Seed of the machine (the twin's default machine is 1).
    pub machine_seed: u64,
    /// Robot geometry asset (the embedded one when `None`).
    pub robot: Option<PathBuf>,
    /// Where the path lies on the part: its held-out placement
    /// ([`PathParams::held_out`]) when `None`. Nothing checks that another placement
    /// keeps clear of the training recordings.
    pub placement: Option<PathParams>,
}

/// A held-out run ready to go: the machine, both controllers, and the run itself
/// (starting from the warmed-up machine).
pub struct Prepared {
    /// The twin's hidden-truth machine.
    pub machine: Machine,
    /// The nominal controller (no calibration).
    pub nominal: Robot,
    /// The controller with the calibration file's errors.
    pub calibrated: Robot,
    /// The run, starting from the warmed-up machine.
    pub run: HeldOut,
}

impl RunSpec {
    /// Draws the machine, loads the controllers and warms the machine up.
    pub fn prepare(&self) -> Result<Prepared> {
        let geometry = Geometry::load_or_default(self.robot.as_deref())?;
        let machine = draw_machine(geometry.clone(), self.machine_seed);
        let nominal = Robot::nominal(geometry.clone());
        let calibrated = file::calibrated_robot(geometry, &self.calibration)?;
        ensure(self.minutes.is_finite() && self.minutes > 0.0, || {
            format!("a run must last a positive time, got {} min", self.minutes)
        })?;
        let start = warm_up(
            &machine,
            &calibrated,
            self.warm_up_minutes * 60.0,
            self.seed ^ 0x5741_524d,
        )
        .map_err(|e| e.context("warm-up run"))?;
        let run = HeldOut {
            path: self.path,
            params: self
                .placement
                .unwrap_or_else(|| PathParams::held_out(self.path)),
            seconds: self.minutes * 60.0,
            seed: self.seed,
            start,
            conditions: Conditions::NOMINAL,
        };
        Ok(Prepared {
            machine,
            nominal,
            calibrated,
            run,
        })
    }
}
