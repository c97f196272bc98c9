//! The machine's instruments (docs/twin.md "Sensors"): the 14 graph nodes of Table II,
//! the polishing force and the laser tracker. Each channel is modelled as the instrument
//! that would measure it on a real machine (what it spans, its resolution, noise, lag and
//! drift), never as a term of the truth model plus white noise.
//!
//! - E1–E3: a sealed linear scale beside each ball screw, from the screw's fixed bearing
//!   block to the nut carriage, minus the motor encoder's length. It sees lost motion,
//!   the screw's thermal growth and the stretch inside its span; not the strut tube's
//!   growth, the rest of the stretch or the joints' clearance. Its own errors: the glass
//!   scale expands with the housing, and its graduation has a long-wave pitch error.
//! - E4: the same kind of scale along the passive UP limb's slide, minus the extension
//!   the controller commanded.
//! - E5–E6: a load-side absolute encoder minus the motor encoder over the gear ratio: the
//!   backlash and the gear's wind-up, through both encoders' quanta and the load
//!   encoder's eccentricity.
//! - Q1–Q5: the motor encoders (the actual inputs), quantised.
//! - φX, φY: a two-axis inclinometer on the head: roll and pitch of its frame against
//!   gravity (it cannot see yaw), low-pass filtered, with a mounting offset, a temperature
//!   coefficient and a bias random walk.
//! - φZ: a fibre-optic gyro about the tool frame's yaw, integrated from the run's start
//!   (aligned to the commanded yaw there): angle random walk and a bias.
//! - F: the force from the pneumatic cylinder's pressure: the seal's friction and the
//!   valve's lag stand between it and the contact force.

use nalgebra::{Isometry3, UnitQuaternion};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::noise::gaussian;

/// Channel names in recording order: the 14 nodes of Table II, the force, then the
/// controller's planned motion ([`PLAN_CHANNELS`]).
pub const CHANNELS: [&str; 18] = [
    "E1", "E2", "E3", "E4", "E5", "E6", "Q1", "Q2", "Q3", "Q4", "Q5", "phiX", "phiY", "phiZ", "F",
    "planX", "planY", "planZ",
];

/// The instruments' channels: the first of [`CHANNELS`], each read by a sensor (the
/// rest are [`PLAN_CHANNELS`]).
pub const SENSOR_CHANNELS: usize = CHANNELS.len() - PLAN_CHANNELS.len();

/// What the controller plans, not what a sensor reads: the velocity of the path target
/// from this tick to the next (mm/s, base frame), known one tick ahead because the path
/// and its feed are the controller's own program. A look-ahead model's graph has them
/// as nodes (docs/model.md "Look-ahead"); nothing measured after a tick is in them.
pub const PLAN_CHANNELS: [&str; 3] = ["planX", "planY", "planZ"];

/// What each channel measures and its unit, for reports and the docs.
pub const CHANNEL_UNITS: [(&str, &str); 18] = [
    (
        "E1",
        "µm: linear scale (bearing block → nut) minus encoder length, UPS limb 1",
    ),
    ("E2", "µm: same, limb 2"),
    ("E3", "µm: same, limb 3"),
    (
        "E4",
        "µm: linear scale on the UP slide minus commanded extension",
    ),
    (
        "E5",
        "mdeg: load-side encoder minus motor encoder / ratio, serial joint 1",
    ),
    ("E6", "mdeg: same, serial joint 2"),
    ("Q1", "mm: motor encoder length of UPS limb 1"),
    ("Q2", "mm: motor encoder length of UPS limb 2"),
    ("Q3", "mm: motor encoder length of UPS limb 3"),
    (
        "Q4",
        "deg: motor encoder angle of serial joint 1 (multi-turn)",
    ),
    ("Q5", "deg: motor encoder angle of serial joint 2"),
    ("phiX", "deg: inclinometer roll of the head against gravity"),
    (
        "phiY",
        "deg: inclinometer pitch of the head against gravity",
    ),
    (
        "phiZ",
        "deg: fibre-optic gyro yaw of the head, integrated from the run's start",
    ),
    ("F", "N: polishing force from the cylinder pressure"),
    (
        "planX",
        "mm/s: planned velocity of the path target from this tick to the next, base x",
    ),
    ("planY", "mm/s: same, base y"),
    ("planZ", "mm/s: same, base z"),
];

