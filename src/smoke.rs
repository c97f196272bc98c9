//! The smoke check of a device (`iastgcn smoke`): the kernel families the model leans on
//! (products, the split reductions of weight gradients, the LayerNorm, the gate),
//! and the mirror's (the pad's removal, the dwell solve's FFTs), run once on the device,
//! are compared with the f64 CPU reference and are timed. A quick "does this GPU work"
//! for a new machine.

use std::time::Instant;

use crate::error::{Error, Result};
use crate::gpu::{DType, Dispatch, Gpu, Recorder, Tensor};
use crate::model::block::residual_layer_norm::layer_norm_kernel::{self, LayerNorm};
use crate::ops::elementwise::{self, Binary, Unary};
use crate::ops::fft::{dft2, Transform2};
use crate::ops::matmul::{self, Matmul};
use crate::ops::removal::{Accumulator, Footprint, Tick};
use crate::ops::Accumulate;
use crate::testing::{rng, round_f32, to_f32, uniform, worst, Tolerance, Worst};

/// The sizes and seed of the smoke check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SmokeOptions {
    /// Seed of the random inputs.
    pub seed: u64,
    /// Rows of the activation matrix (B·N·T of a layer); 1400 = 1 window of 14 nodes ×
    /// 100 steps.
    pub rows: usize,
    /// Channels (C of docs/model.md).
    pub channels: usize,
}

impl Default for SmokeOptions {
    fn default() -> SmokeOptions {
        SmokeOptions {
            seed: 7,
            rows: 1400,
            channels: 64,
        }
    }
}

/// One tensor of the smoke check compared with its reference.
#[derive(Clone, Debug)]
pub struct SmokeRow {
    /// The tensor compared, e.g. `matmul backward dW`.
    pub name: String,
    /// The kernels that computed it, run and timed together, e.g.
    /// `matmul [1400,64]x[64,64] fwd+bwd`; rows of one group share `seconds` and `flops`.
    pub group: String,
    /// The element furthest from the reference relative to its tolerance (its absolute
    /// and relative error, and that ratio).
    pub worst: Worst,
    /// The tolerance the tensor was checked against.
    pub tolerance: Tolerance,
    /// Whether every element is within the tolerance (`worst.ratio <= 1`).
    pub pass: bool,
    /// Wall time of one run of the group's kernels.
    pub seconds: f64,
    /// Whether `seconds` includes compiling the pipelines (a first run) rather than the
    /// mean of warm runs.
    pub includes_compile: bool,
    /// Floating-point operations of one run of the group, where counted.
    pub flops: Option<f64>,
}

/// Runs every kernel family of the check once on `gpu`, compares each output with the
/// f64 CPU reference and times it: one row per tensor compared, failing rows included
/// (`Err` only when the device or a tensor cannot be used).
pub fn smoke(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let mut rows = matmul_check(gpu, options)?;
    rows.extend(reduction_check(gpu, options)?);
    rows.extend(layer_norm_check(gpu, options)?);
    rows.extend(gated_unit_check(gpu, options)?);
    rows.extend(removal_check(gpu, options)?);
    rows.extend(fft_check(gpu, options)?);
    Ok(rows)
}

/// What one group of kernels produced: the tensors to compare and how it was timed.
struct Group<'a> {
    name: String,
    seconds: f64,
    includes_compile: bool,
    flops: Option<f64>,
    checks: Vec<(&'a str, Output<'a>, &'a [f64], Tolerance)>,
}

/// What a kernel produced: a tensor still on the device, or values already read back.
enum Output<'a> {
    Device(&'a Tensor),
    Host(Vec<f64>),
}

