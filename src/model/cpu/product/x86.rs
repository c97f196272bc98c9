//! The x86-64 tiles: each step of a sum is one fused multiply-add (exactly rounded, so
//! the 512- and 256-bit tiles give the same bits).

use std::arch::x86_64::*;

use super::kernel::{lanes_total, Dot, Kernel, Out, Tile, DOT_LANES, DOT_ROWS};

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
unsafe fn dot4_avx512(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS] {
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
