//! Two-dimensional FFTs (rows then columns, rustfft) and the linear convolution of a
//! map with a small kernel through them: the dwell-time solver's heavy part. The rows
//! are transformed in parallel (rayon), the columns as rows of a transposed copy (cache
//! blocks of [`BLOCK`] columns), and a convolution skips the rows it knows to be zero
//! and the columns it crops away: every transform that runs is the one a plain
//! row-then-column pass would run, so the results are the same.

use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

use crate::gpu::{Gpu, GpuError};
use crate::ops::fft::Convolution;

/// Columns moved together by a transpose: 16 complex values, four cache lines.
const BLOCK: usize = 16;

/// Forward and inverse 2-D transforms of a `size × size` complex array, row-major.
#[derive(Clone)]
pub struct Fft2 {
    size: usize,
    forward: Arc<dyn Fft<f64>>,
    inverse: Arc<dyn Fft<f64>>,
    transposed: Vec<Complex64>,
}

/// `dst[c·n + r] = src[r·n + c]` for the `n × n` array `src`, in blocks of columns.
fn transpose(src: &[Complex64], dst: &mut [Complex64], n: usize) {
    dst.par_chunks_mut(BLOCK * n)
        .enumerate()
        .for_each(|(block, out)| {
            let c0 = block * BLOCK;
            let width = out.len() / n;
            for r in 0..n {
                let row = &src[r * n + c0..][..width];
                for (b, v) in row.iter().enumerate() {
                    out[b * n + r] = *v;
                }
            }
        });
}

/// Transforms the first `rows` rows (each `size` long) of `data` in place, in parallel.
fn rows(fft: &dyn Fft<f64>, data: &mut [Complex64], size: usize, rows: usize) {
    let per = rows.div_ceil(rayon::current_num_threads()).max(1);
    data[..rows * size]
        .par_chunks_mut(per * size)
        .for_each(|chunk| fft.process(chunk));
}

impl Fft2 {
    /// Plans the transforms for `size × size` arrays.
    pub fn new(size: usize) -> Fft2 {
        let mut planner = FftPlanner::new();
        Fft2 {
            size,
            forward: planner.plan_fft_forward(size),
            inverse: planner.plan_fft_inverse(size),
            transposed: vec![Complex64::default(); size * size],
        }
    }

    /// The side of the arrays it transforms.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Rows, then columns; rows from `nonzero` on are taken as zero (their transform is
    /// zero and is not computed), and only the first `kept` columns are transformed
    /// (the others are left as the row pass left them).
    fn both_passes(&mut self, data: &mut [Complex64], inverse: bool, nonzero: usize, kept: usize) {
        let n = self.size;
        let fft = if inverse {
            &self.inverse
        } else {
            &self.forward
        };
        rows(fft.as_ref(), data, n, nonzero);
        transpose(data, &mut self.transposed, n);
        rows(fft.as_ref(), &mut self.transposed, n, kept);
        transpose(&self.transposed, data, n);
    }

    /// In place, unnormalised.
    pub fn forward(&mut self, data: &mut [Complex64]) {
        self.both_passes(data, false, self.size, self.size);
    }

    /// In place, divided by `size²`: `inverse(forward(x)) = x`.
    pub fn inverse(&mut self, data: &mut [Complex64]) {
        self.both_passes(data, true, self.size, self.size);
        self.normalise(data);
    }

    fn normalise(&self, data: &mut [Complex64]) {
        let scale = 1.0 / (self.size * self.size) as f64;
        data.par_iter_mut().for_each(|v| *v *= scale);
    }
}

/// Linear convolution of `n × n` maps with one kernel of half-width `reach` pixels
/// (`(2·reach + 1)²` values, centred), as products of spectra on a zero-padded square
/// large enough that nothing wraps around.
pub struct Convolver {
    n: usize,
    fft: Fft2,
    spectrum: Vec<Complex64>,
    work: Vec<Complex64>,
    /// The same filtering by WGSL kernels on a GPU (`ops::fft`, f32), when set.
    gpu: Option<Convolution>,
}

impl Convolver {
    /// For maps `n` pixels a side and the kernel `kernel` (side `2·reach + 1`, row-major,
    /// its centre the zero offset).
    pub fn new(n: usize, kernel: &[f64], reach: usize) -> Convolver {
        let side = 2 * reach + 1;
        assert_eq!(kernel.len(), side * side, "kernel of side {side}");
        let size = n + 2 * reach;
        let mut fft = Fft2::new(size);
        let mut spectrum = vec![Complex64::default(); size * size];
        // The kernel's centre at (0, 0), negative offsets wrapped to the far end.
        for kr in 0..side {
            for kc in 0..side {
                let r = (kr + size - reach) % size;
                let c = (kc + size - reach) % size;
                spectrum[r * size + c] = Complex64::new(kernel[kr * side + kc], 0.0);
            }
        }
        fft.forward(&mut spectrum);
        Convolver {
            n,
            fft,
            work: vec![Complex64::default(); size * size],
            spectrum,
            gpu: None,
        }
    }

