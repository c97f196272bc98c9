//! A serial arm of the user's (docs/arms.md): joints in modified Denavit–Hartenberg form
//! with Hayati's β for nearly parallel axes, joint limits, the base transform (the
//! measurement frame's registration) and the tool transform, read from a TOML
//! description. Units inside: mm and rad; the file says degrees where it says `_deg`.
//!
//! Every kinematic parameter has a name (`<joint>.alpha|a|beta|theta|d`,
//! `base.x|y|z|rx|ry|rz`, `tool.x|y|z|rx|ry|rz`) and a place in [`Arm::values`], the
//! vector calibration identifies. A description with a `[gravity]` section adds the
//! elastostatic model (docs/arms.md "Joint compliance"): link masses, a payload, and one
//! compliance per joint (`<joint>.compliance`, after the kinematic parameters), so that
//! each revolute joint turns by its compliance times the gravity torque about its axis.
//! `lost_motion = true` adds each joint's lost motion (`<joint>.lost_motion`, after the
//! compliances): a joint stands half of it to the side it last moved toward
//! (docs/arms.md "Lost motion").

use std::collections::BTreeSet;
use std::path::Path;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::serial::{mdh_link, mdh_motion};
use super::RobotError;

/// Parameters per joint, in [`Arm::values`] order.
pub const JOINT_PARAMS: [&str; 5] = ["alpha", "a", "beta", "theta", "d"];
/// Parameters of the base and of the tool transform, in order.
pub const FRAME_PARAMS: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];
/// The most joints a description may have.
pub const MAX_JOINTS: usize = 32;

/// What a parameter of [`Arm::values`] measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParamKind {
    /// A length, mm.
    Length,
    /// An angle, rad.
    Angle,
    /// A joint compliance, rad per N·m.
    Compliance,
}

impl ParamKind {
    /// The unit a person reads it in, and the factor from the internal value to it.
    pub fn display(self) -> (&'static str, f64) {
        match self {
            ParamKind::Length => ("mm", 1.0),
            ParamKind::Angle => ("deg", 180.0 / std::f64::consts::PI),
            ParamKind::Compliance => ("µrad/(N·m)", 1e6),
        }
    }
}

/// Revolute (the joint value turns θ, degrees in files) or prismatic (it extends d, mm).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JointKind {
    /// Rotates about its z axis.
    Revolute,
    /// Slides along its z axis.
    Prismatic,
}

impl JointKind {
    /// An amount in the joint values' unit (degrees or mm) in the internal one (rad or
    /// mm).
    pub fn internal(self, v: f64) -> f64 {
        match self {
            JointKind::Revolute => v.to_radians(),
            JointKind::Prismatic => v,
        }
    }

    /// An internal amount (rad or mm) in the joint values' unit (degrees or mm).
    pub fn external(self, v: f64) -> f64 {
        match self {
            JointKind::Revolute => v.to_degrees(),
            JointKind::Prismatic => v,
        }
    }
}

/// One joint as the file writes it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointSpec {
    /// Unique name (parameters are named after it).
    pub name: String,
    /// `revolute` or `prismatic`.
    pub kind: JointKind,
    /// Twist about the previous x axis, degrees.
    pub alpha_deg: f64,
    /// Length along the previous x axis, mm.
    pub a_mm: f64,
    /// Hayati's rotation about the previous y axis, degrees (0 in a plain MDH table).
    #[serde(default)]
    pub beta_deg: f64,
    /// Joint angle offset, degrees.
    pub theta_deg: f64,
    /// Offset along the joint's z axis, mm.
    pub d_mm: f64,
    /// Lower limit of the joint value (degrees or mm).
    pub min: f64,
    /// Upper limit of the joint value (degrees or mm).
    pub max: f64,
    /// Mass of the link this joint moves, kg (with `[gravity]`; none when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_kg: Option<f64>,
    /// That link's centre of mass in the joint's frame after its motion (the modified-DH
    /// frame of this joint), mm; when absent, the middle of the link: half way from this
    /// joint's axis origin to the next joint's (or to the tool point).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub com_mm: Option<[f64; 3]>,
    /// Compliance of a revolute joint, µrad per N·m (with `[gravity]`; 0 when absent):
    /// the joint turns by it times the gravity torque about its axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compliance_urad_per_nm: Option<f64>,
    /// Lost motion of the joint's drive, in its values' unit (degrees or mm), with
    /// `lost_motion = true` (0 when absent): the joint stands half of it past the
    /// commanded value in the direction it last moved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lost_motion: Option<f64>,
}

