//! Kernel test support: seeded random data, central finite differences in f64, and
//! comparisons that report the worst element. Used by `tests/`, by the unit tests of
//! `model`, and by [`crate::smoke`], the device check behind `iastgcn smoke`.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::gpu::{Gpu, Tensor};

/// The seeded generator every test uses.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// `n` values uniform in `[lo, hi)`.
pub fn uniform(rng: &mut ChaCha8Rng, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

/// `n` values with `margin <= |x| < hi`, for functions with a kink at 0 (ReLU), so a
/// finite difference never straddles it.
pub fn away_from_zero(rng: &mut ChaCha8Rng, n: usize, margin: f64, hi: f64) -> Vec<f64> {
    (0..n)
        .map(|_| {
            let m = rng.random_range(margin..hi);
            if rng.random_bool(0.5) {
                m
            } else {
                -m
            }
        })
        .collect()
}

/// Rounds to f32, the precision the GPU sees. References are then evaluated on the
/// rounded values so the comparison measures the kernel, not the input rounding.
pub fn round_f32(x: &[f64]) -> Vec<f64> {
    x.iter().map(|&v| v as f32 as f64).collect()
}

/// Converts to f32 (rounding to nearest), for uploading host data to a tensor.
pub fn to_f32(x: &[f64]) -> Vec<f32> {
    x.iter().map(|&v| v as f32).collect()
}

/// `Σ_i a[i]·b[i]` over the shorter length, e.g. a scalar loss `⟨dy, y⟩` for gradient
/// checks.
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Central differences `(f(x + h e_i) − f(x − h e_i)) / 2h` of a scalar function.
pub fn central_difference(mut f: impl FnMut(&[f64]) -> f64, x: &[f64], h: f64) -> Vec<f64> {
    let mut xp = x.to_vec();
    (0..x.len())
        .map(|i| {
            let x0 = xp[i];
            xp[i] = x0 + h;
            let up = f(&xp);
            xp[i] = x0 - h;
            let down = f(&xp);
            xp[i] = x0;
            (up - down) / (2.0 * h)
        })
        .collect()
}

/// Element `i` passes when `|actual − expected| <= abs + rel·|expected|`.
#[derive(Clone, Copy, Debug)]
pub struct Tolerance {
    /// The absolute part, in the compared values' units.
    pub abs: f64,
    /// The relative part, a fraction of `|expected|`.
    pub rel: f64,
}

impl Tolerance {
    /// `abs + rel·|expected|`.
    pub const fn new(abs: f64, rel: f64) -> Tolerance {
        Tolerance { abs, rel }
    }
}

/// The element that came closest to (or went furthest past) its tolerance.
#[derive(Clone, Debug)]
pub struct Worst {
    /// Its flat index in the compared slices.
    pub index: usize,
    /// The value computed (by the kernel under test).
    pub actual: f64,
    /// The reference value.
    pub expected: f64,
    /// `|actual − expected|`.
    pub abs_err: f64,
    /// `abs_err / |expected|` (the denominator at least `f64::MIN_POSITIVE`).
    pub rel_err: f64,
    /// Error divided by the element's tolerance: ≤ 1 passes.
    pub ratio: f64,
}

impl std::fmt::Display for Worst {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "worst element {}: got {:.9e}, expected {:.9e}, abs err {:.3e}, rel err {:.3e} ({:.2} of tolerance)",
            self.index, self.actual, self.expected, self.abs_err, self.rel_err, self.ratio
        )
    }
}

/// Compares element by element; `Err` names `what` and shows the worst element (a
/// non-finite `actual` or `expected`, or a length mismatch, always fails: a NaN in a
/// reference is a broken reference, not a pass).
pub fn compare(
    what: &str,
    actual: &[f64],
    expected: &[f64],
    tol: Tolerance,
) -> Result<Worst, String> {
    let worst = worst(what, actual, expected, tol)?;
    if worst.ratio <= 1.0 {
        Ok(worst)
    } else {
        Err(format!(
            "{what}: {worst} (tolerance abs {:.1e} + rel {:.1e})",
            tol.abs, tol.rel
        ))
    }
}