    /// Filters on `gpu` with the WGSL kernels of `ops::fft` (in f32) from now on, or on
    /// the CPU (f64) with `None`.
    pub fn run_on(&mut self, gpu: Option<Arc<Gpu>>) -> Result<(), GpuError> {
        self.gpu = match gpu {
            Some(g) => Some(Convolution::new(g, self.n, &self.spectrum)?),
            None => None,
        };
        Ok(())
    }

    /// A convolver of its own with the same kernel on the same adapter (the plans are
    /// shared, the scratch is not), for another thread.
    pub fn fork(&self) -> Result<Convolver, GpuError> {
        let mut fork = Convolver {
            n: self.n,
            fft: self.fft.clone(),
            spectrum: self.spectrum.clone(),
            work: vec![Complex64::default(); self.work.len()],
            gpu: None,
        };
        fork.run_on(self.gpu.as_ref().map(|g| g.shared_gpu()))?;
        Ok(fork)
    }

    /// The kernel's spectrum on the padded square (for inverse filters).
    pub fn spectrum(&self) -> &[Complex64] {
        &self.spectrum
    }

    /// The side of the padded square.
    pub fn size(&self) -> usize {
        self.fft.size()
    }

    /// The adapter it filters on, or `None` on the CPU.
    pub fn gpu(&self) -> Option<&Gpu> {
        self.gpu.as_ref().map(Convolution::gpu)
    }

    /// `out = map ∗ kernel`, both `n × n`; `out` may not alias `map`.
    pub fn convolve(&mut self, map: &[f64], out: &mut [f64]) -> Result<(), GpuError> {
        match &mut self.gpu {
            Some(g) => g.convolve(map, out),
            None => {
                self.filter_cpu(map, out, |s, _| s);
                Ok(())
            }
        }
    }

    /// `out = F⁻¹[F(map) · f(kernel spectrum, index)]` on the padded square, cropped
    /// back to `n × n`: [`Convolver::convolve`] with `f` the identity, an inverse filter
    /// otherwise. On a GPU `f` is evaluated on the host and the product sent.
    pub fn filter(
        &mut self,
        map: &[f64],
        out: &mut [f64],
        f: impl Fn(Complex64, usize) -> Complex64 + Sync,
    ) -> Result<(), GpuError> {
        match &mut self.gpu {
            Some(g) => {
                let factor: Vec<Complex64> = self
                    .spectrum
                    .par_iter()
                    .enumerate()
                    .map(|(i, s)| f(*s, i))
                    .collect();
                g.filter(map, out, &factor)
            }
            None => {
                self.filter_cpu(map, out, f);
                Ok(())
            }
        }
    }

    /// [`Convolver::filter`] on the CPU, in f64.
    fn filter_cpu(
        &mut self,
        map: &[f64],
        out: &mut [f64],
        f: impl Fn(Complex64, usize) -> Complex64 + Sync,
    ) {
        let (n, size) = (self.n, self.fft.size());
        self.work.fill(Complex64::default());
        for r in 0..n {
            for c in 0..n {
                self.work[r * size + c] = Complex64::new(map[r * n + c], 0.0);
            }
        }
        // The padding rows are zero; of the result only the first n rows and columns
        // are kept.
        self.fft.both_passes(&mut self.work, false, n, size);
        self.work
            .par_iter_mut()
            .zip(self.spectrum.par_iter())
            .enumerate()
            .for_each(|(i, (w, s))| *w *= f(*s, i));
        self.fft.both_passes(&mut self.work, true, size, n);
        let scale = 1.0 / (size * size) as f64;
        for r in 0..n {
            for c in 0..n {
                out[r * n + c] = (self.work[r * size + c] * scale).re;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn convolution_matches_the_direct_sum() {
        let (n, reach) = (7, 2);
        let side = 2 * reach + 1;
        let map: Vec<f64> = (0..n * n).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
        let kernel: Vec<f64> = (0..side * side)
            .map(|i| ((i * 13) % 7) as f64 * 0.1)
            .collect();
        let mut conv = Convolver::new(n, &kernel, reach);
        let mut out = vec![0.0; n * n];
        conv.convolve(&map, &mut out).unwrap();
        for r in 0..n as isize {
            for c in 0..n as isize {
                let mut want = 0.0;
                for dr in -(reach as isize)..=reach as isize {
                    for dc in -(reach as isize)..=reach as isize {
                        let (sr, sc) = (r - dr, c - dc);
                        if (0..n as isize).contains(&sr) && (0..n as isize).contains(&sc) {
                            let k = kernel[((dr + reach as isize) * side as isize
                                + dc
                                + reach as isize)
                                as usize];
                            want += k * map[(sr * n as isize + sc) as usize];
                        }
                    }
                }
                let got = out[(r * n as isize + c) as usize];
                assert!(
                    (got - want).abs() < 1e-9,
                    "({r}, {c}): {got} against {want}"
                );
            }
        }
    }
}
