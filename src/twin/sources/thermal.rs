//! Thermal elongation of the UPS limbs: friction in each ball screw heats it in
//! proportion to its speed, first-order towards that equilibrium with a time constant of
//! minutes; the screw lengthens by α·L·ΔT. A slow ambient drift acts on all three.

#[derive(Clone, Copy, Debug)]
pub struct ThermalParams {
    /// Equilibrium temperature rise per mm/s of screw speed, K.
    pub gain_per_speed: [f64; 3],
    /// Thermal time constant, s.
    pub time_constant: f64,
    /// Expansion coefficient of the screw, 1/K (steel: 11.5e-6).
    pub expansion: f64,
    /// Heated length of the screw, mm.
    pub length: f64,
    /// Ambient drift: amplitude (K) and period (s) of a slow sinusoid.
    pub ambient_amplitude: f64,
    pub ambient_period: f64,
    pub ambient_phase: f64,
}

#[derive(Clone, Debug)]
pub struct Thermal {
    params: ThermalParams,
    rise: [f64; 3],
    last: Option<[f64; 3]>,
}

impl Thermal {
    pub fn new(params: ThermalParams) -> Thermal {
        Thermal {
            params,
            rise: [0.0; 3],
            last: None,
        }
    }

    /// Temperature rise of each screw above ambient, K.
    pub fn rise(&self) -> [f64; 3] {
        self.rise
    }

    /// Advances by `dt` seconds with the new encoder lengths; returns each limb's thermal
    /// elongation (mm) at time `t`.
    pub fn step(&mut self, t: f64, dt: f64, encoder: [f64; 3]) -> [f64; 3] {
        let p = &self.params;
        let speed = match self.last {
            Some(last) => [0, 1, 2].map(|i| (encoder[i] - last[i]).abs() / dt),
            None => [0.0; 3],
        };
        self.last = Some(encoder);
        // Exact discretisation of dT/dt = (g·|v| − T)/τ over one step.
        let decay = (-dt / p.time_constant).exp();
        for ((rise, gain), v) in self.rise.iter_mut().zip(p.gain_per_speed).zip(speed) {
            let target = gain * v;
            *rise = target + (*rise - target) * decay;
        }
        let ambient = p.ambient_amplitude
            * (std::f64::consts::TAU * t / p.ambient_period + p.ambient_phase).sin();
        self.rise.map(|r| p.expansion * p.length * (r + ambient))
    }
}
