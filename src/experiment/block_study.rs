//! How a calibration holds on a held-out stretch of a pose file (docs/arms.md "Time: does
//! a calibration hold?"). A block of the file's order (the last days of a campaign, a slab
//! of a grid swept in slabs) is held out and scored against two references on the same
//! poses: random hold-outs of the same size, which score each pose with fitted poses
//! all around it in space and in time (what the block's region costs anyway), and the
//! block's own calibration re-registered on poses spread over the block (what a tracker
//! or probe that moved explains). Along the block, in parts of equal size, the course of
//! each in time.

use std::ops::Range;

use super::parallel::run_all;
use crate::calibrate::arm::{
    arm_orientation_errors, arm_position_errors, calibrate_arm, reregister, ArmCalibration,
    ArmCalibrationConfig, ArmCalibrationError,
};
use crate::calibrate::{random_positions, split_where};
use crate::robot::arm::{Arm, ArmPose};
use crate::stats::Summary;

/// What the study compares the block with.
#[derive(Clone, Copy, Debug)]
pub struct BlockStudyConfig {
    /// Random hold-outs of the block's size, seeds 1, 2, …
    pub random_splits: usize,
    /// Re-register the block's calibration on this many poses spread evenly over the
    /// block, and score both on the block's other poses (0: not).
    pub reregister: usize,
    /// Parts of equal size the block is cut into, in the file's order.
    pub parts: usize,
}

/// One random hold-out of the block's size.
#[derive(Clone, Debug)]
pub struct RandomHoldOut {
    /// Its seed.
    pub seed: u64,
    /// Mean position error on every pose it held out, µm.
    pub all_um: f64,
    /// Mean position error on the poses it held out inside the block, µm; `None` when it
    /// held out none there.
    pub block_um: Option<f64>,
    /// Mean orientation error on them, mdeg, where the poses have orientation.
    pub block_mdeg: Option<f64>,
    /// How many of the block's poses it held out.
    pub block_poses: usize,
}

/// The block's calibration re-registered on poses spread evenly over the block.
#[derive(Clone, Debug)]
pub struct BlockReregistration {
    /// Poses re-registered on (every k-th of the block).
    pub fitted: usize,
    /// The block's calibration on the block's other poses: position (µm), orientation
    /// (mdeg).
    pub before: (Summary, Option<Summary>),
    /// Re-registered, on the same poses.
    pub after: (Summary, Option<Summary>),
}

/// One part of the block, in the file's order.
#[derive(Clone, Debug)]
pub struct BlockPart {
    /// Positions in the file.
    pub poses: Range<usize>,
    /// The first and last pose's stamp (time, s, or pose number).
    pub stamps: (f64, f64),
    /// Mean position error of the block's calibration, µm.
    pub block_um: f64,
    /// Mean over the random hold-outs of each one's mean on the part's poses it held out,
    /// µm (`None` when none held out any).
    pub random_um: Option<f64>,
    /// The re-registered calibration's mean on the part's poses it was not fitted on, µm.
    pub reregistered_um: Option<f64>,
}

/// The study's result.
#[derive(Clone, Debug)]
pub struct BlockStudy {
    /// The block's positions in the file.
    pub block: Range<usize>,
    /// The block's calibration on the block: position (µm), orientation (mdeg).
    /// (`None` for an empty block.)
    pub block_errors: (Option<Summary>, Option<Summary>),
    /// The random hold-outs, in seed order.
    pub random: Vec<RandomHoldOut>,
    /// The re-registration, when asked for.
    pub reregistered: Option<BlockReregistration>,
    /// The block in parts.
    pub parts: Vec<BlockPart>,
}

/// Position (µm) and orientation (mdeg) errors of `arm` at each of `poses`; the second
/// is empty without orientation.
fn errors(arm: &Arm, poses: &[ArmPose]) -> (Vec<f64>, Vec<f64>) {
    let scale = |v: Vec<f64>| v.into_iter().map(|e| e * 1e3).collect();
    (
        scale(arm_position_errors(arm, poses)),
        scale(arm_orientation_errors(arm, poses)),
    )
}

fn mean(v: &[f64]) -> Option<f64> {
    Summary::of(v).map(|s| s.mean)
}