/// The gravity load of the elastostatic model: its direction in the robot's base frame
/// and a payload at the tool.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GravitySpec {
    /// Direction of gravity in the base frame (any length; normalised), `[0, 0, -1]`
    /// when absent.
    #[serde(default = "down")]
    pub direction: [f64; 3],
    /// Mass at the tool (tool, reflector and holder), kg.
    #[serde(default)]
    pub payload_kg: f64,
    /// Its centre of mass in the tool frame, mm (the tool point when absent).
    #[serde(default)]
    pub payload_com_mm: [f64; 3],
}

fn down() -> [f64; 3] {
    [0.0, 0.0, -1.0]
}

/// A rigid transform as the file writes it: translation (mm), then roll, pitch, yaw
/// (degrees; R = Rz(yaw)·Ry(pitch)·Rx(roll)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameSpec {
    /// Translation, mm.
    pub xyz_mm: [f64; 3],
    /// Roll, pitch, yaw, degrees.
    pub rpy_deg: [f64; 3],
}

/// What a calibration wrote into a calibrated description (absent in a nominal one).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationRecord {
    /// Poses the parameters were fitted on.
    pub poses: usize,
    /// Identified parameters.
    pub identified: Vec<String>,
    /// Parameters left at their nominal value, each with the reason.
    pub kept_nominal: Vec<String>,
    /// RMS position residual on the fitted poses before and after, mm.
    pub rms_before_mm: f64,
    /// RMS position residual on the fitted poses after calibration, mm.
    pub rms_after_mm: f64,
}

/// The description file of a serial arm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmSpec {
    /// Always `serial` (the hybrid machine's description is `hybrid`,
    /// [`super::Description`]).
    pub kind: String,
    /// The arm's name.
    pub name: String,
    /// Where the nominal values come from.
    #[serde(default)]
    pub source: String,
    /// Joints from the base outwards.
    pub joint: Vec<JointSpec>,
    /// Robot base in the measurement (tracker) frame.
    #[serde(default)]
    pub base: FrameSpec,
    /// Tool point (TCP) in the last joint's frame.
    #[serde(default)]
    pub tool: FrameSpec,
    /// Model each joint's lost motion (backlash): a parameter per joint that depends on
    /// the direction the joint last moved, taken from the pose file's order.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub lost_motion: bool,
    /// The elastostatic model's gravity load; absent: a rigid arm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity: Option<GravitySpec>,
    /// Parameters calibration may identify (all when absent); `*` ends a prefix
    /// (`base.*`, `elbow.*`) and starts a suffix (`*.compliance`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identify: Option<Vec<String>>,
    /// Written by `iastgcn calibrate`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationRecord>,
}

/// A serial arm: its description and the kinematic parameter vector (mm, rad).
#[derive(Clone, Debug, PartialEq)]
pub struct Arm {
    /// The description it was read from (limits, names, what may be identified).
    pub spec: ArmSpec,
    /// Every kinematic parameter, named by [`Arm::names`].
    pub values: Vec<f64>,
}

/// A joint axis in the measurement frame: a point on it (the joint frame's origin) and
/// its direction.
pub type JointAxis = (Point3<f64>, Vector3<f64>);

