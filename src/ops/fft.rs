//! Discrete Fourier transforms of any length on the GPU (`shaders/fft.wgsl`): Bluestein's
//! chirp z-transform over a radix-2 Stockham FFT, batched over the rows or the columns of
//! a square complex array; the 2-D transform and a linear filter through it
//! ([`Convolution`], the dwell solver's convolution and inverse filter on a GPU,
//! docs/polishing.md "Compute"); and the plain f64 DFT they are tested against
//! ([`dft_rows`], [`dft2`]).
//!
//! The side may be any length (the mirror's padded maps are 562 = 2·281 and
//! 1124 = 4·281 a side, a large prime in each): a length-`n` DFT is a convolution with a
//! chirp, done as FFTs of the power of two `m ≥ 2n − 1`. Twiddles, chirps and the chirp
//! filter's spectrum are computed on the host in f64 (rustfft for the spectrum) and
//! rounded to f32 once.

use std::sync::Arc;

use rustfft::num_complex::Complex64;

use crate::gpu::{
    grid_1d, Binding, DType, Dispatch, Gpu, GpuError, Kernel, Readback, Recorder, Shader, Tensor,
};

/// The WGSL module of this family (`shaders/fft.wgsl`: `fft_pass`, `fft_mul`,
/// `fft_chirp_load`, `fft_chirp_store`).
pub static SHADER: Shader = Shader {
    name: "fft",
    source: include_str!("../../shaders/fft.wgsl"),
    base: None,
};

const THREE: &[Binding] = &[Binding::read(1), Binding::read(2), Binding::read_write(3)];

static PASS: Kernel = Kernel {
    shader: &SHADER,
    entry: "fft_pass",
    bindings: THREE,
};
static MUL: Kernel = Kernel {
    shader: &SHADER,
    entry: "fft_mul",
    bindings: &[Binding::read(1), Binding::read_write(3)],
};
static LOAD: Kernel = Kernel {
    shader: &SHADER,
    entry: "fft_chirp_load",
    bindings: THREE,
};
static STORE: Kernel = Kernel {
    shader: &SHADER,
    entry: "fft_chirp_store",
    bindings: THREE,
};

crate::gpu::uniform! {
    #[derive(Default)]
    pub(crate) struct Params = FftParams in SHADER {
        m: u32,
        rows: u32,
        ns: u32,
        inverse: u32,
        n: u32,
        row_stride: u32,
        elem_stride: u32,
        period: u32,
        count: u32,
        pad0: u32,
        scale: f32,
        pad1: u32,
    }
}

/// `values` as the kernels' complex numbers (pairs of f32).
fn to_f32(values: &[Complex64]) -> Vec<[f32; 2]> {
    values.iter().map(|v| [v.re as f32, v.im as f32]).collect()
}

/// A complex tensor of `len` values holding `values` (or zeros).
fn complex(
    gpu: &Gpu,
    name: &str,
    len: usize,
    values: Option<&[Complex64]>,
) -> Result<Tensor, GpuError> {
    let t = gpu.zeros(name, &[len, 2], DType::F32)?;
    if let Some(v) = values {
        gpu.write(&t, &to_f32(v))?;
    }
    Ok(t)
}

/// The length-`n` DFT as Bluestein's algorithm computes it: the chirps, the chirp
/// filter's spectra and the twiddles of the `m`-point FFTs, on the device.
struct Bluestein {
    n: usize,
    m: usize,
    /// `w[k] = exp(−πi·k²/n)` (forward) and its conjugate (inverse).
    chirp: [Tensor; 2],
    /// `FFT_m(b) / m` with `b[±k] = conj(chirp[k])`, forward and inverse.
    spectrum: [Tensor; 2],
    /// `exp(−2πi·k/m)`, k < m/2.
    twiddle: Tensor,
}

