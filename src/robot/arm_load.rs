//! What a serial arm does beyond its geometry (docs/arms.md "Joint compliance" and
//! "Lost motion"): with a `[gravity]` section each revolute joint turns by its
//! compliance times the gravity torque about its axis, and with `lost_motion = true`
//! each joint stands half its lost motion toward the side it last moved. Both add
//! parameters to [`Arm::values`] after the kinematic ones (compliances, then lost
//! motions), which calibration identifies with the geometry.

use std::borrow::Cow;

use nalgebra::{Isometry3, Point3, Vector3};

use super::arm::{frame_isometry, Arm, ArmPose, GravitySpec, JointAxis, JointKind};

/// Gravity, m/s².
const GRAVITY: f64 = 9.81;

impl Arm {
    /// Index in [`Arm::values`] of joint `i`'s compliance, with `[gravity]`.
    pub fn compliance_index(&self, i: usize) -> Option<usize> {
        self.spec
            .gravity
            .as_ref()
            .map(|_| 5 * self.joints() + 12 + i)
    }

    /// Index in [`Arm::values`] of joint `i`'s lost motion, with `lost_motion = true`.
    pub fn lost_motion_index(&self, i: usize) -> Option<usize> {
        let compliances = self.compliance_index(0).map_or(0, |_| self.joints());
        let first = 5 * self.joints() + 12 + compliances;
        self.spec.lost_motion.then_some(first + i)
    }

    /// The same arm without its elastostatic model and lost motion: the geometry alone,
    /// rigid and without play.
    pub fn rigid(&self) -> Arm {
        let mut spec = self.spec.clone();
        spec.gravity = None;
        spec.lost_motion = false;
        for j in &mut spec.joint {
            (j.mass_kg, j.com_mm, j.compliance_urad_per_nm) = (None, None, None);
            j.lost_motion = None;
        }
        Arm {
            spec,
            values: self.values[..5 * self.joints() + 12].to_vec(),
        }
    }

    /// The same arm with the elastostatic model `gravity`, link masses `masses` (kg,
    /// centres of mass at the links' middles) and every revolute joint's compliance
    /// `compliance` (rad per N·m): how the serial twin loads its truth.
    pub fn with_load(&self, gravity: GravitySpec, masses: &[f64], compliance: f64) -> Arm {
        let mut arm = self.rigid();
        arm.spec.gravity = Some(gravity);
        for (j, &m) in arm.spec.joint.iter_mut().zip(masses) {
            j.mass_kg = Some(m);
            if j.kind == JointKind::Revolute {
                arm.values.push(compliance);
            } else {
                arm.values.push(0.0);
            }
        }
        arm
    }

    /// The same arm with lost motion `play` (degrees for a revolute joint, mm for a
    /// prismatic one) on every joint, after whatever load model it has: how the serial
    /// twin gives its truth backlash.
    pub fn with_lost_motion(&self, play: f64) -> Arm {
        let mut arm = self.clone();
        if let Some(first) = arm.lost_motion_index(0) {
            arm.values.truncate(first);
        }
        arm.spec.lost_motion = true;
        for j in &arm.spec.joint {
            arm.values.push(j.kind.internal(play));
        }
        arm
    }

    /// The tool pose where a measurement puts it: at the pose's joint values, reached
    /// from its direction of approach.
    pub fn measured_pose(&self, p: &ArmPose) -> Isometry3<f64> {
        self.tool_pose_from(&p.joints, &p.approach, &self.values)
    }

    /// The tool point of [`Arm::measured_pose`].
    pub fn measured_position(&self, p: &ArmPose) -> Point3<f64> {
        Point3::from(self.measured_pose(p).translation.vector)
    }

