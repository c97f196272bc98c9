//! The twin's hidden truth: a seeded draw of the geometric errors of one machine.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::machine::Machine;
use super::noise::gaussian;
use super::sensors::{Installation, SensorSpecs};
use super::sources::{
    BacklashParams, ComplianceParams, LostMotionParams, NonGeometric, ThermalParams, SCREW_ORIGIN,
};
use crate::robot::{ErrorParams, Geometry, Robot, LIMB_VECTORS, N_PARAMS};

/// Typical sizes (one standard deviation) of a machine's geometric errors.
#[derive(Clone, Copy, Debug)]
pub struct ErrorScales {
    /// Joint-centre and offset positions, mm.
    pub position: f64,
    /// Joint-frame attitudes, rad.
    pub attitude: f64,
    /// Limb zero offsets and shaft lengths, mm.
    pub length: f64,
    /// MDH angles Δα, Δθ, rad.
    pub mdh_angle: f64,
    /// MDH lengths Δa, Δd and the tool offset, mm.
    pub mdh_length: f64,
    /// Base-to-tracker registration position, mm.
    pub tracker_position: f64,
    /// Base-to-tracker registration attitude, rad.
    pub tracker_attitude: f64,
}

impl Default for ErrorScales {
    fn default() -> ErrorScales {
        ErrorScales {
            position: 0.03,
            attitude: 6.0e-4,
            length: 0.05,
            mdh_angle: 2.0e-3,
            mdh_length: 0.08,
            tracker_position: 0.1,
            tracker_attitude: 2.0e-4,
        }
    }
}

/// A seeded random machine: each parameter normal with the scale of its kind, in the
/// layout of [`ErrorParams`]. The same seed gives the same machine, bit for bit.
pub fn draw_errors(seed: u64, scales: &ErrorScales) -> ErrorParams {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut normal = |sigma: f64| gaussian(&mut rng, sigma);
    let mut values = Vec::with_capacity(N_PARAMS);
    for _ in 0..3 {
        for (name, _) in LIMB_VECTORS {
            let s = if name.starts_with("theta") {
                scales.attitude
            } else {
                scales.position
            };
            values.extend((0..3).map(|_| normal(s)));
        }
        values.push(normal(scales.length));
        values.push(normal(scales.length));
    }
    values.extend((0..3).map(|_| normal(scales.position)));
    values.extend((0..3).map(|_| normal(scales.attitude)));
    for _ in 0..2 {
        values.push(normal(scales.mdh_angle));
        values.push(normal(scales.mdh_length));
        values.push(normal(scales.mdh_angle));
        values.push(normal(scales.mdh_length));
    }
    values.extend((0..3).map(|_| normal(scales.mdh_length)));
    values.extend((0..3).map(|_| normal(scales.tracker_position)));
    values.extend((0..3).map(|_| normal(scales.tracker_attitude)));
    debug_assert_eq!(values.len(), N_PARAMS);
    ErrorParams { values }
}

/// A seeded draw of a machine's non-geometric sources, in the ranges of docs/twin.md.
pub fn draw_nongeometric(seed: u64) -> NonGeometric {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6e6f_6e67_656f);
    let mut between = |lo: f64, hi: f64| rng.random_range(lo..hi);
    NonGeometric {
        lost_motion: Some(LostMotionParams {
            width: [0; 3].map(|_| between(0.010, 0.030)),
            wear_per_m: 0.02,
        }),
        backlash: Some(BacklashParams {
            width: [0; 2].map(|_| between(0.005, 0.02).to_radians()),
            transmission_error: [0; 2].map(|_| between(0.002, 0.004).to_radians()),
            transmission_phase: [0; 2].map(|_| between(0.0, std::f64::consts::TAU)),
            ratio: 100.0,
        }),
        thermal: Some(ThermalParams {
            gain_per_speed: [0; 3].map(|_| between(1.0, 2.0)),
            time_constant: 180.0,
            expansion: 11.5e-6,
            tube_length: 350.0,
            tube_share: 0.4,
            tube_time_constant: 900.0,
            ambient_amplitude: 0.3,
            ambient_period: 3600.0,
            ambient_phase: between(0.0, std::f64::consts::TAU),
        }),
        compliance: Some(ComplianceParams {
            limb: 5e-5,
            screw_share: 0.5,
            joint_clearance: between(0.004, 0.012),
            clearance_load: 30.0,
            weight: 600.0,
            tip_axial: 3e-4,
            tip_lateral: 6e-4,
            head_rotation: 4.5e-4,
            head_lever: 0.07,
            head_weight: 200.0,
            friction: 0.3,
            drive_torsion: 4e-6,
        }),
        screw_origin: SCREW_ORIGIN,
    }
}

/// The twin's machine for `seed`: geometric errors, non-geometric sources and the
/// instruments' mounting, drawn with the default scales.
pub fn draw_machine(geometry: Geometry, seed: u64) -> Machine {
    Machine {
        robot: Robot::new(geometry, draw_errors(seed, &ErrorScales::default())),
        nongeometric: draw_nongeometric(seed),
        sensors: Installation::draw(seed, &SensorSpecs::default()),
    }
}