impl Group<'_> {
    fn rows(self, gpu: &Gpu) -> Result<Vec<SmokeRow>> {
        self.checks
            .into_iter()
            .map(|(what, output, expected, tolerance)| {
                let got = match output {
                    Output::Device(tensor) => {
                        let got = gpu.read_f32(tensor)?;
                        got[..tensor.numel()].iter().map(|&v| v as f64).collect()
                    }
                    Output::Host(values) => values,
                };
                let worst = worst(what, &got, expected, tolerance).map_err(Error::Invalid)?;
                Ok(SmokeRow {
                    name: what.to_string(),
                    group: self.name.clone(),
                    pass: worst.ratio <= 1.0,
                    worst,
                    tolerance,
                    seconds: self.seconds,
                    includes_compile: self.includes_compile,
                    flops: self.flops,
                })
            })
            .collect()
    }
}

/// `values` on the device as a flat f32 tensor.
fn upload_flat(gpu: &Gpu, name: &str, values: &[f64]) -> Result<Tensor> {
    Ok(gpu.upload(name, &[values.len()], &to_f32(values))?)
}

/// Runs `step` once in one submit and waits; the seconds it took, its pipelines'
/// compilation included.
fn run_timed(gpu: &Gpu, step: &[Dispatch]) -> Result<f64> {
    let t0 = Instant::now();
    gpu.run(step)?;
    Ok(t0.elapsed().as_secs_f64())
}

/// A 1×1 convolution as the model runs it: `Y = X · W` with W shared, and its backward.
fn matmul_check(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let (r, c) = (options.rows, options.channels);
    let mm = Matmul::new(r, c, c);
    let mut g = rng(options.seed);
    let x = round_f32(&uniform(&mut g, mm.a_len(), -1.0, 1.0));
    let w = round_f32(&uniform(&mut g, mm.b_len(), -1.0, 1.0));
    let dy = round_f32(&uniform(&mut g, mm.c_len(), -1.0, 1.0));
    let xt = gpu.upload("x", &[r, c], &to_f32(&x))?;
    let wt = gpu.upload("w", &[c, c], &to_f32(&w))?;
    let dyt = gpu.upload("dy", &[r, c], &to_f32(&dy))?;
    let yt = gpu.zeros("y", &[r, c], DType::F32)?;
    let dxt = gpu.zeros("dx", &[r, c], DType::F32)?;
    let dwt = gpu.zeros("dw", &[c, c], DType::F32)?;
    let step = [
        mm.forward(gpu, &xt, &wt, &yt, Accumulate::Overwrite)?,
        mm.backward_a(gpu, &wt, &dyt, &dxt, Accumulate::Overwrite)?,
        mm.backward_b(gpu, &xt, &dyt, &dwt, Accumulate::Overwrite)?,
    ];
    gpu.run(&step)?; // warm-up: the first dispatch of a pipeline JIT-compiles it
    let reps = 5;
    let t0 = Instant::now();
    let mut rec = Recorder::new(gpu);
    for _ in 0..reps {
        rec.dispatch_all(&step);
    }
    rec.submit()?;
    gpu.wait()?;
    let seconds = t0.elapsed().as_secs_f64() / reps as f64;
    let y = matmul::cpu::forward(&mm, &x, &w);
    let (dx, dw) = matmul::cpu::backward(&mm, &x, &w, &dy);
    // f32 sums of `k` products of |v| ≤ 1: a few ulps times √k, far below any real bug.
    let tol = |k: usize| Tolerance::new(1e-6 * (k as f64).sqrt() * 4.0, 1e-4);
    Group {
        name: format!("matmul [{r},{c}]x[{c},{c}] fwd+bwd"),
        seconds,
        includes_compile: false,
        flops: Some(3.0 * mm.flops()),
        checks: vec![
            ("matmul forward", Output::Device(&yt), &y, tol(c)),
            ("matmul backward dX", Output::Device(&dxt), &dx, tol(c)),
            ("matmul backward dW", Output::Device(&dwt), &dw, tol(r)),
        ],
    }
    .rows(gpu)
}