    /// The tool pose at joint values `q` reached from `approach` (each joint's last
    /// direction of motion, +1 or −1; 0 or absent: the middle of its lost motion) under
    /// `values`. With lost motion, each joint first stands half its lost motion toward
    /// its approach; with `[gravity]`, each revolute joint then turns by its compliance
    /// times the gravity torque about its axis there ([`Arm::gravity_torques_with`]).
    pub fn tool_pose_from(&self, q: &[f64], approach: &[f64], values: &[f64]) -> Isometry3<f64> {
        let mut actual = Cow::Borrowed(q);
        if let Some(first) = self.lost_motion_index(0) {
            let q = actual.to_mut();
            for (i, (v, side)) in q.iter_mut().zip(approach).enumerate() {
                *v += self.spec.joint[i]
                    .kind
                    .external(0.5 * values[first + i] * side);
            }
        }
        match self.deflected(&actual, values) {
            Some(deflected) => self.walk(&deflected, values, |_, _| {}),
            None => self.walk(&actual, values, |_, _| {}),
        }
    }

    /// Joint values `q` turned by each revolute joint's compliance times its gravity
    /// torque under `values`; `None` for a rigid arm.
    fn deflected(&self, q: &[f64], values: &[f64]) -> Option<Vec<f64>> {
        let c = self.compliance_index(0)?;
        let torques = self.gravity_torques_with(q, values);
        Some(
            self.spec
                .joint
                .iter()
                .enumerate()
                .map(|(i, j)| match j.kind {
                    JointKind::Revolute => q[i] + (values[c + i] * torques[i]).to_degrees(),
                    JointKind::Prismatic => q[i],
                })
                .collect(),
        )
    }

    /// Gravity torque about each joint's axis at joint values `q` (N·m; 0 for prismatic
    /// joints and for a rigid arm): the link masses at their centres of mass and the
    /// payload, beyond each joint, under gravity along the `[gravity]` direction.
    pub fn gravity_torques(&self, q: &[f64]) -> Vec<f64> {
        self.gravity_torques_with(q, &self.values)
    }

    /// [`Arm::gravity_torques`] under the parameter vector `values`.
    pub fn gravity_torques_with(&self, q: &[f64], values: &[f64]) -> Vec<f64> {
        let n = self.joints();
        let Some(g) = &self.spec.gravity else {
            return vec![0.0; n];
        };
        // Joint axes (origin, direction) and the frames after each joint's motion.
        let mut axes: Vec<JointAxis> = Vec::with_capacity(n);
        let mut moved = Vec::with_capacity(n);
        let tool = self.walk(q, values, |before, after| {
            axes.push((
                Point3::from(before.translation.vector),
                before.rotation * Vector3::z(),
            ));
            moved.push(*after);
        });
        let o = 5 * n;
        let down = frame_isometry(&values[o..o + 6]).rotation
            * Vector3::from(g.direction).normalize()
            * GRAVITY;
        // Point masses (mm, kg): each link's, then the payload.
        let mut masses: Vec<(Point3<f64>, f64)> = self
            .spec
            .joint
            .iter()
            .enumerate()
            .map(|(k, j)| {
                let at = match j.com_mm {
                    Some(c) => moved[k] * Point3::from(c),
                    None => {
                        let next = axes
                            .get(k + 1)
                            .map_or(Point3::from(tool.translation.vector), |a| a.0);
                        nalgebra::center(&axes[k].0, &next)
                    }
                };
                (at, j.mass_kg.unwrap_or(0.0))
            })
            .collect();
        masses.push((tool * Point3::from(g.payload_com_mm), g.payload_kg));
        axes.iter()
            .enumerate()
            .map(|(i, (origin, axis))| {
                if self.spec.joint[i].kind != JointKind::Revolute {
                    return 0.0;
                }
                // Masses beyond joint i load it (link i's own mass sits beyond its axis).
                masses[i..]
                    .iter()
                    .map(|(p, m)| axis.dot(&((p - origin) * 1e-3).cross(&(down * *m))))
                    .sum()
            })
            .collect()
    }
}
