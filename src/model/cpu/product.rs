//! The matrix products of the native path: `C[m×n] = A[m×k]·B[k×n] + beta·C` on strided
//! views of row-major tensors (no copies, no transposes), by one of two engines.
//!
//! - [`Products::Packed`], the `gemm` crate (AVX-512, AVX2 or scalar kernels chosen at run
//!   time, one thread per call): fastest on the large products of training, and it
//!   allocates on every call (a flag vector, and a packing buffer when it packs).
//! - [`Products::InPlace`], this file's kernel: tiles of 6 × 32 elements of C (6 × 16
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

use std::cell::Cell;

use super::flushing_subnormals;

/// A strided read-only matrix view: element (i, j) at `data[i·rs + j·cs]`.
#[derive(Clone, Copy)]
pub(crate) struct View<'a> {
    pub data: &'a [f32],
    pub rs: usize,
    pub cs: usize,
}

impl View<'_> {
    /// The same data seen as the transpose.
    fn t(self) -> Self {
        View {
            rs: self.cs,
            cs: self.rs,
            ..self
        }
    }
}

/// Row-major `[rows, cols]` (row stride `cols`).
pub(crate) fn rows(data: &[f32], cols: usize) -> View<'_> {
    View {
        data,
        rs: cols,
        cs: 1,
    }
}

/// The transpose of a row-major `[rows, cols]` matrix, seen as `[cols, rows]`.
pub(crate) fn transposed(data: &[f32], cols: usize) -> View<'_> {
    View {
        data,
        rs: 1,
        cs: cols,
    }
}

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
    // SAFETY: the checks above keep every element the product reads or writes inside
    // the three slices; C does not alias A or B (it is borrowed mutably).
    unsafe {
        // gemm's convention: C := alpha·C + beta·(A·B), C read only when `read_dst`.
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            ldc as isize,
            beta != 0.0,
            a.data.as_ptr(),
            a.cs as isize,
            a.rs as isize,
            b.data.as_ptr(),
            b.cs as isize,
            b.rs as isize,
            beta,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
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

/// Rows of C per tile.
const MR: usize = 6;
/// Steps of k per panel of B (32 KiB on the stack at the widest tile).
const KC: usize = 256;
/// The widest tile's columns.
const WIDEST: usize = 32;

/// Where C is written: element (i, j) at `ptr[i·rs + j·cs]`.
#[derive(Clone, Copy)]
struct Out {
    ptr: *mut f32,
    rs: usize,
    cs: usize,
}

impl Out {
    /// Row-major C with row stride `ldc`.
    fn rows(c: &mut [f32], ldc: usize) -> Out {
        Out {
            ptr: c.as_mut_ptr(),
            rs: ldc,
            cs: 1,
        }
    }

    fn t(self) -> Self {
        Out {
            rs: self.cs,
            cs: self.rs,
            ..self
        }
    }
}

/// The instruction sets the in-place kernels are written for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Isa {
    /// AVX-512F: tiles of 6 × 32 (6 × 16 on the last columns when at most 16 are left).
    Avx512,
    /// AVX2 and FMA: tiles of 6 × 16.
    Avx2,
    /// Plain code (a multiply then an add per step): tiles of 6 × 16.
    Portable,
}

impl Isa {
    /// The widest this CPU runs (a cached feature test, no allocation).
    fn detected() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx512f") {
                return Isa::Avx512;
            }
            if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
                return Isa::Avx2;
            }
        }
        Isa::Portable
    }
}