/// Weight gradients summed over a batch as the model's are, split into partial sums
/// that a second launch adds, which a GPU plans differently from a CPU adapter
/// (`ops::matmul`'s split reduction): a 1×1 convolution's W over 112 windows of 100
/// steps, and a rank-1 weight's single row (the temporal attention's U1: 14 values over
/// 64 items of C·100 steps, the most partial sums per output on a GPU).
fn reduction_check(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let c = options.channels;
    let conv = Matmul::new(100, c, c).batched(112).share_b(true);
    let row = Matmul::new(1, c * 100, 14).batched(64).share_a(true);
    let mut g = rng(options.seed + 4);
    let mut inputs = |mm: &Matmul| {
        let mut draw = |n: usize| round_f32(&uniform(&mut g, n, -1.0, 1.0));
        (draw(mm.a_len()), draw(mm.b_len()), draw(mm.c_len()))
    };
    let (cx, cw, cdy) = inputs(&conv);
    let (ru, rx, rdy) = inputs(&row);
    let up = |name: &str, v: &[f64]| upload_flat(gpu, name, v);
    let (cxt, cdyt, rxt, rdyt) = (
        up("x", &cx)?,
        up("dy", &cdy)?,
        up("x", &rx)?,
        up("dy", &rdy)?,
    );
    let dw = gpu.zeros("dW", &[c, c], DType::F32)?;
    let du = gpu.zeros("dU1", &[14], DType::F32)?;
    let step = [
        conv.backward_b(gpu, &cxt, &cdyt, &dw, Accumulate::Overwrite)?,
        row.backward_a(gpu, &rxt, &rdyt, &du, Accumulate::Overwrite)?,
    ];
    let seconds = run_timed(gpu, &step)?;
    let (_, dw_ref) = matmul::cpu::backward(&conv, &cx, &cw, &cdy);
    let (du_ref, _) = matmul::cpu::backward(&row, &ru, &rx, &rdy);
    let tol = |k: usize| Tolerance::new(1e-6 * (k as f64).sqrt() * 4.0, 1e-4);
    Group {
        name: format!("split weight gradients [{c},{c}] x112, [1,14] x64"),
        seconds,
        includes_compile: true,
        flops: Some(conv.flops() + row.flops()),
        checks: vec![
            (
                "batch-summed dW",
                Output::Device(&dw),
                &dw_ref,
                tol(112 * 100),
            ),
            (
                "batch-summed row",
                Output::Device(&du),
                &du_ref,
                tol(64 * c * 100),
            ),
        ],
    }
    .rows(gpu)
}

/// The channel LayerNorm of docs/model.md step 6 over 224 rows of C channels and 100
/// steps, forward and backward: the parameter gradients sum 22 400 terms per channel,
/// split over slices of the rows (`layer_norm_kernel`).
fn layer_norm_check(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let c = options.channels;
    let ln = LayerNorm::new(224, c, 100);
    let mut g = rng(options.seed + 5);
    let x = round_f32(&uniform(&mut g, ln.len(), -2.0, 3.0));
    let gamma = round_f32(&uniform(&mut g, c, 0.5, 1.5));
    let beta = round_f32(&uniform(&mut g, c, -0.5, 0.5));
    let dy = round_f32(&uniform(&mut g, ln.len(), -1.0, 1.0));
    let up = |name: &str, v: &[f64]| upload_flat(gpu, name, v);
    let (xt, gt, bt, dyt) = (
        up("x", &x)?,
        up("gamma", &gamma)?,
        up("beta", &beta)?,
        up("dy", &dy)?,
    );
    let z = |name: &str, n: usize| gpu.zeros(name, &[n], DType::F32);
    let (y, mean, rstd) = (
        z("y", ln.len())?,
        z("mean", ln.rows())?,
        z("rstd", ln.rows())?,
    );
    let (dx, dg, db) = (z("dx", ln.len())?, z("dgamma", c)?, z("dbeta", c)?);
    let new = Accumulate::Overwrite;
    let step = [
        ln.forward(gpu, &xt, &gt, &bt, &y, &mean, &rstd)?,
        ln.backward_input(gpu, &xt, &gt, &dyt, &mean, &rstd, &dx, new)?,
        ln.backward_params(gpu, &xt, &dyt, &mean, &rstd, &dg, &db, new)?,
    ];
    let seconds = run_timed(gpu, &step)?;
    let y_ref = layer_norm_kernel::cpu::forward(&ln, &x, &gamma, &beta);
    let (dx_ref, dg_ref, db_ref) = layer_norm_kernel::cpu::backward(&ln, &x, &gamma, &dy);
    // Normalised values are O(1); the parameter gradients sum `rows` such terms.
    let tol = Tolerance::new(5e-5, 5e-5);
    let sums = Tolerance::new(8e-6 * (ln.rows() as f64).sqrt(), 1e-4);
    Group {
        name: format!("layernorm [224,{c},100] fwd+bwd"),
        seconds,
        includes_compile: true,
        flops: None,
        checks: vec![
            ("layernorm y", Output::Device(&y), &y_ref, tol),
            ("layernorm dX", Output::Device(&dx), &dx_ref, tol),
            ("layernorm dgamma", Output::Device(&dg), &dg_ref, sums),
            ("layernorm dbeta", Output::Device(&db), &db_ref, sums),
        ],
    }
    .rows(gpu)
}

