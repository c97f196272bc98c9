//! Compliance (docs/twin.md "Compliance"): the limbs stretch under their share of the
//! gravity load and of the polishing force, their joints shift across their clearance
//! when a limb's load changes sign, the head's gear trains wind up under the torque about
//! each joint, and the tool bends under the pad's friction and the head's weight.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// The machine's compliance parameters (docs/twin.md "Compliance").
#[derive(Clone, Copy, Debug)]
pub struct ComplianceParams {
    /// Axial compliance of a UPS limb, mm/N.
    pub limb: f64,
    /// Share of a limb's axial compliance inside the screw's span (screw between bearing
    /// and nut, the bearing itself); the rest is in the strut tube and joints.
    pub screw_share: f64,
    /// Total axial clearance of a limb's two joints, mm.
    pub joint_clearance: f64,
    /// Axial load over which a limb's joints cross their clearance, N.
    pub clearance_load: f64,
    /// Weight carried by the parallel module (platform + head + tool), N.
    pub weight: f64,
    /// Tool-tip compliance along the tool axis, mm/N.
    pub tip_axial: f64,
    /// Tool-tip compliance across the tool axis, mm/N.
    pub tip_lateral: f64,
    /// Angular compliance of the head, rad/(N·m).
    pub head_rotation: f64,
    /// Distance from the head's bending centre to the pad, m.
    pub head_lever: f64,
    /// Weight of the head acting at its lever, N.
    pub head_weight: f64,
    /// Pad friction coefficient (lateral force along the feed per unit normal force).
    pub friction: f64,
    /// Torsional compliance of each serial joint's gear train, rad/(N·m).
    pub drive_torsion: f64,
}

/// Base z points down: gravity is +z.
fn gravity() -> Vector3<f64> {
    Vector3::z()
}

/// How each limb gives under load, mm (positive lengthens it).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LimbGive {
    /// Stretch inside the length sensor's span.
    pub screw: [f64; 3],
    /// Stretch of the strut tube and joints outside it.
    pub strut: [f64; 3],
    /// Shift of the joints across their clearance.
    pub clearance: [f64; 3],
}

impl LimbGive {
    /// Each limb's whole give (screw, strut and clearance), mm.
    pub fn total(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| self.screw[i] + self.strut[i] + self.clearance[i])
    }
}

/// How each limb gives (mm) for limb directions `u` (base → platform), polishing force
/// `force` (N) pressing along `tool_axis`.
pub fn limb_give(
    p: &ComplianceParams,
    u: &[Vector3<f64>; 3],
    tool_axis: &Vector3<f64>,
    force: f64,
) -> LimbGive {
    // The load hanging on the limbs: gravity down, minus the glass pushing the tool back
    // up its axis; shared equally, each limb takes the component along itself.
    let load = p.weight * gravity() - force * tool_axis;
    let axial = [0, 1, 2].map(|i| load.dot(&u[i]) / 3.0);
    LimbGive {
        screw: axial.map(|a| p.screw_share * p.limb * a),
        strut: axial.map(|a| (1.0 - p.screw_share) * p.limb * a),
        // Tension pulls the joints to the far side of their clearance, compression to the
        // near side; the change is smooth over `clearance_load` (preload, friction).
        clearance: axial.map(|a| 0.5 * p.joint_clearance * (a / p.clearance_load).tanh()),
    }
}

/// The forces on the tool that the head's joints carry: the glass's push and drag at the
/// pad, and the head's weight at its lever.
pub struct ToolLoad {
    /// The pad centre, mm, base frame.
    pub pad: Point3<f64>,
    /// The force of the glass on the pad (normal push and friction drag), N, base frame.
    pub pad_force: Vector3<f64>,
    /// Where the head's weight acts: `head_lever` up the tool axis from the pad, mm.
    pub weight_at: Point3<f64>,
    /// The head's weight, N, base frame (+z is down).
    pub weight: Vector3<f64>,
}

impl ToolLoad {
    /// The load for the pad at `pad` (mm) pressing with `force` (N) along `tool_axis` while
    /// it moves along `feed_dir` (unit, or zero at rest).
    pub fn new(
        p: &ComplianceParams,
        pad: Point3<f64>,
        tool_axis: &Vector3<f64>,
        feed_dir: &Vector3<f64>,
        force: f64,
    ) -> ToolLoad {
        ToolLoad {
            pad,
            pad_force: -force * tool_axis - p.friction * force * feed_dir,
            weight_at: pad - 1000.0 * p.head_lever * tool_axis,
            weight: p.head_weight * gravity(),
        }
    }

    /// Torque (N·m) about the axis `axis` through `origin` (mm).
    pub fn torque_about(&self, origin: &Point3<f64>, axis: &Vector3<f64>) -> f64 {
        let m = (self.pad - origin).cross(&self.pad_force)
            + (self.weight_at - origin).cross(&self.weight);
        1e-3 * m.dot(axis)
    }
}

/// Wind-up of each serial joint's gear train (rad) under `load`, for joint axes
/// `(origin, axis)` in the base frame.
pub fn drive_windup(
    p: &ComplianceParams,
    axes: &[(Point3<f64>, Vector3<f64>); 2],
    load: &ToolLoad,
) -> [f64; 2] {
    axes.map(|(o, z)| p.drive_torsion * load.torque_about(&o, &z))
}

/// Deflection of the pad frame (applied in the base frame at the pad) under the normal
/// force, the friction along the feed direction `feed_dir` (unit, or zero at rest) and the
/// head's weight.
pub fn tip_deflection(
    p: &ComplianceParams,
    tool_axis: &Vector3<f64>,
    feed_dir: &Vector3<f64>,
    force: f64,
) -> Isometry3<f64> {
    let normal = -force * tool_axis; // the glass pushes back up the axis
    let friction = -p.friction * force * feed_dir; // drag against the motion
    let lateral = friction - friction.dot(tool_axis) * tool_axis;
    let shift = p.tip_axial * normal + p.tip_lateral * lateral;
    // Bending moment about the head's centre: friction and the head's own weight act at
    // the lever along the tool axis.
    let arm = p.head_lever * tool_axis;
    let moment = arm.cross(&(friction + p.head_weight * gravity()));
    let bend = p.head_rotation * moment;
    // Turning about the bending centre also carries the pad sideways (arm in mm).
    let swing = bend.cross(&(1000.0 * arm));
    Isometry3::from_parts(
        Translation3::from(shift + swing),
        UnitQuaternion::from_scaled_axis(bend),
    )
}
