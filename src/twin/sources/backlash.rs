//! Gear backlash of the two serial joints: direction-dependent play on the joint angle.

use super::play::Play;

#[derive(Clone, Copy, Debug)]
pub struct BacklashParams {
    /// Total backlash of each joint, rad (0.005–0.02°).
    pub width: [f64; 2],
}

#[derive(Clone, Debug)]
pub struct Backlash {
    params: BacklashParams,
    play: [Play; 2],
}

impl Backlash {
    pub fn new(params: BacklashParams) -> Backlash {
        Backlash {
            params,
            play: Default::default(),
        }
    }

    /// Feeds the motor-side joint angles; returns the angle error of each joint (rad).
    pub fn step(&mut self, motor: [f64; 2]) -> [f64; 2] {
        [0, 1].map(|j| self.play[j].step(motor[j], self.params.width[j]) - motor[j])
    }
}
