//! The machine's sensors (the 14 graph nodes of Table II and the polishing force) and the
//! laser tracker: what each one reads, in which unit, how noisy and how often.

/// Channel names in recording order: the 14 nodes of Table II, then the force.
pub const CHANNELS: [&str; 15] = [
    "E1", "E2", "E3", "E4", "E5", "E6", "Q1", "Q2", "Q3", "Q4", "Q5", "phiX", "phiY", "phiZ", "F",
];

/// What each channel measures and its unit, for reports and the README.
pub const CHANNEL_UNITS: [(&str, &str); 15] = [
    ("E1", "µm: wire-sensor minus encoder length of UPS limb 1"),
    ("E2", "µm: same, limb 2"),
    ("E3", "µm: same, limb 3"),
    (
        "E4",
        "µm: measured minus commanded extension of the UP limb",
    ),
    (
        "E5",
        "mdeg: load-side minus motor-side angle of serial joint 1",
    ),
    ("E6", "mdeg: same, serial joint 2"),
    ("Q1", "mm: encoder length of UPS limb 1"),
    ("Q2", "mm: encoder length of UPS limb 2"),
    ("Q3", "mm: encoder length of UPS limb 3"),
    ("Q4", "deg: motor angle of serial joint 1 (multi-turn)"),
    ("Q5", "deg: motor angle of serial joint 2"),
    (
        "phiX",
        "deg: tilt sensor on the CCOS head, roll of the tool frame",
    ),
    ("phiY", "deg: pitch of the tool frame"),
    ("phiZ", "deg: yaw of the tool frame"),
    ("F", "N: pneumatic polishing force"),
];

/// One standard deviation of each sensor's noise, in the channel's unit.
#[derive(Clone, Copy, Debug)]
pub struct SensorNoise {
    /// E1–E4, µm.
    pub length_error: f64,
    /// E5–E6, mdeg.
    pub angle_error: f64,
    /// Q1–Q3, mm (encoder quantisation).
    pub encoder_length: f64,
    /// Q4–Q5, deg.
    pub encoder_angle: f64,
    /// φX–φZ, deg.
    pub tilt: f64,
    /// F, N.
    pub force: f64,
    /// Laser tracker position per axis, mm.
    pub tracker_position: f64,
    /// Laser tracker attitude per axis, rad.
    pub tracker_attitude: f64,
}

impl Default for SensorNoise {
    fn default() -> SensorNoise {
        SensorNoise {
            length_error: 1.0,
            angle_error: 0.5,
            encoder_length: 1e-4,
            encoder_angle: 1e-4,
            tilt: 2e-3,
            force: 0.5,
            tracker_position: 7e-3,
            tracker_attitude: 1.5e-3_f64.to_radians(),
        }
    }
}

/// Every how many control ticks each sensor delivers a sample (1 = every tick).
#[derive(Clone, Copy, Debug)]
pub struct SensorRates {
    /// Per channel, in [`CHANNELS`] order.
    pub channel_every: [u32; 15],
    pub tracker_every: u32,
}

impl Default for SensorRates {
    /// At 50 Hz control: encoders and wire sensors 50 Hz, the tilt sensor 10 Hz, the force
    /// sensor 25 Hz, the laser tracker 10 Hz.
    fn default() -> SensorRates {
        let mut every = [1; 15];
        for e in &mut every[11..14] {
            *e = 5;
        }
        every[14] = 2;
        SensorRates {
            channel_every: every,
            tracker_every: 5,
        }
    }
}