/// The in-place engine on `isa`. A product narrower than a tile whose operands both run
/// along k (a matrix-vector product, Q·Kᵀ-like products of a few columns) is dot products
/// vectorised along k; another narrow one runs as its transpose (Cᵀ = Bᵀ·Aᵀ) when that
/// fills more of the tiles' columns; the rest in tiles.
///
/// # Safety
/// Every element (i, k) of `a`, (k, j) of `b` for i < m, k < `k`, j < n lies inside its
/// slice, every element (i, j) of `c` inside one allocation no view aliases, and the CPU
/// has `isa`'s features.
#[allow(clippy::too_many_arguments)]
unsafe fn in_place(isa: Isa, m: usize, k: usize, n: usize, a: View, b: View, beta: f32, c: Out) {
    if n < 16 && a.cs == 1 && b.rs == 1 {
        return match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => dots::<x86::Avx512>(m, k, n, a, b, beta, c),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => dots::<x86::Avx2>(m, k, n, a, b, beta, c),
            _ => dots::<Portable>(m, k, n, a, b, beta, c),
        };
    }
    if n < 16 && m > n {
        // Cᵀ's element (j, i) is C's (i, j).
        return in_place(isa, n, k, m, b.t(), a.t(), beta, c.t());
    }
    match isa {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => columns::<x86::Avx512, x86::Avx512Half>(m, k, n, a, b, beta, c),
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => columns::<x86::Avx2, x86::Avx2>(m, k, n, a, b, beta, c),
        _ => columns::<Portable, Portable>(m, k, n, a, b, beta, c),
    }
}

/// A tile kernel: `W` columns of up to [`MR`] rows of C over one panel of k.
trait Kernel {
    const W: usize;
    /// The R × W tile `t` into C at `c`: R·W sums in registers over k, then C = sum +
    /// beta·C (C not read when beta is 0) for the `t.nc` columns that exist.
    ///
    /// # Safety
    /// As [`in_place`]'s, for this tile's elements, and the CPU has the kernel's features.
    unsafe fn tile<const R: usize>(t: &Tile, c: Out);
}

/// For each 256 steps of k and each `K::W` columns of C (the last ones by `L` when at
/// most `L::W` are left), B's panel, in place when its rows are contiguous and whole,
/// else copied (zero-padded) to the stack; then every tile of up to [`MR`] rows over it.
///
/// # Safety
/// As [`in_place`]'s, for `K` and `L`.
#[allow(clippy::too_many_arguments)]
unsafe fn columns<K: Kernel, L: Kernel>(
    m: usize,
    k: usize,
    n: usize,
    a: View,
    b: View,
    beta: f32,
    c: Out,
) {
    // Written before it is read (each panel's first kc·w elements), never zeroed: a
    // 32 KiB fill per product would cost the small ones more than their arithmetic.
    let mut panel = std::mem::MaybeUninit::<[f32; KC * WIDEST]>::uninit();
    let panel = panel.as_mut_ptr() as *mut f32;
    for k0 in (0..k).step_by(KC) {
        let kc = KC.min(k - k0);
        // The first panel of k applies beta; the next ones add to what it wrote.
        let beta = if k0 == 0 { beta } else { 1.0 };
        for j0 in (0..n).step_by(K::W) {
            let nc = K::W.min(n - j0);
            let w = if nc <= L::W { L::W } else { K::W };
            let (bp, bs): (*const f32, usize) = if b.cs == 1 && nc == w {
                (b.data.as_ptr().add(k0 * b.rs + j0), b.rs)
            } else {
                for kk in 0..kc {
                    let from = b.data.as_ptr().add((k0 + kk) * b.rs + j0 * b.cs);
                    let row = panel.add(kk * w);
                    for j in 0..w {
                        *row.add(j) = if j < nc { *from.add(j * b.cs) } else { 0.0 };
                    }
                }
                (panel as *const f32, w)
            };
            let mut i0 = 0;
            while i0 < m {
                let tile = Tile {
                    kc,
                    a: a.data.as_ptr().add(i0 * a.rs + k0 * a.cs),
                    ars: a.rs,
                    acs: a.cs,
                    b: bp,
                    bs,
                    nc,
                    beta,
                };
                let out = Out {
                    ptr: c.ptr.add(i0 * c.rs + j0 * c.cs),
                    ..c
                };
                if w == K::W {
                    rows_of::<K>(m - i0, &tile, out);
                } else {
                    rows_of::<L>(m - i0, &tile, out);
                }
                i0 += MR;
            }
        }
    }
}

/// `K`'s tile with min(rows, [`MR`]) rows.
///
/// # Safety
/// As [`Kernel::tile`]'s.
#[inline(always)]
unsafe fn rows_of<K: Kernel>(rows: usize, tile: &Tile, c: Out) {
    match rows {
        1 => K::tile::<1>(tile, c),
        2 => K::tile::<2>(tile, c),
        3 => K::tile::<3>(tile, c),
        4 => K::tile::<4>(tile, c),
        5 => K::tile::<5>(tile, c),
        _ => K::tile::<MR>(tile, c),
    }
}

