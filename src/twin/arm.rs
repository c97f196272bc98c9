//! A twin of any serial arm (docs/arms.md "The serial twin"): the description's nominal
//! values plus hidden geometric errors and an unknown tracker registration, and the
//! usual non-geometric errors of a real arm: joint compliance under gravity (link
//! masses and a payload), gear backlash that depends on the direction each joint last
//! moved, and thermal growth of the links as the arm warms up. A laser tracker measures
//! the tool point at static poses, and a temperature sensor reads the arm's temperature.

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::noise::gaussian;
use crate::robot::arm::{set_approach, Arm, ArmPose, GravitySpec};

/// The hidden machine's error sources, with defaults typical of a 5–20 kg payload arm.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmTwinConfig {
    /// SD of each link length (a, d) and tool offset error, mm.
    pub length_sd_mm: f64,
    /// SD of each twist, β and joint offset error, degrees.
    pub angle_sd_deg: f64,
    /// Where the robot's base really is in the tracker's frame (x, y, z mm; roll,
    /// pitch, yaw degrees); the description's nominal base is only a guess of it.
    pub registration: [f64; 6],
    /// Compliance of every revolute joint, rad per N·m.
    pub compliance_rad_per_nm: f64,
    /// Mass of each link (at the middle of the link), kg.
    pub link_mass_kg: f64,
    /// Payload at the tool point, kg.
    pub payload_kg: f64,
    /// Lost motion of each joint's gear, degrees (mm for prismatic joints).
    pub backlash: f64,
    /// Linear expansion of the links, 1/K.
    pub expansion_per_k: f64,
    /// Temperature rise of the warm arm over its cold start, K.
    pub warm_rise_k: f64,
    /// Time constant of the warm-up, s.
    pub warm_time_s: f64,
    /// Time from one measured pose to the next (move, settle, measure), s.
    pub dwell_s: f64,
    /// The tracker's noise per axis, mm.
    pub tracker_sd_mm: f64,
    /// Measure the tool's orientation too (a 6-DoF probe), with this noise per axis in
    /// degrees; `None` measures position only, as a plain reflector does.
    pub orientation_sd_deg: Option<f64>,
    /// The temperature sensor's noise, K.
    pub thermometer_sd_k: f64,
    /// Share of each joint's range left out at either end when poses are drawn.
    pub limit_margin: f64,
    /// Machine-to-machine spread of the non-geometric constants: each machine seed draws
    /// its compliance, link mass, payload, backlash, expansion, warm rise and warm-up time
    /// as this config's value times a factor uniform in [1 − spread, 1 + spread] (0: every
    /// machine has the config's values; at most 0.9).
    pub spread: f64,
}

impl Default for ArmTwinConfig {
    fn default() -> ArmTwinConfig {
        ArmTwinConfig {
            length_sd_mm: 0.3,
            angle_sd_deg: 0.03,
            registration: [1800.0, -650.0, -420.0, 0.4, -0.3, 32.0],
            compliance_rad_per_nm: 2e-6,
            link_mass_kg: 3.0,
            payload_kg: 3.0,
            backlash: 0.006,
            expansion_per_k: 23e-6,
            warm_rise_k: 6.0,
            warm_time_s: 1800.0,
            dwell_s: 10.0,
            tracker_sd_mm: 0.015,
            orientation_sd_deg: None,
            thermometer_sd_k: 0.05,
            limit_margin: 0.1,
            spread: 0.3,
        }
    }
}

/// The hidden machine of a serial arm.
#[derive(Clone, Debug)]
pub struct ArmTwin {
    /// The arm as it really is, cold: geometric errors, the real registration, and its
    /// elastostatic model (the config's masses, payload and compliance) and every joint's
    /// lost motion (the config's backlash).
    pub truth: Arm,
    /// Its non-geometric sources.
    pub config: ArmTwinConfig,
}

/// A measured pose list with its hidden truth.
#[derive(Clone, Debug)]
pub struct ArmRun {
    /// What the tracker and the thermometer report, as a pose CSV holds it.
    pub poses: Vec<ArmPose>,
    /// The true tool point at each pose (no tracker noise), mm.
    pub truth: Vec<Point3<f64>>,
    /// The true tool point of the geometric model alone (cold, no load, no backlash),
    /// mm: what a perfect geometric calibration could reach.
    pub geometric: Vec<Point3<f64>>,
}

/// Names of the sensor channels a twin's pose CSV carries beyond joints and position.
pub const ARM_CHANNELS: [&str; 1] = ["temp_c"];

