//! The twin's non-geometric error sources, one small piece each; every one can be
//! switched off (a `None` in [`NonGeometric`]).

pub mod backlash;
pub mod compliance;
pub mod lost_motion;
pub mod play;
pub mod thermal;

pub use backlash::{Backlash, BacklashParams};
pub use compliance::ComplianceParams;
pub use lost_motion::{LostMotion, LostMotionParams};
pub use play::Play;
pub use thermal::{Thermal, ThermalParams};

/// Which non-geometric sources act, with their parameters.
#[derive(Clone, Copy, Debug)]
pub struct NonGeometric {
    pub lost_motion: Option<LostMotionParams>,
    pub backlash: Option<BacklashParams>,
    pub thermal: Option<ThermalParams>,
    pub compliance: Option<ComplianceParams>,
}

impl NonGeometric {
    /// No non-geometric error at all (a purely geometric machine).
    pub fn none() -> NonGeometric {
        NonGeometric {
            lost_motion: None,
            backlash: None,
            thermal: None,
            compliance: None,
        }
    }
}
