//! The IASTGCN variants on the CPU in f32, with no device: the inference forward, one
//! window at a time (the controller's latency path where the only adapter is a CPU, or
//! there is none; [`super::Predictor`] picks it on its own, docs/performance.md "The
//! native CPU forward"), and training (`train::Trainer` picks it on a CPU adapter,
//! docs/performance.md "Native CPU training").
//!
//! Both compute docs/model.md's steps 1–7 and the head in the order of the device
//! schedule: X_t = X·(E' + I), the spatial attention folded into Q = Ψ·(I + S') and
//! M = Q·X_t, and in the last block steps 4–7 at the last time step only. Every
//! contraction is a `matrixmultiply::sgemm` on a strided view of the row-major tensors
//! (no copies, no transposes); the rest are loops over contiguous rows. Working memory is
//! allocated when a path is built.
//!
//! Files: `forward.rs` ([`NativeForward`]), `tape.rs` (the training forward of one
//! window, keeping its intermediates), `backward.rs` (its backward), `step.rs`
//! ([`NativeTraining`]: a batch over threads, the loss, Adam), `slots.rs` (where each
//! tensor sits in the parameter list). Tested against the WGSL path and the f64
//! reference in tests/native_forward.rs and tests/native_train.rs.

mod backward;
mod dense;
mod forward;
mod slots;
mod step;
mod tape;

pub use forward::NativeForward;
pub use step::{NativeAdam, NativeStepShape, NativeTraining};

/// A strided read-only matrix view: element (i, j) at `data[i·rs + j·cs]`.
#[derive(Clone, Copy)]
struct View<'a> {
    data: &'a [f32],
    rs: usize,
    cs: usize,
}

/// Row-major `[rows, cols]` (row stride `cols`).
fn rows(data: &[f32], cols: usize) -> View<'_> {
    View {
        data,
        rs: cols,
        cs: 1,
    }
}

/// The transpose of a row-major `[rows, cols]` matrix, seen as `[cols, rows]`.
fn transposed(data: &[f32], cols: usize) -> View<'_> {
    View {
        data,
        rs: 1,
        cs: cols,
    }
}

/// `C[m×n] = A[m×k]·B[k×n] + beta·C`, C row-major with row stride `ldc`.
///
/// Panics when a view does not cover its extent: the shapes are the network's own, so
/// that would be a bug here, never bad input. (The BLAS argument list, hence the allow.)
#[allow(clippy::too_many_arguments)]
fn gemm(m: usize, k: usize, n: usize, a: View, b: View, beta: f32, c: &mut [f32], ldc: usize) {
    let last = |v: &View, r: usize, s: usize| (r - 1) * v.rs + (s - 1) * v.cs;
    assert!(m > 0 && k > 0 && n > 0, "empty product");
    assert!(last(&a, m, k) < a.data.len(), "A does not cover [{m}, {k}]");
    assert!(last(&b, k, n) < b.data.len(), "B does not cover [{k}, {n}]");
    assert!((m - 1) * ldc + n <= c.len(), "C does not cover [{m}, {n}]");
    // SAFETY: the asserts above keep every element the product reads or writes inside
    // the three slices; C does not alias A or B (it is borrowed mutably).
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.data.as_ptr(),
            a.rs as isize,
            a.cs as isize,
            b.data.as_ptr(),
            b.rs as isize,
            b.cs as isize,
            beta,
            c.as_mut_ptr(),
            ldc as isize,
            1,
        );
    }
}

/// Multiply-adds per task below which [`par_gemm`] does not split a product (a rayon task
/// costs a few microseconds; 2^19 multiply-adds take ~25 µs on one core).
const PAR_MIN_MACS: usize = 1 << 19;

/// [`gemm`] with C's rows split into up to `threads` tasks on the current rayon pool, each
/// of at least [`PAR_MIN_MACS`] multiply-adds; one call when `threads` is 1 or the product
/// is small. Every element of C is the same sum in the same order either way (the split
/// only chooses which rows each call computes), so the result does not depend on it.
#[allow(clippy::too_many_arguments)]
fn par_gemm(
    threads: usize,
    m: usize,
    k: usize,
    n: usize,
    a: View,
    b: View,
    beta: f32,
    c: &mut [f32],
    ldc: usize,
) {
    let tasks = threads.min(m).min(m * k * n / PAR_MIN_MACS);
    if tasks < 2 {
        return gemm(m, k, n, a, b, beta, c, ldc);
    }
    let rows = m.div_ceil(tasks);
    rayon::scope(|scope| {
        let mut rest = c;
        for r0 in (0..m).step_by(rows) {
            let r = rows.min(m - r0);
            let take = if r0 + r < m { r * ldc } else { rest.len() };
            let (chunk, tail) = std::mem::take(&mut rest).split_at_mut(take);
            rest = tail;
            let a = View {
                data: &a.data[r0 * a.rs..],
                ..a
            };
            scope.spawn(move |_| gemm(r, k, n, a, b, beta, chunk, ldc));
        }
    });
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// tanh(x) = 2σ(2x) − 1: one `exp` instead of libm's `tanhf` (whose `expm1f` took a
/// third of the paper-shape forward); absolute error below 1e-7.
fn tanh(x: f32) -> f32 {
    2.0 * sigmoid(2.0 * x) - 1.0
}

/// Softmax of `len` values `x[i·stride]`, in place, max-subtracted.
fn softmax_strided(x: &mut [f32], len: usize, stride: usize) {
    let max = (0..len)
        .map(|i| x[i * stride])
        .fold(f32::NEG_INFINITY, f32::max);
    let mut sum = 0.0;
    for i in 0..len {
        let e = (x[i * stride] - max).exp();
        x[i * stride] = e;
        sum += e;
    }
    for i in 0..len {
        x[i * stride] /= sum;
    }
}
