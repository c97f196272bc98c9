//! Scoring a calibration: the split of a measurement set into the poses the EKF fits and
//! the poses held out to judge it, and a model's pose error at measured poses.

use nalgebra::Vector3;

use super::identify::Measurement;
use super::jacobian::twist;
use crate::robot::{Robot, RobotError};

/// `(kept, taken)`: the items of `all` at the positions `take` says, and the others,
/// each side in `all`'s order. Every hold-out below is one of these.
pub fn split_where<T: Clone>(all: &[T], take: impl Fn(usize) -> bool) -> (Vec<T>, Vec<T>) {
    let (taken, kept): (Vec<_>, Vec<_>) = all.iter().enumerate().partition(|(i, _)| take(*i));
    let clone = |v: Vec<(usize, &T)>| v.into_iter().map(|(_, m)| m.clone()).collect();
    (clone(kept), clone(taken))
}

/// `(fit, held out)`: every `every`-th measurement (or arm pose) is held out (none when `every` is 0).
pub fn hold_out<T: Clone>(all: &[T], every: usize) -> (Vec<T>, Vec<T>) {
    split_where(all, |i| every != 0 && (i + 1) % every == 0)
}

/// `(fit, held out)`: the measurements at positions `block` of the file's order are held
/// out (a stretch of time, a slab of a grid); the others are fitted, in order.
pub fn hold_out_block<T: Clone>(all: &[T], block: std::ops::Range<usize>) -> (Vec<T>, Vec<T>) {
    split_where(all, |i| block.contains(&i))
}

/// The positions of `all.len()` measurements drawn at random (`count` of them, seeded),
/// in ascending order: the same seed draws the same positions.
pub fn random_positions(len: usize, count: usize, seed: u64) -> Vec<usize> {
    use rand::seq::index::sample;
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut picked = sample(&mut rng, len, count.min(len)).into_vec();
    picked.sort_unstable();
    picked
}

/// `(fit, held out)`: `count` measurements drawn at random (seeded) are held out; both
/// sides keep the file's order.
pub fn hold_out_random<T: Clone>(all: &[T], count: usize, seed: u64) -> (Vec<T>, Vec<T>) {
    let held = random_positions(all.len(), count, seed);
    split_where(all, |i| held.binary_search(&i).is_ok())
}

/// Position (µm) and attitude (mdeg) error of `model`'s prediction of each measured
/// pose, in the tracker's frame through the model's registration.
pub fn pose_errors(model: &Robot, ms: &[Measurement]) -> Result<(Vec<f64>, Vec<f64>), RobotError> {
    let (mut p, mut a) = (Vec::new(), Vec::new());
    let mut guess = None;
    for m in ms {
        let (platform, tool) = model.forward(&m.joints, guess)?;
        guess = Some(platform);
        let d = twist(&(model.tracker_from_base() * tool), &m.pose);
        p.push(Vector3::new(d[0], d[1], d[2]).norm() * 1e3);
        a.push(Vector3::new(d[3], d[4], d[5]).norm().to_degrees() * 1e3);
    }
    Ok((p, a))
}