impl ArmTwin {
    /// Draws the hidden machine of `nominal` for `machine_seed`.
    pub fn draw(nominal: &Arm, machine_seed: u64, config: ArmTwinConfig) -> ArmTwin {
        let mut rng = ChaCha8Rng::seed_from_u64(machine_seed ^ 0x6172_6d5f_7477_696e);
        let mut values = nominal.values.clone();
        let joints = 5 * nominal.joints();
        let angle = config.angle_sd_deg.to_radians();
        for (i, v) in values.iter_mut().enumerate().take(joints + 12) {
            // The base is the tracker's registration, set below; the tool's orientation
            // does not move a tool point.
            if (joints..joints + 6).contains(&i) || i >= joints + 9 {
                continue;
            }
            let sd = if nominal.is_length(i) {
                config.length_sd_mm
            } else {
                angle
            };
            *v += gaussian(&mut rng, sd);
        }
        // Drawn after the geometric errors, so a machine seed keeps its geometry whatever
        // the spread.
        let mut config = config;
        let spread = config.spread.clamp(0.0, 0.9);
        for constant in [
            &mut config.compliance_rad_per_nm,
            &mut config.link_mass_kg,
            &mut config.payload_kg,
            &mut config.backlash,
            &mut config.expansion_per_k,
            &mut config.warm_rise_k,
            &mut config.warm_time_s,
        ] {
            *constant *= 1.0 + spread * (2.0 * rng.random::<f64>() - 1.0);
        }
        let r = config.registration;
        values[joints..joints + 6].copy_from_slice(&[
            r[0],
            r[1],
            r[2],
            r[3].to_radians(),
            r[4].to_radians(),
            r[5].to_radians(),
        ]);
        // The truth's load: the config's link masses at the links' middles, its payload
        // at the tool point, gravity along the base's −z, one compliance for every
        // revolute joint (whatever load model the description itself has).
        let load = GravitySpec {
            direction: [0.0, 0.0, -1.0],
            payload_kg: config.payload_kg,
            payload_com_mm: [0.0; 3],
        };
        let truth = nominal.rigid().with_values(values[..joints + 12].to_vec());
        let truth = truth
            .with_load(
                load,
                &vec![config.link_mass_kg; nominal.joints()],
                config.compliance_rad_per_nm,
            )
            .with_lost_motion(config.backlash);
        ArmTwin { truth, config }
    }

    /// Temperature of the arm above its cold start at time `t`, K.
    pub fn warming(&self, t: f64) -> f64 {
        self.config.warm_rise_k * (1.0 - (-t / self.config.warm_time_s).exp())
    }

    /// The true tool point at commanded joints `q`, time `t` and motion direction `dir`
    /// of each joint (+1 or −1: the side its gear's lost motion is taken up on).
    pub fn tool_point(&self, q: &[f64], t: f64, dir: &[f64]) -> Point3<f64> {
        Point3::from(self.tool_pose(q, t, dir).translation.vector)
    }

    /// The true tool pose at commanded joints `q`, time `t` and motion directions `dir`.
    pub fn tool_pose(&self, q: &[f64], t: f64, dir: &[f64]) -> Isometry3<f64> {
        let c = &self.config;
        let arm = &self.truth;
        // Thermal growth of every link length.
        let grow = 1.0 + c.expansion_per_k * self.warming(t);
        let mut values = arm.values.clone();
        let joints = 5 * arm.joints();
        for (i, v) in values.iter_mut().enumerate() {
            // The links and the tool grow; the base registration and a prismatic
            // joint's lost motion do not.
            let link = i < joints || (joints + 6..joints + 12).contains(&i);
            if arm.is_length(i) && link {
                *v *= grow;
            }
        }
        // The warm arm's lost motion puts each joint half its backlash toward the side
        // it last moved; its elastostatic model then turns each revolute joint by its
        // compliance times the gravity torque about its axis.
        arm.tool_pose_from(q, dir, &values)
    }

    /// Measures `count` static poses drawn uniformly inside the joint limits (less the
    /// margin), visited in the drawn order from a cold start, with seed `seed`.
    pub fn measure(&self, count: usize, seed: u64) -> ArmRun {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6172_6d5f_706f_7365);
        let spec = &self.truth.spec;
        let margin = self.config.limit_margin;
        let mut previous: Vec<f64> = spec.joint.iter().map(|j| j.min).collect();
        let mut dir = vec![1.0; spec.joint.len()];
        let rigid = self.truth.rigid();
        let (mut poses, mut truth, mut geometric) = (Vec::new(), Vec::new(), Vec::new());
        for n in 0..count {
            let t = n as f64 * self.config.dwell_s;
            let q = self
                .truth
                .at_shares(|_| margin + (1.0 - 2.0 * margin) * rng.random::<f64>());
            for i in 0..q.len() {
                if q[i] != previous[i] {
                    dir[i] = (q[i] - previous[i]).signum();
                }
            }
            previous.clone_from(&q);
            let pose = self.tool_pose(&q, t, &dir);
            let p = Point3::from(pose.translation.vector);
            let noise = Vector3::from_fn(|_, _| gaussian(&mut rng, self.config.tracker_sd_mm));
            let orientation = self.config.orientation_sd_deg.map(|sd| {
                let turn = Vector3::from_fn(|_, _| gaussian(&mut rng, sd.to_radians()));
                UnitQuaternion::from_scaled_axis(turn) * pose.rotation
            });
            let temp = 20.0 + self.warming(t) + gaussian(&mut rng, self.config.thermometer_sd_k);
            poses.push(ArmPose {
                stamp: t,
                joints: q.clone(),
                position: p + noise,
                orientation,
                channels: vec![temp],
                reading_sd: None,
                approach: Vec::new(),
            });
            truth.push(p);
            geometric.push(rigid.tool_position(&q));
        }
        // What the file says of the approach: its order (the first pose's is unknown).
        set_approach(&mut poses);
        ArmRun {
            poses,
            truth,
            geometric,
        }
    }
}
