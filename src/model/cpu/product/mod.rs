//! The matrix products of the native path: `C[m×n] = A[m×k]·B[k×n] + beta·C` on strided
//! views of row-major tensors (no copies, no transposes), by one of two engines.
//!
//! - [`Products::Packed`], the `gemm` crate (AVX-512, AVX2 or scalar kernels chosen at run
//!   time, one thread per call): fastest on the large products of training, and it
//!   allocates on every call (a flag vector, and a packing buffer when it packs).
//! - [`Products::InPlace`], the in-place kernels (`in_place.rs`, `x86.rs`): tiles of 6 × 32 elements of C (6 × 16
//!   without AVX-512) held in registers, B read in place when its rows are contiguous and
//!   else copied 256 steps of k at a time into a panel on the stack; it allocates nothing. The predictor's forward
//!   ([`crate::model::NativeForward`]) runs every product through it, so that a control loop's
//!   tick touches no allocator (docs/embedding.md "Real-time advice"); it is also the
//!   faster of the two on the forward's small and medium products.
//!
//! The engine is a mode of the calling thread, like the subnormal flushing of
//! [`super::flushing_subnormals`]: [`with_products`] sets it around a pass, and every
//! [`gemm`] on that thread uses it. Each engine computes every element of C as the same
//! sum in the same order whatever the SIMD width (the in-place kernel: k in order, one
//! fused multiply-add per step where the CPU has FMA, restarted from C every 256 steps of
//! k).
//!
//! The files: `view.rs` the strided views, `kernel.rs` what a tile kernel and a dot
//! kernel are, `in_place.rs` the in-place engine and its plain kernels, `x86.rs` its
//! AVX-512 and AVX2 kernels, `tests.rs` every engine against a plain sum.

use std::cell::Cell;

use super::flushing_subnormals;
use in_place::{in_place, Isa};
use kernel::Out;
pub(crate) use view::{rows, transposed, View};

mod in_place;
mod kernel;
#[cfg(test)]
mod tests;
mod view;
#[cfg(target_arch = "x86_64")]
mod x86;

/// Which kernel computes the products of the calling thread (see the module's doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Products {
    Packed,
    InPlace,
}

thread_local! {
    static PRODUCTS: Cell<Products> = const { Cell::new(Products::Packed) };
}

/// Runs `f` with the calling thread's products computed by `engine`, then restores the
/// thread's engine, also when `f` panics.
pub(crate) fn with_products<R>(engine: Products, f: impl FnOnce() -> R) -> R {
    /// Puts the saved engine back when dropped.
    struct Restore(Products);
    impl Drop for Restore {
        fn drop(&mut self) {
            PRODUCTS.with(|p| p.set(self.0));
        }
    }
    let _restore = Restore(PRODUCTS.with(|p| p.replace(engine)));
    f()
}