/// One tile's operands: `kc` steps of k of A's rows from `a` (strides `ars`, `acs`) and of
/// B's panel from `b` (row stride `bs`); `nc` of its columns are C's.
struct Tile {
    kc: usize,
    a: *const f32,
    ars: usize,
    acs: usize,
    b: *const f32,
    bs: usize,
    nc: usize,
    beta: f32,
}

impl Tile {
    /// Element (r, kk) of the tile's rows of A.
    ///
    /// # Safety
    /// r and kk inside the tile.
    #[inline(always)]
    unsafe fn a(&self, r: usize, kk: usize) -> f32 {
        *self.a.add(r * self.ars + kk * self.acs)
    }

    /// Writes row `r` of the tile's sums (`row`, at least `nc` long) into C.
    ///
    /// # Safety
    /// r inside the tile, C as [`in_place`]'s.
    #[inline(always)]
    unsafe fn store(&self, c: Out, r: usize, row: &[f32]) {
        let out = c.ptr.add(r * c.rs);
        for (j, &v) in row.iter().enumerate().take(self.nc) {
            let o = out.add(j * c.cs);
            *o = if self.beta == 0.0 {
                v
            } else {
                v + self.beta * *o
            };
        }
    }
}

/// Rows of A per [`Dot::dot4`].
const DOT_ROWS: usize = 4;
/// Partial sums per dot product: element k goes into sum k mod 16.
const DOT_LANES: usize = 16;

/// Dot products of rows of A with columns of B, both contiguous along k: the 16 partial
/// sums of each (the first k − k mod 16 elements), added first to last, then the rest of
/// k in order.
trait Dot {
    /// The dot products of the four rows at `rows` with the column at `b`, `k` long.
    ///
    /// # Safety
    /// Every pointer has `k` floats; the CPU has the kernel's features.
    unsafe fn dot4(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS];
}

/// C by [`Dot`] `D` (`a.cs` and `b.rs` are 1), four rows of A per column of B (the last
/// rows repeated past m).
///
/// # Safety
/// As [`in_place`]'s, for `D`.
#[allow(clippy::too_many_arguments)]
unsafe fn dots<D: Dot>(m: usize, k: usize, n: usize, a: View, b: View, beta: f32, c: Out) {
    for i0 in (0..m).step_by(DOT_ROWS) {
        let rows: [*const f32; DOT_ROWS] =
            std::array::from_fn(|r| a.data.as_ptr().add((i0 + r).min(m - 1) * a.rs));
        for j in 0..n {
            let sums = D::dot4(rows, b.data.as_ptr().add(j * b.cs), k);
            for (r, &v) in sums.iter().enumerate().take(m - i0) {
                let o = c.ptr.add((i0 + r) * c.rs + j * c.cs);
                *o = if beta == 0.0 { v } else { v + beta * *o };
            }
        }
    }
}

/// The 16 partial sums of a dot product added first to last.
#[inline(always)]
fn lanes_total(lanes: &[f32; DOT_LANES]) -> f32 {
    lanes.iter().sum()
}

/// Tiles 16 wide in plain code (a multiply then an add per step), for CPUs without the
/// features of [`x86`]'s.
struct Portable;

impl Kernel for Portable {
    const W: usize = 16;

    #[inline(always)]
    unsafe fn tile<const R: usize>(t: &Tile, c: Out) {
        let mut acc = [[0f32; 16]; R];
        for kk in 0..t.kc {
            let b = (t.b.add(kk * t.bs) as *const [f32; 16]).read_unaligned();
            for (r, row) in acc.iter_mut().enumerate() {
                let a = t.a(r, kk);
                for (s, y) in row.iter_mut().zip(b) {
                    *s += a * y;
                }
            }
        }
        for (r, row) in acc.iter().enumerate() {
            t.store(c, r, row);
        }
    }
}

