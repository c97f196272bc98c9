//! The native CPU path's arithmetic in f32, shared by the ST block's steps
//! (`model::block`) and the native networks (`model::native`): the matrix products
//! (`product/`: a strided [`gemm`] and its split over threads), and the element-wise
//! functions that must vectorise and give the same bits at every SIMD width (a libm-free
//! [`exp`], [`sigmoid`], [`tanh`], the softmaxes, [`lanes_dot`] and [`lanes_sum`]'s fixed
//! partial sums), and [`flushing_subnormals`], which every pass runs under.
//!
//! Every contraction is a [`gemm`] on a strided view of the row-major tensors (no copies,
//! no transposes): in training the `gemm` crate's, in the predictor's forward an in-place
//! kernel that allocates nothing (`product/in_place.rs`). f32 arithmetic is never reassociated or
//! contracted, and the sums that must vectorise use [`lanes_sum`]'s fixed partial sums,
//! so every SIMD width gives the same bits. Every pass runs with subnormal f32 values
//! flushed to zero: trained weights and attention scores drift into the subnormal range,
//! where x86 arithmetic takes a microcode assist per operation.

mod product;

pub use product::product_for_bench;
pub(crate) use product::{
    gemm, par_gemm, rows, transposed, with_products, Products, View, PAR_MIN_MACS,
};

/// Runs `f` with subnormal f32 inputs read as zero and subnormal results flushed to zero
/// on this thread (x86-64 MXCSR's DAZ and FTZ bits), then restores the thread's mode,
/// also when `f` panics. Values below 1.2e-38 carry no information at the scale of the
/// network's activations and gradients, and the device schedule may flush them too; on
/// other architectures `f` runs unchanged.
#[inline]
pub(crate) fn flushing_subnormals<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        /// MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6).
        const FTZ_DAZ: u32 = (1 << 15) | (1 << 6);
        /// Puts the saved MXCSR back when dropped.
        struct Restore(u32);
        impl Drop for Restore {
            fn drop(&mut self) {
                // SAFETY: SSE is part of x86-64; this writes back the value read below.
                #[allow(deprecated)]
                unsafe {
                    std::arch::x86_64::_mm_setcsr(self.0)
                }
            }
        }
        // SAFETY: SSE is part of x86-64; FTZ and DAZ change only how subnormal f32
        // values are read and written, on this thread, until `Restore` drops.
        #[allow(deprecated)]
        let _restore = unsafe {
            let saved = std::arch::x86_64::_mm_getcsr();
            std::arch::x86_64::_mm_setcsr(saved | FTZ_DAZ);
            Restore(saved)
        };
        f()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        f()
    }
}

/// Partial sums of [`lanes_dot`] and [`lanes_sum`].
pub(crate) const LANES: usize = 16;

/// Σ a[j]·b[j] as 16 interleaved partial sums (element j into sum j mod 16) added in a
/// fixed order at the end, so that the loop vectorises (a plain `sum()` stays a scalar
/// chain: f32 addition is not reassociated) and the result is the same at any SIMD width.
#[inline(always)]
pub(crate) fn lanes_dot(a: &[f32], b: &[f32]) -> f32 {
    debug_assert_eq!(a.len(), b.len());
    let (a_body, a_tail) = a.as_chunks::<LANES>();
    let (b_body, b_tail) = b.as_chunks::<LANES>();
    let mut acc = [0f32; LANES];
    for (x, y) in a_body.iter().zip(b_body) {
        for j in 0..LANES {
            acc[j] += x[j] * y[j];
        }
    }
    let tail: f32 = a_tail.iter().zip(b_tail).map(|(x, y)| x * y).sum();
    acc.iter().sum::<f32>() + tail
}

/// Σ a[j] in the order of [`lanes_dot`].
#[inline(always)]
pub(crate) fn lanes_sum(a: &[f32]) -> f32 {
    let (body, tail) = a.as_chunks::<LANES>();
    let mut acc = [0f32; LANES];
    for x in body {
        for j in 0..LANES {
            acc[j] += x[j];
        }
    }
    acc.iter().sum::<f32>() + tail.iter().sum::<f32>()
}

/// e^x in f32 without a libm call, so that loops over slices vectorise: x = n·ln 2 + r
/// with |r| ≤ ln 2 / 2, e^r by Cephes' degree-6 polynomial (`expf`), times 2^n built in
/// the exponent bits. Relative error below 2e-7 on [−87, 88]; inputs are clamped to that
/// range (e^x ≈ 1e−38 below, 2e38 above: what a sigmoid, tanh or softmax needs) and NaN
/// stays NaN. libm's `expf`, called once per element, took 9–15 % of a demo-shape
/// forward or training step and kept the loops around it scalar.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 in two parts: `n·LN2_HI` is exact for |n| < 2^9.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // 1.5·2^23: adding and subtracting it rounds to the nearest integer.
    const ROUND: f32 = 12_582_912.0;
    let c = x.clamp(-87.0, 88.0);
    // n + ROUND holds n in its low mantissa bits: 2^n is built from them with integer
    // operations (a float-to-int cast would not vectorise).
    let shifted = c * LOG2E + ROUND;
    let n = shifted - ROUND;
    let r = c - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let er = p * r * r + r + 1.0;
    let scale = f32::from_bits(shifted.to_bits().wrapping_sub(ROUND.to_bits() - 127) << 23);
    if x.is_nan() {
        x
    } else {
        er * scale
    }
}

