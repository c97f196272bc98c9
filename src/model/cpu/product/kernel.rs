//! What the in-place engine's kernels are: a tile kernel ([`Kernel`]: up to [`MR`] rows
//! and `W` columns of C over one panel of k) and a dot kernel ([`Dot`]: four rows of A
//! against one column of B), with where they read ([`Tile`]) and write ([`Out`]).

/// Rows of C per tile.
pub(super) const MR: usize = 6;

/// Where C is written: element (i, j) at `ptr[i·rs + j·cs]`.
#[derive(Clone, Copy)]
pub(super) struct Out {
    pub(super) ptr: *mut f32,
    pub(super) rs: usize,
    pub(super) cs: usize,
}

impl Out {
    /// Row-major C with row stride `ldc`.
    pub(super) fn rows(c: &mut [f32], ldc: usize) -> Out {
        Out {
            ptr: c.as_mut_ptr(),
            rs: ldc,
            cs: 1,
        }
    }

    pub(super) fn t(self) -> Self {
        Out {
            rs: self.cs,
            cs: self.rs,
            ..self
        }
    }
}

/// A tile kernel: `W` columns of up to [`MR`] rows of C over one panel of k.
pub(super) trait Kernel {
    const W: usize;
    /// The R × W tile `t` into C at `c`: R·W sums in registers over k, then C = sum +
    /// beta·C (C not read when beta is 0) for the `t.nc` columns that exist.
    ///
    /// # Safety
    /// As [`in_place`]'s, for this tile's elements, and the CPU has the kernel's features.
    unsafe fn tile<const R: usize>(t: &Tile, c: Out);
}

/// One tile's operands: `kc` steps of k of A's rows from `a` (strides `ars`, `acs`) and of
/// B's panel from `b` (row stride `bs`); `nc` of its columns are C's.
pub(super) struct Tile {
    pub(super) kc: usize,
    pub(super) a: *const f32,
    pub(super) ars: usize,
    pub(super) acs: usize,
    pub(super) b: *const f32,
    pub(super) bs: usize,
    pub(super) nc: usize,
    pub(super) beta: f32,
}

impl Tile {
    /// Element (r, kk) of the tile's rows of A.
    ///
    /// # Safety
    /// r and kk inside the tile.
    #[inline(always)]
    pub(super) unsafe fn a(&self, r: usize, kk: usize) -> f32 {
        *self.a.add(r * self.ars + kk * self.acs)
    }

    /// Writes row `r` of the tile's sums (`row`, at least `nc` long) into C.
    ///
    /// # Safety
    /// r inside the tile, C as [`in_place`]'s.
    #[inline(always)]
    pub(super) unsafe fn store(&self, c: Out, r: usize, row: &[f32]) {
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
pub(super) const DOT_ROWS: usize = 4;
/// Partial sums per dot product: element k goes into sum k mod 16.
pub(super) const DOT_LANES: usize = 16;

/// Dot products of rows of A with columns of B, both contiguous along k: the 16 partial
/// sums of each (the first k − k mod 16 elements), added first to last, then the rest of
/// k in order.
pub(super) trait Dot {
    /// The dot products of the four rows at `rows` with the column at `b`, `k` long.
    ///
    /// # Safety
    /// Every pointer has `k` floats; the CPU has the kernel's features.
    unsafe fn dot4(rows: [*const f32; DOT_ROWS], b: *const f32, k: usize) -> [f32; DOT_ROWS];
}

/// The 16 partial sums of a dot product added first to last.
#[inline(always)]
pub(super) fn lanes_total(lanes: &[f32; DOT_LANES]) -> f32 {
    lanes.iter().sum()
}