/// The gate of docs/model.md step 4, `H = tanh(F) ⊙ σ(G)`, forward and backward.
fn gated_unit_check(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let n = options.rows * options.channels;
    let mut g = rng(options.seed + 1);
    let f = round_f32(&uniform(&mut g, n, -3.0, 3.0));
    let gg = round_f32(&uniform(&mut g, n, -3.0, 3.0));
    let dh = round_f32(&uniform(&mut g, n, -1.0, 1.0));
    let shape = [n];
    let ft = upload_flat(gpu, "filter", &f)?;
    let gt = upload_flat(gpu, "gate", &gg)?;
    let dht = upload_flat(gpu, "dH", &dh)?;
    let z = |name: &str| gpu.zeros(name, &shape, DType::F32);
    let (tf, sg, h, dtf, dsg, df, dg) = (
        z("tanh")?,
        z("sigma")?,
        z("H")?,
        z("dtanh")?,
        z("dsigma")?,
        z("dF")?,
        z("dG")?,
    );
    let new = Accumulate::Overwrite;
    let step = [
        elementwise::unary_forward(gpu, Unary::Tanh, &ft, &tf, new)?,
        elementwise::unary_forward(gpu, Unary::Sigmoid, &gt, &sg, new)?,
        elementwise::binary_forward(gpu, Binary::Mul, &tf, &sg, &h, new)?,
        elementwise::binary_backward(gpu, Binary::Mul, &sg, &dht, &dtf, new)?,
        elementwise::binary_backward(gpu, Binary::Mul, &tf, &dht, &dsg, new)?,
        elementwise::unary_backward(gpu, Unary::Tanh, &tf, &dtf, &df, new)?,
        elementwise::unary_backward(gpu, Unary::Sigmoid, &sg, &dsg, &dg, new)?,
    ];
    let seconds = run_timed(gpu, &step)?;
    let tf_ref = elementwise::cpu::unary_forward(Unary::Tanh, &f);
    let sg_ref = elementwise::cpu::unary_forward(Unary::Sigmoid, &gg);
    let h_ref = elementwise::cpu::binary_forward(Binary::Mul, &tf_ref, &sg_ref);
    let (dtf_ref, dsg_ref) = elementwise::cpu::binary_backward(Binary::Mul, &tf_ref, &sg_ref, &dh);
    let df_ref = elementwise::cpu::unary_backward(Unary::Tanh, &f, &dtf_ref);
    let dg_ref = elementwise::cpu::unary_backward(Unary::Sigmoid, &gg, &dsg_ref);
    let tol = Tolerance::new(1e-6, 1e-5);
    Group {
        name: format!("gated unit tanh(F)*sigmoid(G) fwd+bwd on {n} elements"),
        seconds,
        includes_compile: true,
        flops: None,
        checks: vec![
            ("gate H", Output::Device(&h), &h_ref, tol),
            ("gate dF", Output::Device(&df), &df_ref, tol),
            ("gate dG", Output::Device(&dg), &dg_ref, tol),
        ],
    }
    .rows(gpu)
}

