//! Nominal geometry: the TOML asset (`assets/robot.toml`), checked on load.

use nalgebra::{Isometry3, Rotation3, Translation3, Vector3};
use serde::Deserialize;

use super::RobotError;

/// The asset shipped with the engine, used when no other file is given.
pub const DEFAULT_ASSET: &str = include_str!("../../assets/robot.toml");

/// One modified Denavit–Hartenberg row (eq. 7): `Rx(α) Tx(a) Rz(θ + offset) Tz(d)`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MdhJoint {
    /// The joint's name (`revolution`, `tilt`), used in error messages.
    pub name: String,
    /// α, deg.
    pub alpha_deg: f64,
    /// a, mm.
    pub a: f64,
    /// Constant offset added to the joint angle θ, deg.
    pub theta_offset_deg: f64,
    /// d, mm.
    pub d: f64,
    /// Joint range; `None` for a continuous (slip-ring) joint.
    #[serde(default)]
    pub limits_deg: Option<[f64; 2]>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ParallelGeometry {
    pub base_radius: f64,
    pub base_angles_deg: [f64; 3],
    pub platform_radius: f64,
    pub platform_angles_deg: [f64; 3],
    pub shaft_length: f64,
    pub stroke: [f64; 2],
    pub extension: [f64; 2],
    pub tilt_limit_deg: f64,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SerialGeometry {
    pub joints: [MdhJoint; 2],
}

/// The fixed MDH row from the last joint to the polishing-pad centre.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ToolGeometry {
    pub alpha_deg: f64,
    pub a: f64,
    pub theta_deg: f64,
    pub d: f64,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrackerGeometry {
    pub position: [f64; 3],
    pub rpy_deg: [f64; 3],
}

/// Nominal geometry of the hybrid robot (mm, degrees as in the file).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    /// `hybrid` (the description's kind, see [`super::Description`]); absent in assets
    /// written before the field existed.
    #[serde(default)]
    pub kind: Option<String>,
    /// The 3-UPS/UP parallel module.
    pub parallel: ParallelGeometry,
    /// The 2R serial head.
    pub serial: SerialGeometry,
    /// The fixed MDH row from the tilt joint to the pad centre.
    pub tool: ToolGeometry,
    /// The base frame's nominal pose in the laser tracker's frame.
    pub tracker: TrackerGeometry,
}

impl Geometry {
    /// The embedded default asset.
    pub fn default_asset() -> Geometry {
        // invariant: the embedded asset is parsed in tests/robot.rs.
        Geometry::parse(DEFAULT_ASSET, "assets/robot.toml").expect("embedded robot asset is valid")
    }

    /// Reads and checks a geometry file.
    pub fn load(path: &std::path::Path) -> Result<Geometry, RobotError> {
        Geometry::parse(&super::read_description(path)?, &path.display().to_string())
    }

    /// The file at `path`, or the embedded default asset when there is none.
    pub fn load_or_default(path: Option<&std::path::Path>) -> Result<Geometry, RobotError> {
        path.map_or_else(|| Ok(Geometry::default_asset()), Geometry::load)
    }

    /// Parses TOML text; `file` names the source in errors.
    pub fn parse(text: &str, file: &str) -> Result<Geometry, RobotError> {
        let g: Geometry = toml::from_str(text).map_err(|e| RobotError::Asset {
            file: file.to_string(),
            message: e.to_string(),
        })?;
        g.check().map_err(|message| RobotError::Asset {
            file: file.to_string(),
            message,
        })?;
        Ok(g)
    }

    fn check(&self) -> Result<(), String> {
        if let Some(kind) = self.kind.as_deref().filter(|k| *k != "hybrid") {
            return Err(format!(
                "kind = {kind:?}: this reader takes the hybrid machine (kind = \"hybrid\"); a serial arm's description has kind = \"serial\" and is read as one (docs/arms.md)"
            ));
        }
        let p = &self.parallel;
        let positive = [
            ("parallel.base_radius", p.base_radius),
            ("parallel.platform_radius", p.platform_radius),
            ("parallel.tilt_limit_deg", p.tilt_limit_deg),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be a positive number, got {v}"));
            }
        }
        if !(p.shaft_length.is_finite() && p.shaft_length >= 0.0) {
            return Err(format!(
                "parallel.shaft_length must be >= 0, got {}",
                p.shaft_length
            ));
        }
        let mut ranges = vec![
            ("parallel.stroke", p.stroke),
            ("parallel.extension", p.extension),
        ];
        let joint_names = ["serial.joints[0].limits_deg", "serial.joints[1].limits_deg"];
        for (j, name) in self.serial.joints.iter().zip(joint_names) {
            if let Some(l) = j.limits_deg {
                ranges.push((name, l));
            }
        }
        for (name, [lo, hi]) in ranges {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(format!(
                    "{name} must be [low, high] with low < high, got [{lo}, {hi}]"
                ));
            }
        }
        if p.extension[0] <= 0.0 {
            return Err("parallel.extension must stay positive".to_string());
        }
        if p.tilt_limit_deg >= 80.0 {
            return Err(format!(
                "parallel.tilt_limit_deg must be below 80, got {}",
                p.tilt_limit_deg
            ));
        }
        let mut all = vec![
            ("tool.alpha_deg", self.tool.alpha_deg),
            ("tool.a", self.tool.a),
            ("tool.theta_deg", self.tool.theta_deg),
            ("tool.d", self.tool.d),
        ];
        all.extend(self.tracker.position.map(|v| ("tracker.position", v)));
        all.extend(self.tracker.rpy_deg.map(|v| ("tracker.rpy_deg", v)));
        let serial = ["serial.joints[0]", "serial.joints[1]"];
        let mut joint_fields = Vec::new();
        for (j, prefix) in self.serial.joints.iter().zip(serial) {
            joint_fields.extend([
                (format!("{prefix}.alpha_deg"), j.alpha_deg),
                (format!("{prefix}.a"), j.a),
                (format!("{prefix}.theta_offset_deg"), j.theta_offset_deg),
                (format!("{prefix}.d"), j.d),
            ]);
        }
        all.extend(joint_fields.iter().map(|(n, v)| (n.as_str(), *v)));
        all.extend(p.base_angles_deg.map(|v| ("parallel.base_angles_deg", v)));
        all.extend(
            p.platform_angles_deg
                .map(|v| ("parallel.platform_angles_deg", v)),
        );
        if let Some((name, v)) = all.iter().find(|(_, v)| !v.is_finite()) {
            return Err(format!("{name} must be a finite number, got {v}"));
        }
        Ok(())
    }

    /// Base joint centres `b_i` (base frame).
    pub fn base_points(&self) -> [Vector3<f64>; 3] {
        let p = &self.parallel;
        p.base_angles_deg.map(|a| on_circle(p.base_radius, a))
    }

    /// Platform joint centres `a_0i` (platform frame).
    pub fn platform_points(&self) -> [Vector3<f64>; 3] {
        let p = &self.parallel;
        p.platform_angles_deg
            .map(|a| on_circle(p.platform_radius, a))
    }

    /// Nominal pose of the base frame in the tracker frame.
    pub fn tracker_from_base(&self) -> Isometry3<f64> {
        let [r, p, y] = self.tracker.rpy_deg.map(f64::to_radians);
        Isometry3::from_parts(
            Translation3::from(Vector3::from(self.tracker.position)),
            Rotation3::from_euler_angles(r, p, y).into(),
        )
    }
}

fn on_circle(radius: f64, angle_deg: f64) -> Vector3<f64> {
    let a = angle_deg.to_radians();
    Vector3::new(radius * a.cos(), radius * a.sin(), 0.0)
}