/// σ(x) = 1 / (1 + e^−x).
#[inline(always)]
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// tanh(x) = 2σ(2x) − 1: one `exp`; absolute error below 2e-7.
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    2.0 * sigmoid(2.0 * x) - 1.0
}

/// Softmax of each contiguous `len`-long row of `x`, in place, max-subtracted.
#[inline(always)]
pub(crate) fn softmax_rows(x: &mut [f32], len: usize) {
    for row in x.chunks_mut(len) {
        let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        for v in row.iter_mut() {
            *v = exp(*v - max);
        }
        let sum: f32 = row.iter().sum();
        for v in row.iter_mut() {
            *v /= sum;
        }
    }
}

/// Softmax of each column of the row-major `[rows, cols]` matrix `x`, in place,
/// max-subtracted: the column's values in row order, as a loop down each column would
/// take them, but row by row so that the work runs along contiguous rows.
#[inline(always)]
pub(crate) fn softmax_columns(x: &mut [f32], cols: usize, max: &mut [f32], sum: &mut [f32]) {
    max.fill(f32::NEG_INFINITY);
    sum.fill(0.0);
    for row in x.chunks(cols) {
        for (m, v) in max.iter_mut().zip(row) {
            *m = m.max(*v);
        }
    }
    for row in x.chunks_mut(cols) {
        for ((v, m), s) in row.iter_mut().zip(max.iter()).zip(sum.iter_mut()) {
            *v = exp(*v - m);
            *s += *v;
        }
    }
    for row in x.chunks_mut(cols) {
        for (v, s) in row.iter_mut().zip(sum.iter()) {
            *v /= s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_is_within_2e_7_of_f64_and_keeps_nan() {
        let mut worst = 0f64;
        for i in 0..=200_000 {
            let x = -87.0 + 175.0 * i as f32 / 200_000.0;
            let want = (x as f64).exp();
            worst = worst.max(((exp(x) as f64) - want).abs() / want);
        }
        assert!(worst < 2e-7, "relative error {worst:e}");
        assert!(exp(f32::NAN).is_nan());
        // Clamped far out, never 0 or ∞: what σ and softmax need.
        assert!(exp(-1e4) > 0.0 && exp(-1e4) < 1e-37);
        assert!(exp(1e4).is_finite() && exp(1e4) > 1e38);
        assert!(sigmoid(-1e4) >= 0.0 && sigmoid(1e4) == 1.0 && tanh(-1e4) == -1.0);
    }

    #[test]
    fn lane_sums_follow_their_documented_order() {
        for len in [0, 1, 15, 16, 17, 48, 100] {
            let a: Vec<f32> = (0..len)
                .map(|i| ((i * 29 % 13) as f32 - 6.0) * 0.37)
                .collect();
            let b: Vec<f32> = (0..len)
                .map(|i| ((i * 17 % 7) as f32 - 3.0) * 1.3)
                .collect();
            // Lane j sums elements j, j + 16, … of the whole chunks in order; the lanes
            // are added first to last, then the tail in order.
            let body = len / LANES * LANES;
            let ordered = |f: &dyn Fn(usize) -> f32| {
                let mut lanes = [0f32; LANES];
                for i in 0..body {
                    lanes[i % LANES] += f(i);
                }
                let tail: f32 = (body..len).map(f).sum();
                lanes.iter().sum::<f32>() + tail
            };
            let want_dot = ordered(&|i| a[i] * b[i]);
            let want_sum = ordered(&|i| a[i]);
            assert_eq!(
                lanes_dot(&a, &b).to_bits(),
                want_dot.to_bits(),
                "dot, {len}"
            );
            assert_eq!(lanes_sum(&a).to_bits(), want_sum.to_bits(), "sum, {len}");
            let exact: f64 = a.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            assert!((lanes_dot(&a, &b) as f64 - exact).abs() < 1e-4, "{len}");
        }
    }

    #[test]
    fn softmax_of_columns_equals_softmax_down_each_column() {
        let (rows_n, cols) = (7, 5);
        let x: Vec<f32> = (0..rows_n * cols)
            .map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.7)
            .collect();
        let mut got = x.clone();
        softmax_columns(&mut got, cols, &mut [0.0; 5], &mut [0.0; 5]);
        for j in 0..cols {
            let col: Vec<f64> = (0..rows_n).map(|i| x[i * cols + j] as f64).collect();
            let max = col.iter().cloned().fold(f64::MIN, f64::max);
            let sum: f64 = col.iter().map(|v| (v - max).exp()).sum();
            for i in 0..rows_n {
                let want = (col[i] - max).exp() / sum;
                assert!((got[i * cols + j] as f64 - want).abs() < 1e-6, "({i}, {j})");
            }
        }
        let mut rows_x = x.clone();
        softmax_rows(&mut rows_x, cols);
        for row in rows_x.chunks(cols) {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        }
    }
}
