//! Thermal elongation of the UPS limbs (docs/twin.md "Thermal"). Friction in each ball
//! screw heats it in proportion to its speed, first order towards that equilibrium with a
//! time constant of minutes. Two parts of the limb grow:
//!
//! - the **screw** between its fixed bearing and the nut: the thread pitch stretches by
//!   α·ΔT, so the nut sits α·ΔT·x further out, x being its distance from the bearing
//!   (which changes with the stroke);
//! - the **strut tube** and joint housings beyond the nut: warmed by the screw through
//!   the nut and the bearing, slower (a second first-order node driven by the screw's
//!   rise) and to a fraction of it.
//!
//! A slow ambient drift acts on both. The limb's length sensor spans only the first part.

/// The limbs' thermal parameters (docs/twin.md "Thermal").
#[derive(Clone, Copy, Debug)]
pub struct ThermalParams {
    /// Equilibrium temperature rise of the screw per mm/s of screw speed, K.
    pub gain_per_speed: [f64; 3],
    /// Thermal time constant of the screw, s.
    pub time_constant: f64,
    /// Expansion coefficient of screw and tube, 1/K (steel: 11.5e-6).
    pub expansion: f64,
    /// Length of the strut tube and joint housings outside the screw's span, mm.
    pub tube_length: f64,
    /// Equilibrium rise of the tube as a fraction of the screw's.
    pub tube_share: f64,
    /// Thermal time constant of the tube, s.
    pub tube_time_constant: f64,
    /// Amplitude of the slow ambient sinusoid, K.
    pub ambient_amplitude: f64,
    /// Period of the ambient sinusoid, s.
    pub ambient_period: f64,
    /// Phase of the ambient sinusoid at session time 0, rad.
    pub ambient_phase: f64,
}

/// A limb's thermal elongation split by where it happens, mm.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ThermalGrowth {
    /// Screw between bearing and nut (inside the length sensor's span).
    pub screw: [f64; 3],
    /// Strut tube and housings beyond the nut (outside it).
    pub tube: [f64; 3],
}

impl ThermalGrowth {
    /// Each limb's whole elongation (screw plus tube), mm.
    pub fn total(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| self.screw[i] + self.tube[i])
    }
}

/// The shop's ambient on the day of a session (docs/twin.md "Days"): how far its mean
/// temperature sits from the calibration day's, and where in its slow cycle the session
/// starts. [`Day::CALIBRATION`] (both zero) is the day the machine was calibrated on.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Day {
    /// Mean ambient temperature of the day minus the calibration day's, K.
    pub ambient_offset_k: f64,
    /// Phase of the ambient cycle at the session's start, added to the machine's, rad.
    pub ambient_phase_shift: f64,
}

impl Day {
    /// The calibration day: no offset, the machine's own phase.
    pub const CALIBRATION: Day = Day {
        ambient_offset_k: 0.0,
        ambient_phase_shift: 0.0,
    };
}

/// The temperatures of the three limbs: they carry over from one run to the next of a
/// session (a warm machine), see [`crate::twin::MachineState`].
#[derive(Clone, Debug)]
pub struct Thermal {
    params: ThermalParams,
    day: Day,
    rise: [f64; 3],
    tube_rise: [f64; 3],
    last: Option<[f64; 3]>,
}

impl Thermal {
    /// Cold limbs on the calibration day: no rise above ambient, no last reading.
    pub fn new(params: ThermalParams) -> Thermal {
        Thermal::on(params, Day::CALIBRATION)
    }

    /// Cold limbs on `day`: the whole machine sits at that day's ambient.
    pub fn on(params: ThermalParams, day: Day) -> Thermal {
        Thermal {
            params,
            day,
            rise: [0.0; 3],
            tube_rise: [0.0; 3],
            last: None,
        }
    }

    /// Temperature rise of each screw above ambient, K.
    pub fn rise(&self) -> [f64; 3] {
        self.rise
    }

    /// Temperature rise of each strut tube above ambient, K.
    pub fn tube_rise(&self) -> [f64; 3] {
        self.tube_rise
    }

    /// Ambient temperature offset from the calibration day's mean at session time `t`, K:
    /// the day's offset plus the slow cycle.
    pub fn ambient(&self, t: f64) -> f64 {
        let p = &self.params;
        let d = &self.day;
        let phase = p.ambient_phase + d.ambient_phase_shift;
        d.ambient_offset_k
            + p.ambient_amplitude * (std::f64::consts::TAU * t / p.ambient_period + phase).sin()
    }

    /// Forgets the last encoder reading (the machine was moved while nobody watched, e.g.
    /// between runs): the next step sees no speed.
    pub fn lose_track(&mut self) {
        self.last = None;
    }

    /// Lets `seconds` pass at rest: the screws and tubes cool
    /// towards ambient, and the next step sees no speed (the move to wherever the next
    /// run starts is not a polishing stroke).
    pub fn idle(&mut self, seconds: f64) {
        let steps = seconds.ceil().max(1.0) as usize;
        let dt = seconds / steps as f64;
        let p = self.params;
        for _ in 0..steps {
            let decay = (-dt / p.time_constant).exp();
            let tube_decay = (-dt / p.tube_time_constant).exp();
            for i in 0..3 {
                self.rise[i] *= decay;
                let tube_target = p.tube_share * self.rise[i];
                self.tube_rise[i] = tube_target + (self.tube_rise[i] - tube_target) * tube_decay;
            }
        }
        self.last = None;
    }

    /// Advances by `dt` seconds with the new encoder lengths and each nut's distance from
    /// its bearing (mm); returns each limb's thermal elongation at time `t`, split into
    /// the screw and the tube part.
    pub fn step(
        &mut self,
        t: f64,
        dt: f64,
        encoder: [f64; 3],
        nut_travel: [f64; 3],
    ) -> ThermalGrowth {
        let p = self.params;
        let speed = match self.last {
            Some(last) => [0, 1, 2].map(|i| (encoder[i] - last[i]).abs() / dt),
            None => [0.0; 3],
        };
        self.last = Some(encoder);
        // Exact discretisation of dT/dt = (g·|v| − T)/τ over one step for the screw; the
        // tube relaxes towards share·T_screw (the screw's new value held over the step).
        let decay = (-dt / p.time_constant).exp();
        let tube_decay = (-dt / p.tube_time_constant).exp();
        for (i, v) in speed.into_iter().enumerate() {
            let target = p.gain_per_speed[i] * v;
            self.rise[i] = target + (self.rise[i] - target) * decay;
            let tube_target = p.tube_share * self.rise[i];
            self.tube_rise[i] = tube_target + (self.tube_rise[i] - tube_target) * tube_decay;
        }
        let ambient = self.ambient(t);
        ThermalGrowth {
            screw: [0, 1, 2].map(|i| p.expansion * nut_travel[i] * (self.rise[i] + ambient)),
            tube: [0, 1, 2].map(|i| p.expansion * p.tube_length * (self.tube_rise[i] + ambient)),
        }
    }
}