/// `C[m×n] = A[m×k]·B[k×n] + beta·C`, C row-major with row stride `ldc`; C is not read
/// when `beta` is 0.
///
/// Panics when a view does not cover its extent: the shapes are the network's own, so
/// that would be a bug here, never bad input. (The BLAS argument list, hence the allow.)
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm(
    m: usize,
    k: usize,
    n: usize,
    a: View,
    b: View,
    beta: f32,
    c: &mut [f32],
    ldc: usize,
) {
    check_extents((m, k, n), &a, &b, c.len(), ldc);
    if PRODUCTS.with(|p| p.get()) == Products::InPlace {
        // SAFETY: the checks above keep every element read inside `a` and `b` and every
        // element written inside `c`, which aliases neither (borrowed mutably).
        unsafe { in_place(Isa::detected(), m, k, n, a, b, beta, Out::rows(c, ldc)) };
        return;
    }
    // gemm's own entry (`gemm::gemm`) turns a row-major C into the column-major C its
    // kernels prefer by swapping A and B, then calls the f32 kernel; the same is done
    // here, so that only the f32 kernels (`gemm-f32`) are compiled, not the crate's
    // complex, f64 and f16 ones. Every stride here is non-negative, so gemm's
    // negative-stride normalisation never applies.
    let (a_ptr, b_ptr) = (a.data.as_ptr(), b.data.as_ptr());
    #[rustfmt::skip]
    let (m, n, dst_cs, dst_rs, lhs, lhs_cs, lhs_rs, rhs, rhs_cs, rhs_rs) = if 1 < ldc {
        (n, m, ldc, 1, b_ptr, b.rs, b.cs, a_ptr, a.rs, a.cs)
    } else {
        (m, n, 1, ldc, a_ptr, a.cs, a.rs, b_ptr, b.cs, b.rs)
    };
    // SAFETY: the checks above keep every element the product reads or writes inside
    // the three slices; C does not alias A or B (it is borrowed mutably).
    unsafe {
        // gemm's convention: C := alpha·C + beta·(A·B), C read only when `read_dst`.
        gemm_f32::gemm::f32::get_gemm_fn()(
            m,
            n,
            k,
            c.as_mut_ptr(),
            dst_cs as isize,
            dst_rs as isize,
            beta != 0.0,
            lhs,
            lhs_cs as isize,
            lhs_rs as isize,
            rhs,
            rhs_cs as isize,
            rhs_rs as isize,
            beta,
            1.0,
            false,
            false,
            false,
            gemm_common::Parallelism::None,
        );
    }
}

/// One product by the chosen engine (`in_place`: [`Products::InPlace`], else
/// [`Products::Packed`]) on row-major buffers with the given strides, for
/// benches/products.rs, which compares the two at the forward's shapes. Panics as
/// [`gemm`] does.
#[doc(hidden)]
#[allow(clippy::too_many_arguments)]
pub fn product_for_bench(
    in_place: bool,
    (m, k, n): (usize, usize, usize),
    a: (&[f32], usize, usize),
    b: (&[f32], usize, usize),
    c: &mut [f32],
    ldc: usize,
) {
    let engine = if in_place {
        Products::InPlace
    } else {
        Products::Packed
    };
    let a = View {
        data: a.0,
        rs: a.1,
        cs: a.2,
    };
    let b = View {
        data: b.0,
        rs: b.1,
        cs: b.2,
    };
    with_products(engine, || gemm(m, k, n, a, b, 0.0, c, ldc));
}

/// Panics unless the product is non-empty and `a`, `b` and a C of `c_len` floats with row
/// stride `ldc` cover their extents: what makes [`gemm`]'s unchecked reads and writes safe.
fn check_extents((m, k, n): (usize, usize, usize), a: &View, b: &View, c_len: usize, ldc: usize) {
    let last = |v: &View, r: usize, s: usize| (r - 1) * v.rs + (s - 1) * v.cs;
    assert!(m > 0 && k > 0 && n > 0, "empty product");
    assert!(last(a, m, k) < a.data.len(), "A does not cover [{m}, {k}]");
    assert!(last(b, k, n) < b.data.len(), "B does not cover [{k}, {n}]");
    assert!((m - 1) * ldc + n <= c_len, "C does not cover [{m}, {n}]");
}

/// Multiply-adds per task below which [`par_gemm`] does not split a product (a rayon task
/// costs a few microseconds; 2^19 multiply-adds take ~25 µs on one core).
pub(crate) const PAR_MIN_MACS: usize = 1 << 19;

/// [`gemm`] with C's rows split into up to `threads` tasks on the current rayon pool, each
/// of at least [`PAR_MIN_MACS`] multiply-adds; one call when `threads` is 1 or the product
/// is small. Every element of C is the same sum in the same order either way (the split
/// only chooses which rows each call computes), so the result does not depend on it. The
/// tasks use the calling thread's engine.
#[allow(clippy::too_many_arguments)]
pub(crate) fn par_gemm(
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
    let engine = PRODUCTS.with(|p| p.get());
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
            scope.spawn(move |_| {
                with_products(engine, || {
                    flushing_subnormals(|| gemm(r, k, n, a, b, beta, chunk, ldc))
                })
            });
        }
    });
}