/// The element that came closest to (or went furthest past) its tolerance, whether or
/// not it passes (a non-finite `actual` or `expected` has ratio ∞); `Err` names `what`
/// only when the lengths differ or there is nothing to compare.
pub fn worst(
    what: &str,
    actual: &[f64],
    expected: &[f64],
    tol: Tolerance,
) -> Result<Worst, String> {
    if actual.len() != expected.len() {
        return Err(format!(
            "{what}: {} elements, expected {}",
            actual.len(),
            expected.len()
        ));
    }
    if expected.is_empty() {
        return Err(format!("{what}: nothing to compare"));
    }
    let mut worst: Option<Worst> = None;
    for (i, (&a, &e)) in actual.iter().zip(expected).enumerate() {
        let abs_err = (a - e).abs();
        let ratio = if !(a.is_finite() && e.is_finite()) {
            f64::INFINITY
        } else if abs_err == 0.0 {
            // Exact checks use a zero tolerance.
            0.0
        } else {
            abs_err / (tol.abs + tol.rel * e.abs())
        };
        if worst.as_ref().is_none_or(|w| ratio > w.ratio) {
            worst = Some(Worst {
                index: i,
                actual: a,
                expected: e,
                abs_err,
                rel_err: abs_err / e.abs().max(f64::MIN_POSITIVE),
                ratio,
            });
        }
    }
    // invariant: the empty case returned above.
    Ok(worst.expect("non-empty"))
}

/// Reads a tensor back and compares it with an f64 reference.
pub fn compare_tensor(
    gpu: &Gpu,
    what: &str,
    tensor: &Tensor,
    expected: &[f64],
    tol: Tolerance,
) -> Result<Worst, String> {
    let got = gpu.read_f32(tensor).map_err(|e| format!("{what}: {e}"))?;
    let got: Vec<f64> = got[..tensor.numel()].iter().map(|&v| v as f64).collect();
    compare(what, &got, expected, tol)
}

/// Checks an analytic gradient of `loss` at `x` against central differences (step `h`).
pub fn check_gradient(
    what: &str,
    analytic: &[f64],
    loss: impl FnMut(&[f64]) -> f64,
    x: &[f64],
    h: f64,
    tol: Tolerance,
) -> Result<Worst, String> {
    let numeric = central_difference(loss, x, h);
    compare(what, analytic, &numeric, tol)
}

/// Opens the default adapter or panics with the install hint (tests only).
pub fn gpu() -> Gpu {
    // invariant: test support: a test without a device fails with the reason.
    Gpu::new().unwrap_or_else(|e| panic!("{e}"))
}

#[cfg(test)]
mod tests {
    use super::{compare, Tolerance};

    const TOL: Tolerance = Tolerance {
        abs: 1e-6,
        rel: 1e-6,
    };

    #[test]
    fn a_nan_or_infinity_anywhere_fails_the_comparison() {
        let good = [1.0, 2.0, 3.0];
        assert!(compare("ok", &good, &good, TOL).is_ok());
        for bad in [f64::NAN, f64::INFINITY] {
            for i in 0..3 {
                let mut v = good;
                v[i] = bad;
                assert!(compare("expected", &good, &v, TOL).is_err(), "{bad} at {i}");
                assert!(compare("actual", &v, &good, TOL).is_err(), "{bad} at {i}");
            }
        }
    }

    #[test]
    fn the_worst_element_past_its_tolerance_is_named() {
        let err = compare("x", &[1.0, 2.1, 3.0], &[1.0, 2.0, 3.0], TOL).unwrap_err();
        assert!(err.starts_with("x: worst element 1:"), "{err}");
        assert!(compare("x", &[1.0, 2.0 + 1e-7], &[1.0, 2.0], TOL).is_ok());
    }
}