impl Bluestein {
    fn new(gpu: &Gpu, n: usize) -> Result<Bluestein, GpuError> {
        let m = (2 * n).saturating_sub(1).max(1).next_power_of_two();
        let mut planner = rustfft::FftPlanner::<f64>::new();
        let fft = planner.plan_fft_forward(m);
        // The chirp of one direction and its filter's spectrum.
        let make = |sign: f64| -> Result<(Tensor, Tensor), GpuError> {
            // k² mod 2n keeps the angle exact for large k.
            let w: Vec<Complex64> = (0..n as u64)
                .map(|k| {
                    let q = (k * k) % (2 * n as u64);
                    Complex64::from_polar(1.0, sign * std::f64::consts::PI * q as f64 / n as f64)
                })
                .collect();
            let mut b = vec![Complex64::default(); m];
            for (k, v) in w.iter().enumerate() {
                b[k] = v.conj();
                if k > 0 {
                    b[m - k] = v.conj();
                }
            }
            fft.process(&mut b);
            let scale = 1.0 / m as f64;
            b.iter_mut().for_each(|v| *v *= scale);
            Ok((
                complex(gpu, "fft chirp", n, Some(&w))?,
                complex(gpu, "fft chirp spectrum", m, Some(&b))?,
            ))
        };
        let (forward, inverse) = (make(-1.0)?, make(1.0)?);
        let twiddles: Vec<Complex64> = (0..(m / 2).max(1))
            .map(|k| Complex64::from_polar(1.0, -std::f64::consts::TAU * k as f64 / m as f64))
            .collect();
        Ok(Bluestein {
            n,
            m,
            chirp: [forward.0, inverse.0],
            spectrum: [forward.1, inverse.1],
            twiddle: complex(gpu, "fft twiddles", twiddles.len(), Some(&twiddles))?,
        })
    }

    /// The dispatches of `rows` length-`n` transforms of `data` (element k of row r at
    /// `r·row_stride + k·elem_stride`), in place, through the work arrays `work` (each
    /// `rows·m` complex values), every result times `scale`.
    #[allow(clippy::too_many_arguments)]
    fn dispatches(
        &self,
        gpu: &Gpu,
        data: &Tensor,
        work: [&Tensor; 2],
        (rows, row_stride, elem_stride): (usize, usize, usize),
        inverse: bool,
        scale: f32,
        out: &mut Vec<Dispatch>,
    ) -> Result<(), GpuError> {
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let dir = usize::from(inverse);
        let base = Params {
            m: self.m as u32,
            rows: rows as u32,
            n: self.n as u32,
            row_stride: row_stride as u32,
            elem_stride: elem_stride as u32,
            scale,
            ..Params::default()
        };
        let chirp = &self.chirp[dir];
        out.push(gpu.dispatch(
            &LOAD,
            &[],
            &base,
            &[chirp, data, work[0]],
            grid_1d(rows * self.m, 256, max),
        )?);
        // Forward FFTs, the product with the chirp filter's spectrum, inverse FFTs; `at`
        // is the work array that holds the latest result.
        let mut at = 0;
        for inverse in [0u32, 1] {
            if inverse == 1 {
                let product = Params {
                    period: self.m as u32,
                    count: (rows * self.m) as u32,
                    ..base
                };
                out.push(gpu.dispatch(
                    &MUL,
                    &[],
                    &product,
                    &[&self.spectrum[dir], work[at]],
                    grid_1d(rows * self.m, 256, max),
                )?);
            }
            for s in 0..self.m.trailing_zeros() {
                let params = Params {
                    ns: 1 << s,
                    inverse,
                    ..base
                };
                out.push(gpu.dispatch(
                    &PASS,
                    &[],
                    &params,
                    &[&self.twiddle, work[at], work[1 - at]],
                    grid_1d(rows * self.m / 2, 256, max),
                )?);
                at = 1 - at;
            }
        }
        out.push(gpu.dispatch(
            &STORE,
            &[],
            &base,
            &[chirp, work[at], data],
            grid_1d(rows * self.n, 256, max),
        )?);
        Ok(())
    }
}

