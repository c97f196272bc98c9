//! The twin's non-geometric error sources, one small piece each; every one can be
//! switched off (a `None` in [`NonGeometric`]).

pub mod backlash;
pub mod compliance;
pub mod lost_motion;
pub mod play;
pub mod thermal;

pub use backlash::{Backlash, BacklashParams};
pub use compliance::{ComplianceParams, LimbGive, ToolLoad};
pub use lost_motion::{LostMotion, LostMotionParams};
pub use play::Play;
pub use thermal::{Day, Thermal, ThermalGrowth, ThermalParams};

/// The default machine's [`NonGeometric::screw_origin`], mm: 150 mm of screw below the
/// shortest stroke of assets/robot.toml (520 mm).
pub const SCREW_ORIGIN: f64 = 370.0;

/// Which non-geometric sources act, with their parameters.
#[derive(Clone, Copy, Debug)]
pub struct NonGeometric {
    /// Ball-screw lost motion of the UPS limbs.
    pub lost_motion: Option<LostMotionParams>,
    /// Gear backlash and transmission error of the serial joints.
    pub backlash: Option<BacklashParams>,
    /// Thermal growth of the UPS limbs.
    pub thermal: Option<ThermalParams>,
    /// Limb give, gear wind-up and tool-tip deflection under load.
    pub compliance: Option<ComplianceParams>,
    /// Limb length (mm) at which a limb's nut sits at its screw's fixed bearing: the nut
    /// is `length − screw_origin` mm from the bearing (where the screw's thermal growth
    /// and a length sensor's span start).
    pub screw_origin: f64,
}

impl NonGeometric {
    /// No non-geometric error at all (a purely geometric machine).
    pub fn none() -> NonGeometric {
        NonGeometric {
            lost_motion: None,
            backlash: None,
            thermal: None,
            compliance: None,
            screw_origin: SCREW_ORIGIN,
        }
    }
}
