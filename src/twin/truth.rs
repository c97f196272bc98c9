//! The twin's hidden truth: a seeded draw of the geometric errors of one machine.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::robot::{ErrorParams, LIMB_VECTORS, N_PARAMS};

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
    /// Base-to-tracker registration: position mm, attitude rad.
    pub tracker_position: f64,
    pub tracker_attitude: f64,
}

impl Default for ErrorScales {
    fn default() -> ErrorScales {
        ErrorScales {
            position: 0.03,
            attitude: 4.0e-4,
            length: 0.05,
            mdh_angle: 1.0e-3,
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
    let mut normal = |sigma: f64| {
        // Box–Muller from two uniforms: exact and reproducible everywhere.
        let u1: f64 = rng.random_range(f64::EPSILON..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
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