/// Studies `calibrated`, the calibration of `nominal` on `poses` outside `block` (what
/// `calibrate --hold-out-block` fits), on the block. `calibrated` is taken, not fitted
/// again; the random hold-outs are fitted here, on every core.
pub fn block_study(
    nominal: &Arm,
    poses: &[ArmPose],
    block: Range<usize>,
    calibrated: &ArmCalibration,
    config: &BlockStudyConfig,
) -> Result<BlockStudy, ArmCalibrationError> {
    let c = ArmCalibrationConfig::default();
    let block = block.start.min(poses.len())..block.end.min(poses.len());
    let in_block = &poses[block.clone()];
    let (block_um, block_mdeg) = errors(&calibrated.arm, in_block);
    // Each random hold-out: its seed's positions, its fit, its errors at those positions.
    let seeds: Vec<u64> = (1..=config.random_splits as u64).collect();
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let random_fits = run_all(
        seeds,
        workers,
        |seed, _tick: &dyn Fn()| {
            // The same draw as `calibrate --hold-out-random` of as many poses.
            let held = random_positions(poses.len(), block.len(), seed);
            let (fit, held_poses) = split_where(poses, |i| held.binary_search(&i).is_ok());
            let cal = calibrate_arm(nominal, &fit, &c)?;
            let (um, mdeg) = errors(&cal.arm, &held_poses);
            Ok::<_, ArmCalibrationError>((seed, held, um, mdeg))
        },
        || {},
    )?;
    let random = random_fits
        .iter()
        .map(|(seed, held, um, mdeg)| {
            let inside: Vec<usize> = (0..held.len())
                .filter(|&k| block.contains(&held[k]))
                .collect();
            let pick = |v: &[f64]| -> Vec<f64> {
                inside.iter().filter_map(|&k| v.get(k).copied()).collect()
            };
            RandomHoldOut {
                seed: *seed,
                all_um: mean(um).unwrap_or(f64::NAN),
                block_um: mean(&pick(um)),
                block_mdeg: mean(&pick(mdeg)),
                block_poses: inside.len(),
            }
        })
        .collect();
    // The re-registration's poses, spread evenly over the block (a stretch of a grid
    // swept in slabs starts in one corner of the workspace: its first poses alone leave
    // the placement's rotation ill-determined).
    let fitted = config.reregister.min(in_block.len());
    let mut refit = vec![false; in_block.len()];
    (0..fitted).for_each(|k| refit[k * in_block.len() / fitted.max(1)] = true);
    let kept = |v: &[f64]| -> Vec<f64> {
        v.iter()
            .zip(&refit)
            .filter(|(_, &r)| !r)
            .map(|(e, _)| *e)
            .collect()
    };
    let moved = if fitted > 0 {
        let (_, on) = split_where(in_block, |k| refit[k]);
        Some(reregister(&calibrated.arm, &on, &c)?)
    } else {
        None
    };
    // Errors at every pose of the block; the refitted ones are left out of every mean.
    let reregistered_errors = moved.as_ref().map(|m| errors(&m.arm, in_block));
    let reregistered = reregistered_errors.as_ref().and_then(|(um, mdeg)| {
        Some(BlockReregistration {
            fitted,
            before: (
                Summary::of(&kept(&block_um))?,
                Summary::of(&kept(&block_mdeg)),
            ),
            after: (Summary::of(&kept(um))?, Summary::of(&kept(mdeg))),
        })
    });
    // As many parts as asked, at most one per pose (none for an empty block).
    let parts = config.parts.max(1).min(block.len());
    let parts = (0..parts)
        .map(|k| {
            let local = k * block.len() / parts..(k + 1) * block.len() / parts;
            let range = block.start + local.start..block.start + local.end;
            let random_means: Vec<f64> = random_fits
                .iter()
                .filter_map(|(_, held, um, _)| {
                    let v: Vec<f64> = (0..held.len())
                        .filter(|&j| range.contains(&held[j]))
                        .map(|j| um[j])
                        .collect();
                    mean(&v)
                })
                .collect();
            let reregistered_um = reregistered_errors.as_ref().and_then(|(um, _)| {
                let v: Vec<f64> = local
                    .clone()
                    .filter(|&k| !refit[k])
                    .map(|k| um[k])
                    .collect();
                mean(&v)
            });
            BlockPart {
                stamps: (poses[range.start].stamp, poses[range.end - 1].stamp),
                block_um: mean(&block_um[local.clone()]).unwrap_or(f64::NAN),
                random_um: mean(&random_means),
                reregistered_um,
                poses: range,
            }
        })
        .collect();
    Ok(BlockStudy {
        block,
        block_errors: (Summary::of(&block_um), Summary::of(&block_mdeg)),
        random,
        reregistered,
        parts,
    })
}