impl Dot for Portable {
    unsafe fn dot4(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS] {
        let body = k - k % DOT_LANES;
        let mut acc = [[0f32; DOT_LANES]; DOT_ROWS];
        for k0 in (0..body).step_by(DOT_LANES) {
            for (lanes, row) in acc.iter_mut().zip(rows) {
                for (l, s) in lanes.iter_mut().enumerate() {
                    *s += *row.add(k0 + l) * *b.add(k0 + l);
                }
            }
        }
        std::array::from_fn(|r| {
            let mut s = lanes_total(&acc[r]);
            for p in body..k {
                s += *rows[r].add(p) * *b.add(p);
            }
            s
        })
    }
}

/// The x86-64 tiles: each step of a sum is one fused multiply-add (exactly rounded, so
/// the 512- and 256-bit tiles give the same bits).
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{lanes_total, Dot, Kernel, Out, Tile, DOT_LANES, DOT_ROWS};

    /// 32 columns in two 512-bit vectors per row: 12 accumulators of AVX-512's 32.
    pub struct Avx512;
    /// 16 columns in one 512-bit vector per row.
    pub struct Avx512Half;
    /// 16 columns in two 256-bit vectors per row: 12 accumulators of AVX2's 16.
    pub struct Avx2;

    impl Kernel for Avx512 {
        const W: usize = 32;
        #[inline(always)]
        unsafe fn tile<const R: usize>(t: &Tile, c: Out) {
            avx512_32::<R>(t, c)
        }
    }

    impl Kernel for Avx512Half {
        const W: usize = 16;
        #[inline(always)]
        unsafe fn tile<const R: usize>(t: &Tile, c: Out) {
            avx512_16::<R>(t, c)
        }
    }

    impl Kernel for Avx2 {
        const W: usize = 16;
        #[inline(always)]
        unsafe fn tile<const R: usize>(t: &Tile, c: Out) {
            avx2_16::<R>(t, c)
        }
    }

    impl Dot for Avx512 {
        #[inline(always)]
        unsafe fn dot4(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS] {
            dot4_avx512(rows, b, k)
        }
    }

    impl Dot for Avx2 {
        #[inline(always)]
        unsafe fn dot4(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS] {
            dot4_avx2(rows, b, k)
        }
    }

    /// The rest of k (past its last 16) of each row's dot product, in order, fused.
    #[inline(always)]
    unsafe fn tails(
        lanes: [[f32; DOT_LANES]; DOT_ROWS],
        rows: [*const f32; DOT_ROWS],
        b: *const f32,
        body: usize,
        k: usize,
    ) -> [f32; DOT_ROWS] {
        std::array::from_fn(|r| {
            let mut s = lanes_total(&lanes[r]);
            for p in body..k {
                s = (*rows[r].add(p)).mul_add(*b.add(p), s);
            }
            s
        })
    }

    #[target_feature(enable = "avx512f")]
    unsafe fn dot4_avx512(
        rows: [*const f32; DOT_ROWS],
        b: *const f32,
        k: usize,
    ) -> [f32; DOT_ROWS] {
        let body = k - k % DOT_LANES;
        let mut acc = [_mm512_setzero_ps(); DOT_ROWS];
        for k0 in (0..body).step_by(DOT_LANES) {
            let y = _mm512_loadu_ps(b.add(k0));
            for (s, row) in acc.iter_mut().zip(rows) {
                *s = _mm512_fmadd_ps(_mm512_loadu_ps(row.add(k0)), y, *s);
            }
        }
        let mut lanes = [[0f32; DOT_LANES]; DOT_ROWS];
        for (l, s) in lanes.iter_mut().zip(acc) {
            _mm512_storeu_ps(l.as_mut_ptr(), s);
        }
        tails(lanes, rows, b, body, k)
    }

    #[target_feature(enable = "avx2,fma")]
    unsafe fn dot4_avx2(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS] {
        let body = k - k % DOT_LANES;
        let mut acc = [[_mm256_setzero_ps(); 2]; DOT_ROWS];
        for k0 in (0..body).step_by(DOT_LANES) {
            let (y0, y1) = (_mm256_loadu_ps(b.add(k0)), _mm256_loadu_ps(b.add(k0 + 8)));
            for (s, row) in acc.iter_mut().zip(rows) {
                s[0] = _mm256_fmadd_ps(_mm256_loadu_ps(row.add(k0)), y0, s[0]);
                s[1] = _mm256_fmadd_ps(_mm256_loadu_ps(row.add(k0 + 8)), y1, s[1]);
            }
        }
        let mut lanes = [[0f32; DOT_LANES]; DOT_ROWS];
        for (l, s) in lanes.iter_mut().zip(acc) {
            _mm256_storeu_ps(l.as_mut_ptr(), s[0]);
            _mm256_storeu_ps(l.as_mut_ptr().add(8), s[1]);
        }
        tails(lanes, rows, b, body, k)
    }

    #[target_feature(enable = "avx512f")]
    unsafe fn avx512_32<const R: usize>(t: &Tile, c: Out) {
        let mut acc = [[_mm512_setzero_ps(); 2]; R];
        for kk in 0..t.kc {
            let b = t.b.add(kk * t.bs);
            let (b0, b1) = (_mm512_loadu_ps(b), _mm512_loadu_ps(b.add(16)));
            for (r, s) in acc.iter_mut().enumerate() {
                let a = _mm512_set1_ps(t.a(r, kk));
                s[0] = _mm512_fmadd_ps(a, b0, s[0]);
                s[1] = _mm512_fmadd_ps(a, b1, s[1]);
            }
        }
        if t.nc == 32 && c.cs == 1 {
            for (r, s) in acc.iter().enumerate() {
                let o = c.ptr.add(r * c.rs);
                store512(o, s[0], t.beta);
                store512(o.add(16), s[1], t.beta);
            }
            return;
        }
        let mut row = [0f32; 32];
        for (r, s) in acc.iter().enumerate() {
            _mm512_storeu_ps(row.as_mut_ptr(), s[0]);
            _mm512_storeu_ps(row.as_mut_ptr().add(16), s[1]);
            t.store(c, r, &row);
        }
    }

    /// C = v + beta·C at `o`, 16 contiguous elements (C not read when beta is 0): what
    /// [`Tile::store`] does one element at a time.
    #[inline(always)]
    unsafe fn store512(o: *mut f32, v: __m512, beta: f32) {
        let v = if beta == 0.0 {
            v
        } else {
            _mm512_add_ps(v, _mm512_mul_ps(_mm512_set1_ps(beta), _mm512_loadu_ps(o)))
        };
        _mm512_storeu_ps(o, v);
    }

    /// [`store512`] for 8 elements.
    #[inline(always)]
    unsafe fn store256(o: *mut f32, v: __m256, beta: f32) {
        let v = if beta == 0.0 {
            v
        } else {
            _mm256_add_ps(v, _mm256_mul_ps(_mm256_set1_ps(beta), _mm256_loadu_ps(o)))
        };
        _mm256_storeu_ps(o, v);
    }

    #[target_feature(enable = "avx512f")]
    unsafe fn avx512_16<const R: usize>(t: &Tile, c: Out) {
        let mut acc = [_mm512_setzero_ps(); R];
        for kk in 0..t.kc {
            let b0 = _mm512_loadu_ps(t.b.add(kk * t.bs));
            for (r, s) in acc.iter_mut().enumerate() {
                *s = _mm512_fmadd_ps(_mm512_set1_ps(t.a(r, kk)), b0, *s);
            }
        }
        if t.nc == 16 && c.cs == 1 {
            for (r, s) in acc.iter().enumerate() {
                store512(c.ptr.add(r * c.rs), *s, t.beta);
            }
            return;
        }
        let mut row = [0f32; 16];
        for (r, s) in acc.iter().enumerate() {
            _mm512_storeu_ps(row.as_mut_ptr(), *s);
            t.store(c, r, &row);
        }
    }

    #[target_feature(enable = "avx2,fma")]
    unsafe fn avx2_16<const R: usize>(t: &Tile, c: Out) {
        let mut acc = [[_mm256_setzero_ps(); 2]; R];
        for kk in 0..t.kc {
            let b = t.b.add(kk * t.bs);
            let (b0, b1) = (_mm256_loadu_ps(b), _mm256_loadu_ps(b.add(8)));
            for (r, s) in acc.iter_mut().enumerate() {
                let a = _mm256_set1_ps(t.a(r, kk));
                s[0] = _mm256_fmadd_ps(a, b0, s[0]);
                s[1] = _mm256_fmadd_ps(a, b1, s[1]);
            }
        }
        if t.nc == 16 && c.cs == 1 {
            for (r, s) in acc.iter().enumerate() {
                let o = c.ptr.add(r * c.rs);
                store256(o, s[0], t.beta);
                store256(o.add(8), s[1], t.beta);
            }
            return;
        }
        let mut row = [0f32; 16];
        for (r, s) in acc.iter().enumerate() {
            _mm256_storeu_ps(row.as_mut_ptr(), s[0]);
            _mm256_storeu_ps(row.as_mut_ptr().add(8), s[1]);
            t.store(c, r, &row);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic pseudo-random matrix filler.
    fn values(len: usize, seed: usize) -> Vec<f32> {
        (0..len)
            .map(|i| (((i * 7919 + seed * 104_729) % 2003) as f32 / 1001.5 - 1.0) * 0.9)
            .collect()
    }

    /// The instruction sets of the in-place kernels this CPU runs.
    fn isas() -> Vec<Isa> {
        let mut isas = vec![Isa::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
                isas.push(Isa::Avx2);
            }
            if is_x86_feature_detected!("avx512f") {
                isas.push(Isa::Avx512);
            }
        }
        isas
    }

    /// The product by the gemm crate (`None`) or the in-place kernels on `isa`.
    #[allow(clippy::too_many_arguments)]
    fn product(
        isa: Option<Isa>,
        (m, k, n): (usize, usize, usize),
        a: View,
        b: View,
        beta: f32,
        c: &mut [f32],
        ldc: usize,
    ) {
        match isa {
            None => gemm(m, k, n, a, b, beta, c, ldc),
            Some(isa) => {
                check_extents((m, k, n), &a, &b, c.len(), ldc);
                // SAFETY: the checks above passed; `isa` is one this CPU runs.
                unsafe { in_place(isa, m, k, n, a, b, beta, Out::rows(c, ldc)) }
            }
        }
    }

    /// The gemm crate and the in-place kernels of every instruction set this CPU runs
    /// against an f64 product, over shapes at and around every edge of the in-place
    /// kernels (tiles of 6 × 16 and 6 × 32, panels of 256 steps of k, the dot products,
    /// the transposed narrow case), every operand layout, beta 0 (C's old values ignored,
    /// even NaN) and 1.
    #[test]
    fn every_engine_matches_an_f64_product_at_every_edge() {
        let shapes = [
            (1, 1, 1),
            (1, 300, 1),
            (7, 5, 1),
            (1, 9, 33),
            (6, 16, 16),
            (7, 17, 17),
            (13, 257, 3),
            (3, 600, 40),
            (20, 31, 12),
            (64, 100, 48),
        ];
        for (si, &(m, k, n)) in shapes.iter().enumerate() {
            for layout in 0..4 {
                let a_data = values(m * k + 3, si);
                let b_data = values(k * n + 5, si + 17);
                let a = if layout & 1 == 0 {
                    rows(&a_data, k)
                } else {
                    transposed(&a_data, m)
                };
                let b = if layout & 2 == 0 {
                    rows(&b_data, n)
                } else {
                    transposed(&b_data, k)
                };
                let ldc = n + 2;
                let old = values(m * ldc, si + 41);
                let engines = std::iter::once(None).chain(isas().into_iter().map(Some));
                for engine in engines {
                    for beta in [0.0, 1.0] {
                        let mut c = old.clone();
                        if beta == 0.0 {
                            c.iter_mut().for_each(|v| *v = f32::NAN);
                        }
                        product(engine, (m, k, n), a, b, beta, &mut c, ldc);
                        for i in 0..m {
                            for j in 0..n {
                                let want: f64 = (0..k)
                                    .map(|p| {
                                        a.data[i * a.rs + p * a.cs] as f64
                                            * b.data[p * b.rs + j * b.cs] as f64
                                    })
                                    .sum::<f64>()
                                    + beta as f64 * old[i * ldc + j] as f64;
                                let got = c[i * ldc + j] as f64;
                                assert!(
                                    (got - want).abs() < 2e-5 * (1.0 + k as f64).sqrt(),
                                    "{engine:?} [{m}, {k}, {n}] layout {layout} beta {beta} \
                                     ({i}, {j}): {got} against {want}"
                                );
                            }
                            // The padding between C's rows is never written.
                            for j in n..ldc.min(c.len() - i * ldc) {
                                let was = if beta == 0.0 {
                                    f32::NAN
                                } else {
                                    old[i * ldc + j]
                                };
                                assert_eq!(c[i * ldc + j].to_bits(), was.to_bits());
                            }
                        }
                    }
                }
            }
        }
    }

    /// The in-place engine's sums follow the documented order: k in order from zero, a
    /// fused multiply-add where the CPU has FMA (else a multiply then an add), the running
    /// sum added to C every 256 steps.
    #[test]
    fn the_in_place_sums_follow_their_documented_order() {
        let (m, k, n) = (3, 600, 5);
        let a_data = values(m * k, 3);
        let b_data = values(k * n, 4);
        let old = vec![0.5f32; m * n];
        for isa in isas() {
            let mut c = old.clone();
            let fused = isa != Isa::Portable;
            product(
                Some(isa),
                (m, k, n),
                rows(&a_data, k),
                rows(&b_data, n),
                1.0,
                &mut c,
                n,
            );
            for i in 0..m {
                for j in 0..n {
                    let mut want = old[i * n + j];
                    for k0 in (0..k).step_by(KC) {
                        let mut s = 0f32;
                        for p in k0..(k0 + KC).min(k) {
                            let (x, y) = (a_data[i * k + p], b_data[p * n + j]);
                            s = if fused { x.mul_add(y, s) } else { s + x * y };
                        }
                        want += s;
                    }
                    assert_eq!(c[i * n + j].to_bits(), want.to_bits(), "{isa:?} ({i}, {j})");
                }
            }
        }
    }

    /// The dot-product path's sums follow their documented order: 16 partial sums (k mod
    /// 16) of the whole sixteens, added first to last, then the rest of k in order.
    #[test]
    fn the_in_place_dot_products_follow_their_documented_order() {
        let (m, k, n) = (5, 37, 2);
        let a_data = values(m * k, 5);
        let b_data = values(k * n, 6);
        for isa in isas() {
            let mut c = vec![0f32; m * n];
            // B seen transposed: both operands run along k, and n < 16.
            product(
                Some(isa),
                (m, k, n),
                rows(&a_data, k),
                transposed(&b_data, k),
                0.0,
                &mut c,
                n,
            );
            let fused = isa != Isa::Portable;
            let step = |x: f32, y: f32, s: f32| if fused { x.mul_add(y, s) } else { s + x * y };
            for i in 0..m {
                for j in 0..n {
                    let (row, col) = (&a_data[i * k..][..k], &b_data[j * k..][..k]);
                    let mut lanes = [0f32; 16];
                    for p in 0..32 {
                        lanes[p % 16] = step(row[p], col[p], lanes[p % 16]);
                    }
                    let mut want: f32 = lanes.iter().sum();
                    for p in 32..k {
                        want = step(row[p], col[p], want);
                    }
                    assert_eq!(c[i * n + j].to_bits(), want.to_bits(), "{isa:?} ({i}, {j})");
                }
            }
        }
    }

    /// The engine the predictor's forward sets is the one its products run on.
    #[test]
    fn with_products_routes_gemm_to_the_in_place_kernels() {
        let (m, k, n) = (7, 33, 20);
        let a_data = values(m * k, 8);
        let b_data = values(k * n, 9);
        let mut routed = vec![0f32; m * n];
        with_products(Products::InPlace, || {
            gemm(
                m,
                k,
                n,
                rows(&a_data, k),
                rows(&b_data, n),
                0.0,
                &mut routed,
                n,
            )
        });
        let mut direct = vec![0f32; m * n];
        let isa = Some(Isa::detected());
        product(
            isa,
            (m, k, n),
            rows(&a_data, k),
            rows(&b_data, n),
            0.0,
            &mut direct,
            n,
        );
        assert_eq!(routed, direct);
    }

    #[test]
    fn the_engine_is_restored_after_a_panic() {
        let caught = std::panic::catch_unwind(|| {
            with_products(Products::InPlace, || panic!("inside"));
        });
        assert!(caught.is_err());
        assert_eq!(PRODUCTS.with(|p| p.get()), Products::Packed);
    }
}