/// The pad's removal (`ops::removal`): random tilted ticks of the twin's pad over a
/// 64 × 64 map of 1 mm pixels, laid in batches of 256, against the f64 reference.
fn removal_check(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let (n, pitch, count) = (64, 1.0, 600);
    let footprint = Footprint {
        radius: 15.0,
        orbit: 6.0,
        preston: 2.4e-6,
        speed: std::f64::consts::TAU * 6.0 * 300.0 / 60.0,
        glass: 29.0,
    };
    let mut g = rng(options.seed + 2);
    let glass: Vec<bool> = (0..n * n)
        .map(|i| {
            let (r, c) = ((i / n) as f64 + 0.5 - 32.0, (i % n) as f64 + 0.5 - 32.0);
            r.hypot(c) <= 29.0
        })
        .collect();
    let values = uniform(&mut g, 5 * count, -1.0, 1.0);
    let ticks: Vec<Tick> = values
        .chunks(5)
        .map(|v| Tick {
            centre: [38.0 * v[0], 38.0 * v[1]],
            force: 700.0 * (0.125 + 0.075 * v[2]),
            gradient: [1e-3 * v[3], 1e-3 * v[4]],
            seconds: 0.02,
        })
        .collect();
    let mut expected = vec![0.0; n * n];
    for t in &ticks {
        footprint.remove_tick(n, pitch, &glass, t, &mut expected);
    }
    let mut acc = Accumulator::new(gpu, n, pitch, &glass, footprint, 256)?;
    let t0 = Instant::now();
    for t in &ticks {
        acc.push(t)?;
    }
    let mut got = vec![0.0; n * n];
    acc.finish(&mut got)?;
    let seconds = t0.elapsed().as_secs_f64();
    let peak = expected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    Group {
        name: format!("removal: {count} ticks over a {n}x{n} map"),
        seconds,
        includes_compile: true,
        flops: None,
        checks: vec![(
            "removal",
            Output::Host(got),
            &expected,
            Tolerance::new(1e-4 * peak, 1e-4),
        )],
    }
    .rows(gpu)
}

/// The dwell solve's 2-D DFT (`ops::fft`): a random complex array of side 281 (the prime
/// in the mirror's padded sides, 562 and 1124), forward, against the f64 DFT.
fn fft_check(gpu: &Gpu, options: &SmokeOptions) -> Result<Vec<SmokeRow>> {
    let side = 281;
    let mut g = rng(options.seed + 3);
    let x = round_f32(&uniform(&mut g, 2 * side * side, -1.0, 1.0));
    let data = gpu.upload("fft data", &[side * side, 2], &to_f32(&x))?;
    let transform = Transform2::new(gpu, &data, side)?;
    let t0 = Instant::now();
    let mut rec = Recorder::new(gpu);
    transform.record_forward(&mut rec);
    rec.submit()?;
    gpu.wait()?;
    let seconds = t0.elapsed().as_secs_f64();
    let complex: Vec<rustfft::num_complex::Complex64> = x
        .chunks(2)
        .map(|v| rustfft::num_complex::Complex64::new(v[0], v[1]))
        .collect();
    let expected: Vec<f64> = dft2(&complex, side, false)
        .iter()
        .flat_map(|v| [v.re, v.im])
        .collect();
    let peak = expected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    Group {
        name: format!("fft 2-D forward, side {side} (Bluestein)"),
        seconds,
        includes_compile: true,
        flops: None,
        checks: vec![(
            "fft 2-D forward",
            Output::Device(&data),
            &expected,
            Tolerance::new(2e-6 * peak, 2e-6),
        )],
    }
    .rows(gpu)
}
