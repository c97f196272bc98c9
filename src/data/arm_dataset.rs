//! A serial arm's pose files as a dataset for the residual models (docs/arms.md
//! "Residual models"). The graph has one node per joint, chained base to tool, and one
//! per extra sensor channel, joined to every joint. A "step" is one measured pose: the
//! window runs over the measurement order, not over time at a fixed rate.
//!
//! Features per node (F = 3): a joint's value, its change since the pose before (the
//! direction the joint came from: backlash), and the cosine of a revolute joint's angle
//! (0 for a prismatic one); a channel's value, its change since the pose before, and the
//! time since the file's first pose. Labels: the measured tool point minus the
//! calibrated model's (µm), and the orientation residual (mdeg) where the file has
//! orientation, else 0.

use super::dataset::{Dataset, DatasetError, Normalization, Prepared, FEATURES};
use super::windows::{SplitMode, WindowConfig};
use crate::graph::Graph;
use crate::robot::arm::{Arm, ArmPose, JointKind};

use super::arm_poses::ArmPoses;

/// The graph of an arm with `channels` extra sensor channels.
pub fn arm_graph(arm: &Arm, channels: &[String]) -> Graph {
    let n = arm.joints();
    let mut nodes: Vec<String> = arm.spec.joint.iter().map(|j| j.name.clone()).collect();
    nodes.extend(channels.iter().cloned());
    let mut edges: Vec<(usize, usize)> = (1..n).map(|j| (j - 1, j)).collect();
    for c in 0..channels.len() {
        edges.extend((0..n).map(|j| (j, n + c)));
    }
    Graph { nodes, edges }
}

/// The residual (µm, mdeg) of the measured pose `p` against `arm`'s prediction, and
/// the predicted tool axis.
pub fn arm_residual(arm: &Arm, p: &ArmPose) -> ([f64; 6], [f64; 3]) {
    let pose = arm.measured_pose(p);
    let d = (p.position.coords - pose.translation.vector) * 1e3;
    let r = p.orientation.map_or(nalgebra::Vector3::zeros(), |q| {
        (q * pose.rotation.inverse())
            .scaled_axis()
            .map(|a| a.to_degrees() * 1e3)
    });
    let axis = pose.rotation * nalgebra::Vector3::z();
    ([d.x, d.y, d.z, r.x, r.y, r.z], [axis.x, axis.y, axis.z])
}

/// Raw features and labels of one pose file under the calibrated `arm`; a channel's
/// third feature is the time since the file's first pose where `channel_time`, else 0.
pub fn prepare_arm(arm: &Arm, file: &ArmPoses, channel_time: bool) -> Prepared {
    let poses = &file.poses;
    let t0 = poses.first().map_or(0.0, |p| p.stamp);
    let mut features: Vec<[Vec<f64>; FEATURES]> = Vec::new();
    for (j, spec) in arm.spec.joint.iter().enumerate() {
        let q: Vec<f64> = poses.iter().map(|p| p.joints[j]).collect();
        let third = q
            .iter()
            .map(|v| match spec.kind {
                JointKind::Revolute => v.to_radians().cos(),
                JointKind::Prismatic => 0.0,
            })
            .collect();
        let side: Vec<f64> = change(&q)
            .iter()
            .map(|d| if *d == 0.0 { 0.0 } else { d.signum() })
            .collect();
        features.push([q.clone(), side, third]);
    }
    for c in 0..file.channels.len() {
        let v: Vec<f64> = poses.iter().map(|p| p.channels[c]).collect();
        let t = poses
            .iter()
            .map(|p| if channel_time { p.stamp - t0 } else { 0.0 })
            .collect();
        features.push([v.clone(), change(&v), t]);
    }
    let (labels, axes) = poses
        .iter()
        .map(|p| {
            let (label, axis) = arm_residual(arm, p);
            (Some(label), Some(axis))
        })
        .unzip();
    Prepared {
        features,
        labels,
        axes,
    }
}

/// Each value minus the one before (0 for the first).
fn change(v: &[f64]) -> Vec<f64> {
    (0..v.len())
        .map(|i| if i == 0 { 0.0 } else { v[i] - v[i - 1] })
        .collect()
}

/// The graph and dataset of pose files (each with its name) under the calibrated
/// `arm`, windowed and split as `window` and `mode` say; standardised with `fixed`
/// statistics where given, else with the training split's. Every file must carry the
/// same channels and fit the arm. `channel_time`: as [`prepare_arm`].
pub fn arm_dataset(
    arm: &Arm,
    files: &[(String, ArmPoses)],
    window: &WindowConfig,
    mode: SplitMode,
    fixed: Option<&Normalization>,
    channel_time: bool,
) -> Result<(Graph, Dataset), DatasetError> {
    let err = |file: &str, message: String| DatasetError {
        file: file.to_string(),
        message,
    };
    let Some((_, first)) = files.first() else {
        return Err(err("dataset", "no pose file".into()));
    };
    let mut prepared = Vec::with_capacity(files.len());
    for (name, f) in files {
        if f.channels != first.channels {
            return Err(err(
                name,
                format!(
                    "channels {:?}, where the first file has {:?}: every file must carry the same",
                    f.channels, first.channels
                ),
            ));
        }
        if let Some(i) = f.poses.iter().position(|p| p.joints.len() != arm.joints()) {
            return Err(err(
                name,
                format!(
                    "pose {i} has {} joint values, the arm {} joints",
                    f.poses[i].joints.len(),
                    arm.joints()
                ),
            ));
        }
        prepared.push((name.clone(), prepare_arm(arm, f, channel_time)));
    }
    let graph = arm_graph(arm, &first.channels);
    let data = Dataset::from_prepared(&prepared, &graph.nodes, window, mode, fixed)?;
    Ok((graph, data))
}