/// The instruments' specifications (datasheet-class figures; their sources are in
/// docs/twin.md). Lengths in mm or µm and angles in deg or mdeg as named.
#[derive(Clone, Copy, Debug)]
pub struct SensorSpecs {
    /// Linear scales (E1–E4): amplitude of the long-wave pitch error, µm.
    pub scale_pitch_error: f64,
    /// Wavelength of the scales' pitch error, mm.
    pub scale_pitch_wavelength: f64,
    /// Scale expansion coefficient (glass), 1/K.
    pub scale_expansion: f64,
    /// Share of the screw's temperature rise that a scale's housing reaches.
    pub scale_housing_share: f64,
    /// Scale reading noise (vibration, interpolation), µm.
    pub scale_noise: f64,
    /// Load-side absolute encoders (E5–E6): quantum, mdeg.
    pub load_encoder_quantum: f64,
    /// Amplitude of a load encoder's eccentricity error, once per joint turn, mdeg.
    pub load_encoder_eccentricity: f64,
    /// Motor encoders: quantum of a limb's length, mm.
    pub motor_length_quantum: f64,
    /// Motor encoders: quantum of a joint angle at the load (motor counts over the gear
    /// ratio), deg.
    pub motor_angle_quantum: f64,
    /// Inclinometer (φX, φY): time constant of its first-order filter, s.
    pub tilt_lag: f64,
    /// Inclinometer output noise, mdeg.
    pub tilt_noise: f64,
    /// Standard deviation of the inclinometer's mounting offset, mdeg.
    pub tilt_mounting: f64,
    /// Inclinometer temperature coefficient on the ambient offset, mdeg/K.
    pub tilt_tempco: f64,
    /// Inclinometer bias random walk, mdeg/√s (from 0 at each run's start).
    pub tilt_bias_walk: f64,
    /// Gyro (φZ): angle random walk, deg/√s.
    pub gyro_angle_walk: f64,
    /// Standard deviation of the gyro bias drawn per run, deg/s.
    pub gyro_bias: f64,
    /// Gyro output noise, mdeg.
    pub gyro_noise: f64,
    /// Force from pressure (F): standard deviation of the seal friction, N.
    pub force_seal_friction: f64,
    /// Correlation time of the seal friction (Ornstein–Uhlenbeck), s.
    pub force_seal_time: f64,
    /// Time constant of the valve's first-order lag, s.
    pub force_lag: f64,
    /// Force output noise, N.
    pub force_noise: f64,
    /// Laser tracker position per axis, mm.
    pub tracker_position: f64,
    /// Laser tracker attitude per axis, rad.
    pub tracker_attitude: f64,
}

impl Default for SensorSpecs {
    fn default() -> SensorSpecs {
        SensorSpecs {
            scale_pitch_error: 2.0,
            scale_pitch_wavelength: 170.0,
            scale_expansion: 8.0e-6,
            scale_housing_share: 0.3,
            scale_noise: 0.3,
            load_encoder_quantum: 360e3 / (1u64 << 17) as f64,
            load_encoder_eccentricity: 2.5,
            motor_length_quantum: 5.0 / (1u64 << 17) as f64,
            motor_angle_quantum: 360.0 / (1u64 << 17) as f64 / 100.0,
            tilt_lag: 0.16,
            tilt_noise: 0.5,
            tilt_mounting: 50.0,
            tilt_tempco: 1.0,
            tilt_bias_walk: 0.05,
            gyro_angle_walk: 0.012 / 60.0,
            gyro_bias: 0.05 / 3600.0,
            gyro_noise: 0.2,
            force_seal_friction: 3.0,
            force_seal_time: 2.0,
            force_lag: 0.05,
            force_noise: 0.3,
            tracker_position: 7e-3,
            tracker_attitude: 1.5e-3_f64.to_radians(),
        }
    }
}

/// What was fixed when the instruments were mounted on one machine (drawn with it): the
/// phases of the scales' pitch errors, the load encoders' eccentricity phases and the
/// inclinometer's mounting offsets (mdeg).
#[derive(Clone, Copy, Debug, Default)]
pub struct Installation {
    /// Phase of each linear scale's pitch error (E1–E4), rad.
    pub scale_phase: [f64; 4],
    /// Phase of each load encoder's eccentricity (E5–E6), rad.
    pub eccentricity_phase: [f64; 2],
    /// Inclinometer mounting offsets (φX, φY), mdeg.
    pub tilt_offset: [f64; 2],
}