/// One measured pose of an arm: joint values (degrees or mm), the measured tool
/// position (mm, measurement frame) and, where measured, its orientation.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmPose {
    /// Pose number or time stamp (s), as the file gives it.
    pub stamp: f64,
    /// Joint values, degrees (revolute) or mm (prismatic).
    pub joints: Vec<f64>,
    /// Measured tool position, mm.
    pub position: Point3<f64>,
    /// Measured tool orientation, where the instrument gives one.
    pub orientation: Option<UnitQuaternion<f64>>,
    /// Further sensor channels (names in the file's header).
    pub channels: Vec<f64>,
    /// The instrument's standard deviation of this reading, where the file gives it.
    pub reading_sd: Option<ReadingSd>,
    /// The direction each joint last moved before this pose (+1, −1; 0 where unknown:
    /// the file's first pose, a joint that has not moved yet), from the file's order
    /// ([`set_approach`]).
    pub approach: Vec<f64>,
}

/// The standard deviation an instrument gives with one reading (a laser tracker's spread
/// over the samples it averaged): per axis of the measured position (mm, measurement
/// frame) and, where the orientation is measured, of its three angles as exported
/// (degrees). The calibration weights the reading by them (docs/arms.md "Calibration").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReadingSd {
    /// x, y, z, mm.
    pub position_mm: [f64; 3],
    /// The three orientation angles, degrees.
    pub orientation_deg: Option<[f64; 3]>,
}

impl ReadingSd {
    /// One SD for the orientation as a whole (rad): the RMS of its three angles'.
    pub fn orientation_rad(&self) -> Option<f64> {
        self.orientation_deg.map(|a| {
            (a.iter().map(|v| v * v).sum::<f64>() / 3.0)
                .sqrt()
                .to_radians()
        })
    }
}

/// Sets each pose's [`ArmPose::approach`] from the order of `poses` (measurement order):
/// the sign of each joint's last change before it; 0 until a joint has moved.
pub fn set_approach(poses: &mut [ArmPose]) {
    for k in 0..poses.len() {
        let approach = match k.checked_sub(1).map(|b| &poses[b]) {
            Some(before) => next_approach(before, &poses[k].joints),
            None => vec![0.0; poses[k].joints.len()],
        };
        poses[k].approach = approach;
    }
}

/// The approach of a pose at joint values `now` reached from the pose `before`: each
/// joint's sign of change, or `before`'s approach where the joint did not move.
pub fn next_approach(before: &ArmPose, now: &[f64]) -> Vec<f64> {
    now.iter()
        .zip(&before.joints)
        .zip(before.approach.iter().chain(std::iter::repeat(&0.0)))
        .map(|((q, b), side)| if q == b { *side } else { (q - b).signum() })
        .collect()
}

fn frame(spec: &FrameSpec) -> [f64; 6] {
    let [x, y, z] = spec.xyz_mm;
    let [r, p, w] = spec.rpy_deg.map(f64::to_radians);
    [x, y, z, r, p, w]
}

fn frame_spec(v: &[f64]) -> FrameSpec {
    FrameSpec {
        xyz_mm: [v[0], v[1], v[2]],
        rpy_deg: [v[3].to_degrees(), v[4].to_degrees(), v[5].to_degrees()],
    }
}

/// The isometry of six frame values (mm, rad: x, y, z, roll, pitch, yaw).
pub fn frame_isometry(v: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::from_euler_angles(v[3], v[4], v[5]),
    )
}

impl Arm {
    /// Reads and checks a description file; errors name the file and the field.
    pub fn load(path: &Path) -> Result<Arm, RobotError> {
        Arm::parse(&super::read_description(path)?, &path.display().to_string())
    }

    /// Parses and checks a description (`file` names it in errors).
    pub fn parse(text: &str, file: &str) -> Result<Arm, RobotError> {
        let err = |message: String| RobotError::Asset {
            file: file.to_string(),
            message,
        };
        let spec: ArmSpec = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        Arm::from_spec(spec).map_err(err)
    }