/// The 2-D DFT of a `size × size` complex tensor, forward (unnormalised) and inverse
/// (divided by `size²`), as dispatch lists: rows, then columns.
pub struct Transform2 {
    size: usize,
    forward: Vec<Dispatch>,
    inverse: Vec<Dispatch>,
}

impl Transform2 {
    /// The transforms of `data` (`size²` complex values, row-major) on `gpu`.
    pub fn new(gpu: &Gpu, data: &Tensor, size: usize) -> Result<Transform2, GpuError> {
        data.expect_len(2 * size * size)?;
        let plan = Bluestein::new(gpu, size)?;
        let work = [
            complex(gpu, "fft work a", size * plan.m, None)?,
            complex(gpu, "fft work b", size * plan.m, None)?,
        ];
        let work = [&work[0], &work[1]];
        let (mut forward, mut inverse) = (Vec::new(), Vec::new());
        let scale = 1.0 / (size * size) as f32;
        for (inv, list) in [(false, &mut forward), (true, &mut inverse)] {
            plan.dispatches(gpu, data, work, (size, size, 1), inv, 1.0, list)?;
            let last = if inv { scale } else { 1.0 };
            plan.dispatches(gpu, data, work, (size, 1, size), inv, last, list)?;
        }
        Ok(Transform2 {
            size,
            forward,
            inverse,
        })
    }

    /// The side of the arrays it transforms.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Records the forward transform.
    pub fn record_forward(&self, rec: &mut Recorder) {
        rec.dispatch_all(&self.forward);
    }

    /// Records the inverse transform.
    pub fn record_inverse(&self, rec: &mut Recorder) {
        rec.dispatch_all(&self.inverse);
    }
}

/// Linear filtering of `n × n` real maps on a zero-padded `size × size` square:
/// `out = F⁻¹[F(map) · factor]`, cropped to `n × n` (the real part): with the kernel's
/// spectrum as the factor a convolution, with a thresholded inverse of it an inverse
/// filter. The GPU side of `polish::Convolver`, which holds the f64 spectrum.
pub struct Convolution {
    gpu: Arc<Gpu>,
    n: usize,
    transform: Transform2,
    data: Tensor,
    factor: Tensor,
    /// The spectrum the factor holds now, when it is the convolution's.
    spectrum: Vec<[f32; 2]>,
    holds_spectrum: bool,
    multiply: Dispatch,
    readback: Readback,
    staging: Vec<[f32; 2]>,
    host: Vec<f32>,
}

impl Convolution {
    /// For `n × n` maps and the kernel spectrum `spectrum` (`size²` values, `size ≥ n`).
    pub fn new(gpu: Arc<Gpu>, n: usize, spectrum: &[Complex64]) -> Result<Convolution, GpuError> {
        let size = spectrum.len().isqrt();
        if size * size != spectrum.len() || size < n || n == 0 {
            return Err(GpuError::Shape {
                tensor: "convolution spectrum".into(),
                expected: format!("a square of side at least {n}"),
                got: format!("{} values", spectrum.len()),
            });
        }
        let data = complex(&gpu, "convolution data", size * size, None)?;
        let spectrum = to_f32(spectrum);
        let factor = complex(&gpu, "convolution factor", size * size, None)?;
        gpu.write(&factor, &spectrum)?;
        let transform = Transform2::new(&gpu, &data, size)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let params = Params {
            period: (size * size) as u32,
            count: (size * size) as u32,
            ..Params::default()
        };
        let multiply = gpu.dispatch(
            &MUL,
            &[],
            &params,
            &[&factor, &data],
            grid_1d(size * size, 256, max),
        )?;
        let readback = Readback::new(&gpu, "convolution", data.byte_len())?;
        Ok(Convolution {
            gpu,
            n,
            transform,
            data,
            factor,
            spectrum,
            holds_spectrum: true,
            multiply,
            readback,
            staging: vec![[0.0; 2]; size * size],
            host: vec![0.0; 2 * size * size],
        })
    }

    /// The side of the padded square.
    pub fn size(&self) -> usize {
        self.transform.size()
    }

