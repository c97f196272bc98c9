//! The gear trains of the two serial joints: direction-dependent play (backlash) on the
//! joint angle, and the gear's kinematic transmission error, periodic twice per motor
//! revolution (4–8 mdeg peak to peak in the default machine, a precision strain-wave gear).

use super::play::Play;

/// The gear trains' parameters, one entry per serial joint (docs/twin.md "Lost motion and
/// backlash").
#[derive(Clone, Copy, Debug)]
pub struct BacklashParams {
    /// Total backlash of each joint, rad (0.005–0.02°).
    pub width: [f64; 2],
    /// Amplitude of each gear's transmission error, rad.
    pub transmission_error: [f64; 2],
    /// Phase of each gear's transmission error, rad.
    pub transmission_phase: [f64; 2],
    /// Gear ratio (motor turns per joint turn).
    pub ratio: f64,
}

/// State of the two gear trains: which side of its play each one rests on.
#[derive(Clone, Debug)]
pub struct Backlash {
    params: BacklashParams,
    play: [Play; 2],
}

impl Backlash {
    /// Gear trains with their play centred.
    pub fn new(params: BacklashParams) -> Backlash {
        Backlash {
            params,
            play: Default::default(),
        }
    }

    /// Feeds the motor-side joint angles; returns each joint's angle error from the play
    /// (rad).
    pub fn step(&mut self, motor: [f64; 2]) -> [f64; 2] {
        [0, 1].map(|j| self.play[j].step(motor[j], self.params.width[j]) - motor[j])
    }

    /// Each joint's transmission error (rad) at the motor-side joint angles `motor`.
    pub fn transmission(&self, motor: [f64; 2]) -> [f64; 2] {
        let p = &self.params;
        [0, 1].map(|j| {
            p.transmission_error[j] * (2.0 * p.ratio * motor[j] + p.transmission_phase[j]).sin()
        })
    }
}