    /// Checks a description and builds its parameter vector; the error names the field.
    pub fn from_spec(spec: ArmSpec) -> Result<Arm, String> {
        if spec.kind != "serial" {
            return Err(format!(
                "kind = {:?}: this reader takes serial arms (kind = \"serial\"); the hybrid machine's description is kind = \"hybrid\" (assets/robot.toml)",
                spec.kind
            ));
        }
        if spec.joint.is_empty() {
            return Err("no [[joint]]: a serial arm has at least one joint".into());
        }
        if spec.joint.len() > MAX_JOINTS {
            return Err(format!(
                "{} joints: at most {MAX_JOINTS} are taken",
                spec.joint.len()
            ));
        }
        let mut seen = BTreeSet::new();
        for (i, j) in spec.joint.iter().enumerate() {
            let at = format!("joint[{i}] ({:?})", j.name);
            let valid_name = !j.name.is_empty()
                && j.name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
            if !valid_name || j.name == "base" || j.name == "tool" {
                return Err(format!(
                    "{at}.name: a joint name is letters, digits, '_' or '-', and neither base nor tool"
                ));
            }
            if !seen.insert(j.name.clone()) {
                return Err(format!(
                    "{at}.name: duplicate joint name (parameters are named after joints)"
                ));
            }
            for (field, v) in [
                ("alpha_deg", j.alpha_deg),
                ("a_mm", j.a_mm),
                ("beta_deg", j.beta_deg),
                ("theta_deg", j.theta_deg),
                ("d_mm", j.d_mm),
                ("min", j.min),
                ("max", j.max),
            ] {
                if !v.is_finite() || v.abs() > 1e6 {
                    return Err(format!(
                        "{at}.{field} = {v}: must be a finite number within ±1e6"
                    ));
                }
            }
            if j.min >= j.max {
                return Err(format!(
                    "{at}: min = {} must be below max = {}",
                    j.min, j.max
                ));
            }
            check_load(&at, j, spec.gravity.is_some())?;
            if let Some(b) = j.lost_motion {
                if !spec.lost_motion {
                    return Err(format!(
                        "{at}.lost_motion: a joint's lost motion needs `lost_motion = true` at the top of the description"
                    ));
                }
                if !b.is_finite() || b.abs() > 1e6 {
                    return Err(format!(
                        "{at}.lost_motion = {b}: must be a finite number within ±1e6"
                    ));
                }
            }
        }
        if let Some(g) = &spec.gravity {
            if g.direction.iter().any(|v| !v.is_finite())
                || Vector3::from(g.direction).norm() < 1e-9
            {
                return Err(format!(
                    "gravity.direction = {:?}: must be a finite, non-zero vector (the base frame's down, [0, 0, -1] for an arm on the floor)",
                    g.direction
                ));
            }
            if !(0.0..=1e4).contains(&g.payload_kg) {
                return Err(format!(
                    "gravity.payload_kg = {}: must be from 0 to 1e4",
                    g.payload_kg
                ));
            }
            if let Some(k) = g
                .payload_com_mm
                .iter()
                .position(|v| !v.is_finite() || v.abs() > 1e6)
            {
                return Err(format!(
                    "gravity.payload_com_mm[{k}] = {}: must be a finite number within ±1e6",
                    g.payload_com_mm[k]
                ));
            }
        }
        for (name, f) in [("base", &spec.base), ("tool", &spec.tool)] {
            for (field, values) in [("xyz_mm", &f.xyz_mm), ("rpy_deg", &f.rpy_deg)] {
                if let Some(k) = values.iter().position(|v| !v.is_finite() || v.abs() > 1e6) {
                    return Err(format!(
                        "{name}.{field}[{k}] = {}: must be a finite number within ±1e6",
                        values[k]
                    ));
                }
            }
        }
        let mut values = Vec::new();
        for j in &spec.joint {
            values.extend([
                j.alpha_deg.to_radians(),
                j.a_mm,
                j.beta_deg.to_radians(),
                j.theta_deg.to_radians(),
                j.d_mm,
            ]);
        }
        values.extend(frame(&spec.base));
        values.extend(frame(&spec.tool));
        if spec.gravity.is_some() {
            values.extend(
                spec.joint
                    .iter()
                    .map(|j| j.compliance_urad_per_nm.unwrap_or(0.0) / 1e6),
            );
        }
        if spec.lost_motion {
            values.extend(
                spec.joint
                    .iter()
                    .map(|j| j.kind.internal(j.lost_motion.unwrap_or(0.0))),
            );
        }
        let arm = Arm { spec, values };
        if let Some(patterns) = &arm.spec.identify {
            let names = arm.names();
            let mut listed = BTreeSet::new();
            for p in patterns {
                if !listed.insert(p.clone()) {
                    return Err(format!("identify: {p:?} is listed twice"));
                }
                if !names.iter().any(|n| matches(p, n)) {
                    return Err(format!(
                        "identify: {p:?} names no parameter (names are <joint>.alpha|a|beta|theta|d, base.x|y|z|rx|ry|rz, tool.x|y|z|rx|ry|rz, and <joint>.compliance with [gravity]; a * at the end matches a prefix, at the start a suffix)"
                    ));
                }
            }
        }
        arm.check_moves_tool()?;
        Ok(arm)
    }

