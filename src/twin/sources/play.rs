//! The play (backlash) operator: the driven side follows the drive only after the slack
//! of `width` is taken up, so its lag depends on the direction of the last motion.

/// Play operator with total slack `width` (same unit as the input).
#[derive(Clone, Debug)]
pub struct Play {
    output: Option<f64>,
}

impl Play {
    /// A play operator that has seen no input yet.
    pub fn new() -> Play {
        Play { output: None }
    }

    /// Feeds the drive position; returns the driven position. The first call starts with
    /// the slack centred.
    pub fn step(&mut self, input: f64, width: f64) -> f64 {
        let h = 0.5 * width;
        let y = match self.output {
            None => input,
            Some(prev) => prev.clamp(input - h, input + h),
        };
        self.output = Some(y);
        y
    }
}

impl Default for Play {
    fn default() -> Play {
        Play::new()
    }
}
