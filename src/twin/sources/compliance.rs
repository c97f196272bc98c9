//! Compliance: the limbs stretch under their share of the gravity load and of the
//! polishing force, and the head bends under the pad's friction and its own weight.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

#[derive(Clone, Copy, Debug)]
pub struct ComplianceParams {
    /// Axial compliance of a UPS limb, mm/N.
    pub limb: f64,
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
}

/// Base z points down: gravity is +z.
fn gravity() -> Vector3<f64> {
    Vector3::z()
}

/// Axial stretch of each limb (mm) for limb directions `u` (base → platform), polishing
/// force `force` (N) pressing along `tool_axis`.
pub fn limb_stretch(
    p: &ComplianceParams,
    u: &[Vector3<f64>; 3],
    tool_axis: &Vector3<f64>,
    force: f64,
) -> [f64; 3] {
    // The load hanging on the limbs: gravity down, minus the glass pushing the tool back
    // up its axis; shared equally, each limb takes the component along itself.
    let load = p.weight * gravity() - force * tool_axis;
    [0, 1, 2].map(|i| p.limb * load.dot(&u[i]) / 3.0)
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