    /// Refuses a chain that cannot work: one where no joint moves the tool point anywhere
    /// in its range (every axis passes through it), so that every pose measures the same
    /// point. A joint whose axis alone passes through the tool point (a reflector on the
    /// flange axis, the usual set-up) is accepted: a position measurement cannot see its
    /// angle, and the calibration's identifiability analysis reports the parameters it
    /// cannot see as having no effect ([`Arm::joints_moving_tool`]).
    fn check_moves_tool(&self) -> Result<(), String> {
        if self.joints_moving_tool().iter().any(|&m| m) {
            return Ok(());
        }
        Err(format!(
            "no joint moves the tool point anywhere in its range (every joint axis passes \
             through it), so every pose would measure the same point: give the tool an \
             offset from the last axis ([tool] xyz_mm) or check the {} joints' DH values",
            self.joints()
        ))
    }

    /// Per joint, whether turning it moves the tool point at some of 7 configurations
    /// spread over the joint ranges: false for a joint whose axis passes through the tool
    /// point wherever the others are (a reflector on the last joint's axis).
    pub fn joints_moving_tool(&self) -> Vec<bool> {
        let n = self.joints();
        let mut moves = vec![false; n];
        for s in 0..7 {
            let q = self.at_shares(|i| 0.1 + 0.8 * ((s * 3 + i * 5) % 7) as f64 / 6.0);
            let p0 = self.tool_position(&q);
            for (i, m) in moves.iter_mut().enumerate() {
                let mut dq = q.clone();
                let step = 1e-3 * (self.spec.joint[i].max - self.spec.joint[i].min);
                dq[i] += step;
                if (self.tool_position(&dq) - p0).norm() > 1e-9 * step.abs().max(1e-12) {
                    *m = true;
                }
            }
        }
        moves
    }

    /// Number of joints.
    pub fn joints(&self) -> usize {
        self.spec.joint.len()
    }

    /// The name of every kinematic parameter, in [`Arm::values`] order.
    pub fn names(&self) -> Vec<String> {
        let mut names = Vec::with_capacity(self.values.len());
        for j in &self.spec.joint {
            names.extend(JOINT_PARAMS.iter().map(|p| format!("{}.{p}", j.name)));
        }
        for frame in ["base", "tool"] {
            names.extend(FRAME_PARAMS.iter().map(|p| format!("{frame}.{p}")));
        }
        if self.spec.gravity.is_some() {
            names.extend(
                self.spec
                    .joint
                    .iter()
                    .map(|j| format!("{}.compliance", j.name)),
            );
        }
        if self.spec.lost_motion {
            names.extend(
                self.spec
                    .joint
                    .iter()
                    .map(|j| format!("{}.lost_motion", j.name)),
            );
        }
        names
    }

