//! Does a calibration hold on a held-out stretch of a pose file (docs/arms.md "Time: does
//! a calibration hold?"): the hold-outs `calibrate --hold-out-block` and
//! `--hold-out-random` make, and `experiment::block_study` on the serial twin, with a
//! tracker that stays and one that is moved in the middle of the file.

mod common;

use iastgcn::calibrate::arm::{calibrate_arm, ArmCalibrationConfig};
use iastgcn::experiment::block_study::{block_study, BlockStudyConfig};
use iastgcn::experiment::calibration::HoldOut;
use iastgcn::robot::arm::{Arm, ArmPose};
use iastgcn::twin::arm::{ArmTwin, ArmTwinConfig};

#[test]
fn hold_outs_take_the_poses_they_say() {
    let all: Vec<usize> = (0..200).collect();
    // A block in per cent of the file's order, rounded to the nearest pose.
    let block = HoldOut::Block {
        from_percent: 70.0,
        to_percent: 100.0,
    };
    let (fit, held) = block.split(&all).unwrap();
    assert_eq!(fit, (0..140).collect::<Vec<_>>());
    assert_eq!(held, (140..200).collect::<Vec<_>>());
    assert_eq!(HoldOut::block_range(11911, 70.0, 100.0), 8338..11911);
    assert_eq!(HoldOut::block_range(7, 10.0, 50.0), 1..4);
    // At random: as many as asked, every pose on one side, both sides in the file's
    // order, the same seed the same poses, another seed others.
    let random = |seed| HoldOut::Random {
        percent: 30.0,
        seed,
    };
    let (fit, held) = random(1).split(&all).unwrap();
    assert_eq!(held.len(), 60);
    assert_eq!(fit.len(), 140);
    assert!(held.windows(2).all(|w| w[0] < w[1]) && fit.windows(2).all(|w| w[0] < w[1]));
    let mut both: Vec<usize> = fit.iter().chain(&held).copied().collect();
    both.sort_unstable();
    assert_eq!(both, all);
    assert_eq!(random(1).split(&all).unwrap().1, held);
    assert_ne!(random(2).split(&all).unwrap().1, held);
    // What is not a stretch or a share is refused, saying what it must be.
    for bad in [
        HoldOut::Block {
            from_percent: 50.0,
            to_percent: 50.0,
        },
        HoldOut::Block {
            from_percent: -5.0,
            to_percent: 20.0,
        },
        HoldOut::Block {
            from_percent: 80.0,
            to_percent: 120.0,
        },
    ] {
        let e = bad.split(&all).unwrap_err().to_string();
        assert!(e.contains("within 0 to 100 %"), "{e}");
    }
    for percent in [0.0, 100.0, f64::NAN] {
        let e = HoldOut::Random { percent, seed: 1 }
            .split(&all)
            .unwrap_err()
            .to_string();
        assert!(e.contains("above 0 and below 100"), "{e}");
    }
}

/// The serial twin of the UR5 with geometric errors only and 15 µm, 0.002° of tracker
/// noise; `registration` places its tracker.
fn twin(registration: Option<[f64; 6]>) -> ArmTwin {
    let config = common::geometric_twin_config();
    let config = match registration {
        Some(registration) => ArmTwinConfig {
            registration,
            ..config
        },
        None => config,
    };
    ArmTwin::draw(&nominal(), 7, config)
}

fn nominal() -> Arm {
    common::ur5()
}

/// Calibrates on the poses outside the last 30 % and studies that block.
fn study_last_30(poses: &[ArmPose]) -> iastgcn::experiment::block_study::BlockStudy {
    let nominal = nominal();
    let hold = HoldOut::Block {
        from_percent: 70.0,
        to_percent: 100.0,
    };
    let (fit, _) = hold.split(poses).unwrap();
    let cal = calibrate_arm(&nominal, &fit, &ArmCalibrationConfig::default()).unwrap();
    let config = BlockStudyConfig {
        random_splits: 3,
        reregister: 40,
        parts: 3,
    };
    let block = HoldOut::block_range(poses.len(), 70.0, 100.0);
    block_study(&nominal, poses, block, &cal, &config).unwrap()
}

#[test]
fn a_held_out_block_is_scored_against_random_hold_outs_and_a_moved_tracker_is_found() {
    // A tracker that stays: the last 30 % cost what the same poses cost held out at
    // random (the twin does not drift), and re-registering on them changes nothing.
    let poses = twin(None).measure(400, 1).poses;
    let steady = study_last_30(&poses);
    assert_eq!(steady.block, 280..400);
    let block_um = steady.block_errors.0.as_ref().unwrap().mean;
    let random: Vec<f64> = steady.random.iter().filter_map(|r| r.block_um).collect();
    assert_eq!(random.len(), 3);
    assert!(steady.random.iter().all(|r| r.block_poses > 10));
    let random_um = random.iter().sum::<f64>() / 3.0;
    // The calibration leaves about the noise (15 µm a coordinate, 26 µm a point;
    // measured 24.5 µm on the block, 21.9–24.9 at random).
    assert!(block_um < 40.0, "the block: {block_um:.1} µm");
    assert!(
        (block_um - random_um).abs() < 0.3 * random_um,
        "the block {block_um:.1} µm against {random_um:.1} at random"
    );
    let r = steady.reregistered.as_ref().unwrap();
    assert_eq!((r.fitted, r.after.0.count), (40, 80));
    assert!(
        r.after.0.mean < 1.3 * r.before.0.mean,
        "re-registered {:.1} against {:.1} µm",
        r.after.0.mean,
        r.before.0.mean
    );
    assert_eq!(steady.parts.len(), 3);
    assert_eq!(steady.parts[0].poses, 280..320);
    assert_eq!(steady.parts[2].poses, 360..400);
    // The same parts average to the block's mean.
    let parts = steady.parts.iter().map(|p| p.block_um).sum::<f64>() / 3.0;
    assert!((parts - block_um).abs() < 1e-6 * block_um);

    // The tracker moved (2 mm and 0.05°) before the last 30 %: the block misses by about
    // the move, far more than the random hold-outs on the same poses, and re-registering
    // on 40 of its poses brings the other 80 back to the noise.
    let mut moved = twin(None).measure(280, 1).poses;
    let base = twin(None).config.registration;
    let shifted = [
        base[0] + 2.0,
        base[1],
        base[2],
        base[3],
        base[4],
        base[5] + 0.05,
    ];
    moved.extend(twin(Some(shifted)).measure(120, 2).poses);
    let bumped = study_last_30(&moved);
    let before = bumped.reregistered.as_ref().unwrap().before.0.mean;
    let after = bumped.reregistered.as_ref().unwrap().after.0.mean;
    assert!(before > 1000.0, "the moved tracker: {before:.1} µm");
    // (Measured: 2050.8 µm before, 25.5 after.)
    assert!(
        after < 40.0,
        "re-registered: {after:.1} µm (before {before:.1})"
    );
    assert!(bumped
        .parts
        .iter()
        .all(|p| p.reregistered_um.unwrap() < 40.0));
}