    /// The adapter it runs on.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// The adapter, shared (for another convolution on it).
    pub fn shared_gpu(&self) -> Arc<Gpu> {
        self.gpu.clone()
    }

    /// `out = map ∗ kernel`, both `n × n`.
    pub fn convolve(&mut self, map: &[f64], out: &mut [f64]) -> Result<(), GpuError> {
        if !self.holds_spectrum {
            self.gpu.write(&self.factor, &self.spectrum)?;
            self.holds_spectrum = true;
        }
        self.run(map, out)
    }

    /// `out = F⁻¹[F(map) · factor]` cropped to `n × n`, `factor` on the padded square.
    pub fn filter(
        &mut self,
        map: &[f64],
        out: &mut [f64],
        factor: &[Complex64],
    ) -> Result<(), GpuError> {
        let size = self.size();
        if factor.len() != size * size {
            return Err(GpuError::Shape {
                tensor: "convolution factor".into(),
                expected: format!("{} values", size * size),
                got: format!("{}", factor.len()),
            });
        }
        self.gpu.write(&self.factor, &to_f32(factor))?;
        self.holds_spectrum = false;
        self.run(map, out)
    }

    fn run(&mut self, map: &[f64], out: &mut [f64]) -> Result<(), GpuError> {
        let (n, size) = (self.n, self.size());
        for (what, len) in [
            ("convolution map", map.len()),
            ("convolution output", out.len()),
        ] {
            if len != n * n {
                return Err(GpuError::Shape {
                    tensor: what.into(),
                    expected: format!("{} values", n * n),
                    got: format!("{len}"),
                });
            }
        }
        for r in 0..n {
            for c in 0..n {
                self.staging[r * size + c] = [map[r * n + c] as f32, 0.0];
            }
        }
        self.gpu.write(&self.data, &self.staging)?;
        let mut rec = Recorder::new(&self.gpu);
        self.transform.record_forward(&mut rec);
        rec.dispatch(&self.multiply);
        self.transform.record_inverse(&mut rec);
        rec.read_into(&self.data, &self.readback)?;
        rec.submit()?;
        self.readback.read_into(&self.gpu, &mut self.host)?;
        for r in 0..n {
            for c in 0..n {
                out[r * n + c] = f64::from(self.host[2 * (r * size + c)]);
            }
        }
        Ok(())
    }
}

/// The reference: the DFT of each `n`-long row of `x` by its definition in f64,
/// `X[j] = Σ_k x[k]·exp(∓2πi·jk/n)` (unnormalised both ways).
pub fn dft_rows(x: &[Complex64], n: usize, inverse: bool) -> Vec<Complex64> {
    let sign = if inverse { 1.0 } else { -1.0 };
    let mut out = vec![Complex64::default(); x.len()];
    for (row, dst) in x.chunks(n).zip(out.chunks_mut(n)) {
        for (j, d) in dst.iter_mut().enumerate() {
            *d = row
                .iter()
                .enumerate()
                .map(|(k, v)| {
                    let q = (j * k) % n;
                    v * Complex64::from_polar(
                        1.0,
                        sign * std::f64::consts::TAU * q as f64 / n as f64,
                    )
                })
                .sum();
        }
    }
    out
}

/// The reference 2-D DFT of the `size × size` array `x`: rows, then columns; the inverse
/// divided by `size²`.
pub fn dft2(x: &[Complex64], size: usize, inverse: bool) -> Vec<Complex64> {
    let transpose = |v: &[Complex64]| {
        let mut t = vec![Complex64::default(); v.len()];
        for r in 0..size {
            for c in 0..size {
                t[c * size + r] = v[r * size + c];
            }
        }
        t
    };
    let rows = dft_rows(x, size, inverse);
    let mut out = transpose(&dft_rows(&transpose(&rows), size, inverse));
    if inverse {
        let scale = 1.0 / (size * size) as f64;
        out.iter_mut().for_each(|v| *v *= scale);
    }
    out
}