    /// Whether parameter `name` is in the description's `identify` list (all are when
    /// it has none).
    pub fn may_identify(&self, name: &str) -> bool {
        self.spec
            .identify
            .as_ref()
            .is_none_or(|ps| ps.iter().any(|p| matches(p, name)))
    }

    /// What parameter `index` measures.
    pub fn param_kind(&self, index: usize) -> ParamKind {
        let joints = 5 * self.joints();
        let length = if index < joints {
            matches!(index % 5, 1 | 4)
        } else if index < joints + 12 {
            (index - joints) % 6 < 3
        } else {
            match self.lost_motion_index(0) {
                // A lost motion, in its joint's unit.
                Some(first) if index >= first => {
                    self.spec.joint[index - first].kind == JointKind::Prismatic
                }
                _ => return ParamKind::Compliance,
            }
        };
        if length {
            ParamKind::Length
        } else {
            ParamKind::Angle
        }
    }

    /// Whether parameter `index` is a length (mm).
    pub fn is_length(&self, index: usize) -> bool {
        self.param_kind(index) == ParamKind::Length
    }

    /// The same arm with other parameter values.
    pub fn with_values(&self, values: Vec<f64>) -> Arm {
        Arm {
            spec: self.spec.clone(),
            values,
        }
    }

    /// The base transform (measurement frame ← robot base).
    pub fn base(&self) -> Isometry3<f64> {
        let o = 5 * self.joints();
        frame_isometry(&self.values[o..o + 6])
    }

    /// The tool transform (last joint frame ← tool point).
    pub fn tool(&self) -> Isometry3<f64> {
        let o = 5 * self.joints() + 6;
        frame_isometry(&self.values[o..o + 6])
    }

    /// The tool pose in the measurement frame at joint values `q` (degrees or mm).
    /// With lost motion, each joint stands in the middle of its play (no approach).
    pub fn tool_pose(&self, q: &[f64]) -> Isometry3<f64> {
        self.tool_pose_from(q, &[], &self.values)
    }

    /// The chain from the base to the tool under `values` at joint values `q` (as
    /// given: no deflection), calling `at_joint` with each joint's frame before its own
    /// motion (its z axis is the joint's axis) and after it. Returns the tool pose.
    pub(super) fn walk(
        &self,
        q: &[f64],
        values: &[f64],
        mut at_joint: impl FnMut(&Isometry3<f64>, &Isometry3<f64>),
    ) -> Isometry3<f64> {
        let o = 5 * self.joints();
        let mut t = frame_isometry(&values[o..o + 6]);
        for (i, j) in self.spec.joint.iter().enumerate() {
            let v = &values[5 * i..5 * i + 5];
            let (mut theta, mut d) = (v[3], v[4]);
            match j.kind {
                JointKind::Revolute => theta += q[i].to_radians(),
                JointKind::Prismatic => d += q[i],
            }
            t *= mdh_link(v[0], v[1], v[2]);
            let before = t;
            t *= mdh_motion(theta, d);
            at_joint(&before, &t);
        }
        t * frame_isometry(&values[o + 6..o + 12])
    }

    /// The tool point in the measurement frame at joint values `q`.
    pub fn tool_position(&self, q: &[f64]) -> Point3<f64> {
        Point3::from(self.tool_pose(q).translation.vector)
    }