impl Installation {
    /// The mounting of the machine with seed `seed` (its own random stream, so it does
    /// not shift the other draws of that seed).
    pub fn draw(seed: u64, specs: &SensorSpecs) -> Installation {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7365_6e73_6f72);
        let tau = std::f64::consts::TAU;
        Installation {
            scale_phase: [0; 4].map(|_| rng.random_range(0.0..tau)),
            eccentricity_phase: [0; 2].map(|_| rng.random_range(0.0..tau)),
            tilt_offset: [0; 2].map(|_| gaussian(&mut rng, specs.tilt_mounting)),
        }
    }
}

/// What the instruments look at in one tick: the true state of the machine, split where
/// an instrument sees only part of it.
#[derive(Clone, Copy, Debug)]
pub struct Scene {
    /// Control period, s.
    pub dt: f64,
    /// Motor encoder lengths of the UPS limbs, mm: the commanded inputs.
    pub encoder_lengths: [f64; 3],
    /// Motor encoder angles of the serial joints (at the load), rad: the commanded inputs.
    pub encoder_angles: [f64; 2],
    /// True nut position minus the encoder's, per limb, mm: what a scale from the bearing
    /// block to the nut spans.
    pub nut_error: [f64; 3],
    /// Distance of each nut from its bearing, mm.
    pub nut_travel: [f64; 3],
    /// Temperature rise of each screw above ambient, K.
    pub screw_rise: [f64; 3],
    /// Ambient temperature offset, K.
    pub ambient: f64,
    /// True extension of the UP limb, mm.
    pub extension: f64,
    /// Extension of the UP limb that the controller commanded, mm.
    pub commanded_extension: f64,
    /// True load-side joint angles, rad.
    pub joint_angles: [f64; 2],
    /// True pad pose, base frame.
    pub pose: Isometry3<f64>,
    /// The pad pose the controller commanded (the gyro is aligned to its yaw at the run's
    /// start).
    pub commanded: Isometry3<f64>,
    /// Contact force, N.
    pub force: f64,
}

fn quantise(v: f64, q: f64) -> f64 {
    (v / q).round() * q
}

/// The instruments' dynamic state over one run: filters, integrators, random walks.
#[derive(Clone, Debug)]
pub struct Instruments {
    specs: SensorSpecs,
    install: Installation,
    tilt: Option<[f64; 2]>,
    tilt_bias: [f64; 2],
    gyro: Option<(f64, f64)>,
    gyro_bias: f64,
    seal: f64,
    force: Option<f64>,
}

impl Instruments {
    /// Switched on at the start of a run; `rng` draws this run's gyro bias.
    pub fn new(specs: SensorSpecs, install: Installation, rng: &mut ChaCha8Rng) -> Instruments {
        let gyro_bias = gaussian(rng, specs.gyro_bias);
        Instruments {
            specs,
            install,
            tilt: None,
            tilt_bias: [0.0; 2],
            gyro: None,
            gyro_bias,
            seal: 0.0,
            force: None,
        }
    }

