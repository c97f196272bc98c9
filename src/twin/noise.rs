//! Seeded noise draws shared by the truth model and the instruments.

use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

/// A normal draw with standard deviation `sigma`.
pub fn gaussian<R: Rng + ?Sized>(rng: &mut R, sigma: f64) -> f64 {
    let z: f64 = rng.sample(StandardNormal);
    sigma * z
}