    /// Joint values at the share `share(i)` of each joint's range (0: its lower limit,
    /// 1: its upper one).
    pub fn at_shares(&self, mut share: impl FnMut(usize) -> f64) -> Vec<f64> {
        self.spec
            .joint
            .iter()
            .enumerate()
            .map(|(i, j)| j.min + (j.max - j.min) * share(i))
            .collect()
    }

    /// Joint values (degrees or mm) that put the tool point at `target` (measurement
    /// frame, mm), starting from `seed`: damped least squares on a central-difference
    /// Jacobian, each joint kept within its limits. The error gives the distance left
    /// when no solution within 1 µm is found in 1000 iterations from any start (a target out of reach).
    ///
    /// When the descent from `seed` stalls (at a joint limit, or in a local minimum) it
    /// starts again from the middle of the ranges and from 16 fixed spread
    /// configurations, and returns the first solution found.
    pub fn inverse_position(&self, target: &Point3<f64>, seed: &[f64]) -> Result<Vec<f64>, String> {
        self.inverse_position_from(target, seed, &[])
    }

    /// [`Arm::inverse_position`] for joints that reach their values from `approach`
    /// (each joint's direction of motion, as in [`Arm::tool_pose_from`]).
    pub fn inverse_position_from(
        &self,
        target: &Point3<f64>,
        seed: &[f64],
        approach: &[f64],
    ) -> Result<Vec<f64>, String> {
        let mut best = match self.descend(target, seed, approach) {
            Ok(q) => return Ok(q),
            Err(short) => short,
        };
        for k in 0..17 {
            let start = self.at_shares(|i| {
                // k = 0: the middle; then a Kronecker sequence (golden-ratio steps).
                let f = if k == 0 {
                    0.5
                } else {
                    (0.5 + (k * (i + 1)) as f64 * 0.618_033_988_749_895).fract()
                };
                0.05 + 0.9 * f
            });
            match self.descend(target, &start, approach) {
                Ok(q) => return Ok(q),
                Err(short) => best = best.min(short),
            }
        }
        Err(format!(
            "no joint values within the limits reach ({:.3}, {:.3}, {:.3}) mm: {best:.3} mm short",
            target.x, target.y, target.z
        ))
    }

    /// Damped least squares from `seed`; the distance left when it stalls.
    fn descend(
        &self,
        target: &Point3<f64>,
        seed: &[f64],
        approach: &[f64],
    ) -> Result<Vec<f64>, f64> {
        let at = |q: &[f64]| {
            Point3::from(
                self.tool_pose_from(q, approach, &self.values)
                    .translation
                    .vector,
            )
        };
        let n = self.joints();
        let clamp = |q: &mut [f64]| {
            for (v, j) in q.iter_mut().zip(&self.spec.joint) {
                *v = v.clamp(j.min, j.max);
            }
        };
        let mut q = seed.to_vec();
        clamp(&mut q);
        let mut error = target - at(&q);
        let mut damping = 1e-2;
        for _ in 0..1000 {
            if error.norm() < 1e-3 {
                return Ok(q);
            }
            let mut jac = nalgebra::DMatrix::zeros(3, n);
            for i in 0..n {
                let h = 1e-6 * (self.spec.joint[i].max - self.spec.joint[i].min).max(1e-3);
                let (mut plus, mut minus) = (q.clone(), q.clone());
                plus[i] += h;
                minus[i] -= h;
                let d = (at(&plus) - at(&minus)) / (2.0 * h);
                jac.set_column(i, &d);
            }
            let jjt = &jac * jac.transpose() + nalgebra::Matrix3::identity() * damping;
            let Some(inv) = jjt.try_inverse() else {
                break;
            };
            let step = jac.transpose() * (inv * error);
            let mut trial = q.clone();
            for (v, d) in trial.iter_mut().zip(step.iter()) {
                *v += d;
            }
            clamp(&mut trial);
            let e = target - at(&trial);
            if e.norm() < error.norm() {
                (q, error) = (trial, e);
                damping = (damping * 0.3).max(1e-9);
            } else {
                damping *= 10.0;
                if damping > 1e9 {
                    break;
                }
            }
        }
        if error.norm() < 1e-3 {
            return Ok(q);
        }
        Err(error.norm())
    }

