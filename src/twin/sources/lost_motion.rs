//! Ball-screw lost motion of the UPS limbs: direction-dependent play that grows slowly
//! with the distance each screw has travelled (wear).

use super::play::Play;

/// The ball screws' lost-motion parameters (docs/twin.md "Lost motion and backlash").
#[derive(Clone, Copy, Debug)]
pub struct LostMotionParams {
    /// Total play of each new screw, mm (10–30 µm).
    pub width: [f64; 3],
    /// Relative growth of the play per metre travelled.
    pub wear_per_m: f64,
}

/// State of the three screws.
#[derive(Clone, Debug)]
pub struct LostMotion {
    params: LostMotionParams,
    play: [Play; 3],
    travelled: [f64; 3],
    last: Option<[f64; 3]>,
}

impl LostMotion {
    /// New screws (nothing travelled yet) with their play centred.
    pub fn new(params: LostMotionParams) -> LostMotion {
        LostMotion {
            params,
            play: Default::default(),
            travelled: [0.0; 3],
            last: None,
        }
    }

    /// Current play of each screw, mm.
    pub fn width(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| {
            self.params.width[i] * (1.0 + self.params.wear_per_m * self.travelled[i] * 1e-3)
        })
    }

    /// Feeds the encoder lengths; returns the rod-length error of each limb (mm).
    pub fn step(&mut self, encoder: [f64; 3]) -> [f64; 3] {
        if let Some(last) = self.last {
            for i in 0..3 {
                self.travelled[i] += (encoder[i] - last[i]).abs();
            }
        }
        self.last = Some(encoder);
        let width = self.width();
        [0, 1, 2].map(|i| self.play[i].step(encoder[i], width[i]) - encoder[i])
    }
}
