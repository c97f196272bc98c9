//! The geometric error parameters of Table I (plus the serial MDH, tool and tracker
//! errors), as one named flat vector: the state of the calibration and the hidden truth
//! of the twin.

use nalgebra::Vector3;

/// Parameters per UPS limb (Table I).
pub const LIMB_PARAMS: usize = 29;
/// All parameters: 3 limbs, platform (6), serial MDH (2 × 4), tool (3), tracker (6).
pub const N_PARAMS: usize = 3 * LIMB_PARAMS + 6 + 8 + 3 + 6;

const PLATFORM: usize = 3 * LIMB_PARAMS;
const SERIAL: usize = PLATFORM + 6;
const TOOL: usize = SERIAL + 8;
const TRACKER: usize = TOOL + 3;

/// Vector-valued limb parameters in layout order, each x, y, z (mm or rad).
pub const LIMB_VECTORS: [(&str, &str); 9] = [
    ("db", "position error of the base Hooke joint B_i"),
    ("theta_b", "attitude error of the base Hooke joint B_i"),
    ("dn", "position error of the link origin N_i"),
    ("theta_n", "attitude error of the link origin N_i"),
    ("dm", "position error of the joint-shaft origin M_i"),
    ("theta_m", "attitude error of the joint-shaft origin M_i"),
    ("da", "position error of the platform Hooke joint A_i"),
    ("theta_a", "attitude error of the platform Hooke joint A_i"),
    ("ds", "position error of the composite ball-hinge centre"),
];

/// Errors of one UPS limb, borrowed from the flat vector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LimbErrors {
    /// Position error Δb of the base Hooke joint B_i, mm, base frame.
    pub db: Vector3<f64>,
    /// Attitude error θ_B of the base Hooke joint B_i, rad (rotation vector).
    pub theta_b: Vector3<f64>,
    /// Position error Δn of the link origin N_i, mm.
    pub dn: Vector3<f64>,
    /// Attitude error θ_N of the link origin N_i, rad (rotation vector).
    pub theta_n: Vector3<f64>,
    /// Position error Δm of the joint-shaft origin M_i, mm.
    pub dm: Vector3<f64>,
    /// Attitude error θ_M of the joint-shaft origin M_i, rad (rotation vector).
    pub theta_m: Vector3<f64>,
    /// Position error Δa of the platform Hooke joint A_i, mm, platform frame.
    pub da: Vector3<f64>,
    /// Attitude error θ_A of the platform Hooke joint A_i, rad (rotation vector).
    pub theta_a: Vector3<f64>,
    /// Position error ΔS of the composite ball-hinge centre, mm.
    pub ds: Vector3<f64>,
    /// Length error of the composite ball-joint connection shaft (Δδ_i).
    pub d_shaft: f64,
    /// Rod length (zero offset) error of the drive (Δl_i).
    pub d_length: f64,
}

/// Errors of one MDH row: Δα (rad), Δa (mm), Δθ (rad), Δd (mm).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MdhErrors {
    /// Δα, rad.
    pub alpha: f64,
    /// Δa, mm.
    pub a: f64,
    /// Δθ, rad.
    pub theta: f64,
    /// Δd, mm.
    pub d: f64,
}

/// The flat error vector. `ErrorParams::zero()` is the nominal robot.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorParams {
    /// The [`N_PARAMS`] values in the order of [`ErrorParams::names`], mm or rad.
    pub values: Vec<f64>,
}

impl Default for ErrorParams {
    fn default() -> ErrorParams {
        ErrorParams::zero()
    }
}

fn v3(x: &[f64]) -> Vector3<f64> {
    Vector3::new(x[0], x[1], x[2])
}

impl ErrorParams {
    /// All errors zero: the nominal robot.
    ///
    /// ```
    /// use iastgcn::robot::{ErrorParams, N_PARAMS};
    ///
    /// let errors = ErrorParams::zero();
    /// assert_eq!(errors.values.len(), N_PARAMS);
    /// assert_eq!(ErrorParams::names()[errors.values.len() - 1], "tracker.theta.z");
    /// ```
    pub fn zero() -> ErrorParams {
        ErrorParams {
            values: vec![0.0; N_PARAMS],
        }
    }

    /// Names in layout order, e.g. `limb2.dm.y`, `platform.theta.x`, `serial1.alpha`.
    pub fn names() -> Vec<String> {
        let mut names = Vec::with_capacity(N_PARAMS);
        for limb in 1..=3 {
            for (v, _) in LIMB_VECTORS {
                for c in ["x", "y", "z"] {
                    names.push(format!("limb{limb}.{v}.{c}"));
                }
            }
            names.push(format!("limb{limb}.d_shaft"));
            names.push(format!("limb{limb}.d_length"));
        }
        for v in ["dr", "theta"] {
            for c in ["x", "y", "z"] {
                names.push(format!("platform.{v}.{c}"));
            }
        }
        for j in 1..=2 {
            for p in ["alpha", "a", "theta", "d"] {
                names.push(format!("serial{j}.{p}"));
            }
        }
        for c in ["x", "y", "z"] {
            names.push(format!("tool.d.{c}"));
        }
        for v in ["dp", "theta"] {
            for c in ["x", "y", "z"] {
                names.push(format!("tracker.{v}.{c}"));
            }
        }
        names
    }

    /// Indices of the parallel module's parameters (limbs and platform).
    pub fn parallel_indices() -> std::ops::Range<usize> {
        0..SERIAL
    }

    /// Indices of the serial module's parameters (MDH rows and tool).
    pub fn serial_indices() -> std::ops::Range<usize> {
        SERIAL..TRACKER
    }

    /// Indices of the base-to-tracker registration.
    pub fn tracker_indices() -> std::ops::Range<usize> {
        TRACKER..N_PARAMS
    }

    /// Errors of limb `i` (0-based).
    pub fn limb(&self, i: usize) -> LimbErrors {
        let x = &self.values[i * LIMB_PARAMS..(i + 1) * LIMB_PARAMS];
        LimbErrors {
            db: v3(&x[0..]),
            theta_b: v3(&x[3..]),
            dn: v3(&x[6..]),
            theta_n: v3(&x[9..]),
            dm: v3(&x[12..]),
            theta_m: v3(&x[15..]),
            da: v3(&x[18..]),
            theta_a: v3(&x[21..]),
            ds: v3(&x[24..]),
            d_shaft: x[27],
            d_length: x[28],
        }
    }

    /// Platform position and attitude errors (Δr_A, θ_A).
    pub fn platform(&self) -> (Vector3<f64>, Vector3<f64>) {
        (
            v3(&self.values[PLATFORM..]),
            v3(&self.values[PLATFORM + 3..]),
        )
    }

    /// Errors of serial joint `j` (0-based).
    pub fn mdh(&self, j: usize) -> MdhErrors {
        let x = &self.values[SERIAL + 4 * j..];
        MdhErrors {
            alpha: x[0],
            a: x[1],
            theta: x[2],
            d: x[3],
        }
    }

    /// Tool offset error, in the tool frame (mm).
    pub fn tool(&self) -> Vector3<f64> {
        v3(&self.values[TOOL..])
    }

    /// Base-to-tracker registration error: position (mm) and attitude (rad), tracker frame.
    pub fn tracker(&self) -> (Vector3<f64>, Vector3<f64>) {
        (v3(&self.values[TRACKER..]), v3(&self.values[TRACKER + 3..]))
    }
}