    /// The description with the arm's current values (and `calibration`, if given).
    pub fn to_spec(&self, calibration: Option<CalibrationRecord>) -> ArmSpec {
        let mut spec = self.spec.clone();
        for (i, j) in spec.joint.iter_mut().enumerate() {
            let v = &self.values[5 * i..5 * i + 5];
            j.alpha_deg = v[0].to_degrees();
            j.a_mm = v[1];
            j.beta_deg = v[2].to_degrees();
            j.theta_deg = v[3].to_degrees();
            j.d_mm = v[4];
        }
        let o = 5 * self.joints();
        spec.base = frame_spec(&self.values[o..o + 6]);
        spec.tool = frame_spec(&self.values[o + 6..o + 12]);
        if let Some(c) = self.compliance_index(0) {
            for (j, c) in spec.joint.iter_mut().zip(&self.values[c..]) {
                j.compliance_urad_per_nm = Some(c * 1e6);
            }
        }
        if let Some(b) = self.lost_motion_index(0) {
            for (j, b) in spec.joint.iter_mut().zip(&self.values[b..]) {
                j.lost_motion = Some(j.kind.external(*b));
            }
        }
        spec.calibration = calibration;
        spec
    }

    /// The description as TOML (what [`Arm::load`] reads back).
    pub fn to_toml(&self, calibration: Option<CalibrationRecord>) -> Result<String, String> {
        toml::to_string(&self.to_spec(calibration)).map_err(|e| e.to_string())
    }
}

/// Whether `pattern` (a name, a prefix ending in `*` or a suffix starting with `*`)
/// matches the parameter `name`.
fn matches(pattern: &str, name: &str) -> bool {
    if let Some(prefix) = pattern.strip_suffix('*') {
        return name.starts_with(prefix);
    }
    match pattern.strip_prefix('*') {
        Some(suffix) => name.ends_with(suffix),
        None => pattern == name,
    }
}

/// Checks a joint's load fields (`at` names the joint): finite, a mass not negative,
/// and none of them without a `[gravity]` section to use them.
fn check_load(at: &str, j: &JointSpec, gravity: bool) -> Result<(), String> {
    let given = [
        ("mass_kg", j.mass_kg.is_some()),
        ("com_mm", j.com_mm.is_some()),
        ("compliance_urad_per_nm", j.compliance_urad_per_nm.is_some()),
    ];
    if let (false, Some((field, _))) = (gravity, given.iter().find(|g| g.1)) {
        return Err(format!(
            "{at}.{field}: a joint's load fields need a [gravity] section (the elastostatic model; docs/arms.md \"Joint compliance\")"
        ));
    }
    if let Some(m) = j.mass_kg {
        if !(0.0..=1e4).contains(&m) {
            return Err(format!("{at}.mass_kg = {m}: must be from 0 to 1e4"));
        }
    }
    if let Some(k) = j
        .com_mm
        .and_then(|c| c.iter().position(|v| !v.is_finite() || v.abs() > 1e6))
    {
        return Err(format!(
            "{at}.com_mm[{k}] = {}: must be a finite number within ±1e6",
            j.com_mm.unwrap_or_default()[k]
        ));
    }
    if let Some(c) = j.compliance_urad_per_nm {
        if !c.is_finite() || c.abs() > 1e6 {
            return Err(format!(
                "{at}.compliance_urad_per_nm = {c}: must be a finite number within ±1e6"
            ));
        }
        if j.kind == JointKind::Prismatic && c != 0.0 {
            return Err(format!(
                "{at}.compliance_urad_per_nm = {c}: a prismatic joint is taken as rigid (only revolute joints bend under gravity here)"
            ));
        }
    }
    Ok(())
}
