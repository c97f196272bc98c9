//! The in-place engine: tiles of C held in registers, B read in place or copied a panel
//! at a time to the stack, narrow products as dot products or transposed; the plain
//! kernels for CPUs without [`super::x86`]'s features. Nothing here allocates.

use super::kernel::{lanes_total, Dot, Kernel, Out, Tile, DOT_LANES, DOT_ROWS, MR};
use super::view::View;
#[cfg(target_arch = "x86_64")]
use super::x86;

/// Steps of k per panel of B (32 KiB on the stack at the widest tile).
pub(super) const KC: usize = 256;
/// The widest tile's columns.
const WIDEST: usize = 32;

/// The instruction sets the in-place kernels are written for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Isa {
    /// AVX-512F: tiles of 6 × 32 (6 × 16 on the last columns when at most 16 are left).
    Avx512,
    /// AVX2 and FMA: tiles of 6 × 16.
    Avx2,
    /// Plain code (a multiply then an add per step): tiles of 6 × 16.
    Portable,
}

impl Isa {
    /// The widest this CPU runs (a cached feature test, no allocation).
    pub(super) fn detected() -> Isa {
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
pub(super) unsafe fn in_place(
    isa: Isa,
    m: usize,
    k: usize,
    n: usize,
    a: View,
    b: View,
    beta: f32,
    c: Out,
) {
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

/// Tiles 16 wide in plain code (a multiply then an add per step), for CPUs without the
/// features of [`x86`]'s.
pub(super) struct Portable;

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