    /// Every sensor channel's reading for one tick, in [`CHANNELS`] order (the first
    /// [`SENSOR_CHANNELS`]). Every random draw is made each tick, so the sensors' rates
    /// never shift the random stream.
    pub fn read(&mut self, s: &Scene, rng: &mut ChaCha8Rng) -> [f64; SENSOR_CHANNELS] {
        let p = self.specs;
        let tau = std::f64::consts::TAU;
        // Linear scales: a glass graduation on the housing reads the nut's travel short
        // by its own expansion, plus its pitch error along the travel.
        let scale = |travel: f64, phase: f64, rise: f64, rng: &mut ChaCha8Rng| {
            let expansion =
                -p.scale_expansion * travel * (s.ambient + p.scale_housing_share * rise);
            let pitch = p.scale_pitch_error
                * 1e-3
                * (tau * travel / p.scale_pitch_wavelength + phase).sin();
            1e3 * (expansion + pitch) + gaussian(rng, p.scale_noise)
        };
        let mut v = [0.0; 15];
        for (i, e) in v.iter_mut().take(3).enumerate() {
            let reading = scale(
                s.nut_travel[i],
                self.install.scale_phase[i],
                s.screw_rise[i],
                rng,
            );
            *e = quantise(1e3 * s.nut_error[i] + reading, 0.05);
        }
        let up = scale(s.extension, self.install.scale_phase[3], 0.0, rng);
        v[3] = quantise(1e3 * (s.extension - s.commanded_extension) + up, 0.05);
        for j in 0..2 {
            let load = s.joint_angles[j].to_degrees() * 1e3;
            let ecc = p.load_encoder_eccentricity
                * (s.joint_angles[j] + self.install.eccentricity_phase[j]).sin();
            let motor = quantise(s.encoder_angles[j].to_degrees(), p.motor_angle_quantum) * 1e3;
            v[4 + j] = quantise(load + ecc, p.load_encoder_quantum) - motor;
        }
        for i in 0..3 {
            v[6 + i] = quantise(s.encoder_lengths[i], p.motor_length_quantum);
        }
        for j in 0..2 {
            v[9 + j] = quantise(s.encoder_angles[j].to_degrees(), p.motor_angle_quantum);
        }
        // Inclinometer: roll and pitch of the head frame against gravity (base z is
        // down), offset by its mounting and temperature, low-passed, then noise.
        let (roll, pitch, yaw) = s.pose.rotation.euler_angles();
        let a = (-s.dt / p.tilt_lag).exp();
        let walk = p.tilt_bias_walk * s.dt.sqrt();
        let raw = [roll, pitch].map(|x| x.to_degrees() * 1e3);
        let mut tilt = [0.0; 2];
        for k in 0..2 {
            self.tilt_bias[k] += gaussian(rng, walk);
            let seen = raw[k]
                + self.install.tilt_offset[k]
                + p.tilt_tempco * s.ambient
                + self.tilt_bias[k];
            let prev = self.tilt.map_or(seen, |f| f[k]);
            tilt[k] = seen + (prev - seen) * a;
        }
        self.tilt = Some(tilt);
        v[11] = (tilt[0] + gaussian(rng, p.tilt_noise)) * 1e-3;
        v[12] = (tilt[1] + gaussian(rng, p.tilt_noise)) * 1e-3;
        // Gyro: integrates the true yaw rate plus its bias and angle random walk from the
        // run's start, where it was aligned to the commanded yaw (so it never wraps).
        let yaw = yaw.to_degrees();
        let angle = match self.gyro {
            None => {
                let (_, _, commanded) = s.commanded.rotation.euler_angles();
                commanded.to_degrees()
            }
            Some((last, angle)) => {
                let turn = (yaw - last + 180.0).rem_euclid(360.0) - 180.0;
                let walk = gaussian(rng, p.gyro_angle_walk * s.dt.sqrt());
                angle + turn + self.gyro_bias * s.dt + walk
            }
        };
        self.gyro = Some((yaw, angle));
        v[13] = angle + gaussian(rng, p.gyro_noise) * 1e-3;
        // Force from pressure: the seal's friction wanders (Ornstein–Uhlenbeck), the valve
        // lags.
        let b = (-s.dt / p.force_seal_time).exp();
        self.seal = self.seal * b + gaussian(rng, p.force_seal_friction * (1.0 - b * b).sqrt());
        let pressure = s.force + self.seal;
        let c = (-s.dt / p.force_lag).exp();
        let f = pressure + (self.force.unwrap_or(pressure) - pressure) * c;
        self.force = Some(f);
        v[14] = f + gaussian(rng, p.force_noise);
        v
    }
}

/// `pose` with tracker noise of the given standard deviations (mm, rad) per axis.
pub fn tracker_noise(
    rng: &mut ChaCha8Rng,
    pose: &Isometry3<f64>,
    position_sd: f64,
    attitude_sd: f64,
) -> Isometry3<f64> {
    let dp = nalgebra::Vector3::from_fn(|_, _| gaussian(rng, position_sd));
    let dr = nalgebra::Vector3::from_fn(|_, _| gaussian(rng, attitude_sd));
    Isometry3::from_parts(
        nalgebra::Translation3::from(pose.translation.vector + dp),
        UnitQuaternion::from_scaled_axis(dr) * pose.rotation,
    )
}

/// Every how many control ticks each sensor delivers a sample (1 = every tick).
#[derive(Clone, Copy, Debug)]
pub struct SensorRates {
    /// Per sensor channel, in [`CHANNELS`] order (the planned motion is there every tick).
    pub channel_every: [u32; SENSOR_CHANNELS],
    /// For the laser tracker.
    pub tracker_every: u32,
}

impl Default for SensorRates {
    /// At 50 Hz control: encoders and scales 50 Hz, the inclinometer and gyro 10 Hz, the
    /// force 25 Hz, the laser tracker 10 Hz.
    fn default() -> SensorRates {
        let mut every = [1; SENSOR_CHANNELS];
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
