//! `iastgcn smoke`: run every kernel family once on the device, check it against the f64
//! CPU reference, and time it. A quick "does this GPU work" for a new machine.

use std::time::Instant;

use anyhow::anyhow;

use iastgcn::gpu::{Gpu, Recorder};
use iastgcn::ops::elementwise::{self, Binary, Unary};
use iastgcn::ops::matmul::{self, Matmul};
use iastgcn::ops::Accumulate;
use iastgcn::testing::{compare_tensor, rng, round_f32, to_f32, uniform, Tolerance};

#[derive(clap::Args)]
pub struct SmokeArgs {
    /// Seed of the random inputs.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Rows of the activation matrix (B·N·T of a layer); 1400 = 1 window of 14 nodes × 100 steps.
    #[arg(long, default_value_t = 1400)]
    rows: usize,
    /// Channels (C of docs/model.md).
    #[arg(long, default_value_t = 64)]
    channels: usize,
}

pub fn run(gpu: &Gpu, args: &SmokeArgs) -> anyhow::Result<()> {
    println!("smoke test on {}", gpu.info().name);
    matmul_check(gpu, args)?;
    gated_unit_check(gpu, args)?;
    println!("all kernels match the CPU reference");
    Ok(())
}

/// A 1×1 convolution as the model runs it: `Y = X · W` with W shared, and its backward.
fn matmul_check(gpu: &Gpu, args: &SmokeArgs) -> anyhow::Result<()> {
    let (r, c) = (args.rows, args.channels);
    let mm = Matmul::new(r, c, c);
    let mut g = rng(args.seed);
    let x = round_f32(&uniform(&mut g, mm.a_len(), -1.0, 1.0));
    let w = round_f32(&uniform(&mut g, mm.b_len(), -1.0, 1.0));
    let dy = round_f32(&uniform(&mut g, mm.c_len(), -1.0, 1.0));
    let xt = gpu.upload("x", &[r, c], &to_f32(&x))?;
    let wt = gpu.upload("w", &[c, c], &to_f32(&w))?;
    let dyt = gpu.upload("dy", &[r, c], &to_f32(&dy))?;
    let yt = gpu.zeros("y", &[r, c], iastgcn::gpu::DType::F32);
    let dxt = gpu.zeros("dx", &[r, c], iastgcn::gpu::DType::F32);
    let dwt = gpu.zeros("dw", &[c, c], iastgcn::gpu::DType::F32);
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
    rec.submit();
    gpu.wait()?;
    let secs = t0.elapsed().as_secs_f64() / reps as f64;
    let y = matmul::cpu::forward(&mm, &x, &w);
    let (dx, dw) = matmul::cpu::backward(&mm, &x, &w, &dy);
    // f32 sums of `k` products of |v| ≤ 1: a few ulps times √k, far below any real bug.
    let tol = |k: usize| Tolerance::new(1e-6 * (k as f64).sqrt() * 4.0, 1e-4);
    let worst = [
        compare_tensor(gpu, "matmul forward", &yt, &y, tol(c)),
        compare_tensor(gpu, "matmul backward dX", &dxt, &dx, tol(c)),
        compare_tensor(gpu, "matmul backward dW", &dwt, &dw, tol(r)),
    ]
    .into_iter()
    .collect::<Result<Vec<_>, String>>()
    .map_err(|e| anyhow!(e))?;
    let flops = 3.0 * mm.flops();
    println!(
        "  matmul [{r},{c}]x[{c},{c}] fwd+bwd   {:7.2} ms  {:6.2} GFLOP/s  worst rel err {:.1e}",
        secs * 1e3,
        flops / secs / 1e9,
        worst.iter().map(|w| w.rel_err).fold(0.0, f64::max)
    );
    Ok(())
}

/// The gate of docs/model.md step 4, `H = tanh(F) ⊙ σ(G)`, forward and backward.
fn gated_unit_check(gpu: &Gpu, args: &SmokeArgs) -> anyhow::Result<()> {
    let n = args.rows * args.channels;
    let mut g = rng(args.seed + 1);
    let f = round_f32(&uniform(&mut g, n, -3.0, 3.0));
    let gg = round_f32(&uniform(&mut g, n, -3.0, 3.0));
    let dh = round_f32(&uniform(&mut g, n, -1.0, 1.0));
    let shape = [n];
    let ft = gpu.upload("filter", &shape, &to_f32(&f))?;
    let gt = gpu.upload("gate", &shape, &to_f32(&gg))?;
    let dht = gpu.upload("dH", &shape, &to_f32(&dh))?;
    let z = |name: &str| gpu.zeros(name, &shape, iastgcn::gpu::DType::F32);
    let (tf, sg, h, dtf, dsg, df, dg) = (
        z("tanh"),
        z("sigma"),
        z("H"),
        z("dtanh"),
        z("dsigma"),
        z("dF"),
        z("dG"),
    );
    let step = [
        elementwise::unary_forward(gpu, Unary::Tanh, &ft, &tf, Accumulate::Overwrite)?,
        elementwise::unary_forward(gpu, Unary::Sigmoid, &gt, &sg, Accumulate::Overwrite)?,
        elementwise::binary_forward(gpu, Binary::Mul, &tf, &sg, &h, Accumulate::Overwrite)?,
        elementwise::binary_backward(gpu, Binary::Mul, &sg, &dht, &dtf, Accumulate::Overwrite)?,
        elementwise::binary_backward(gpu, Binary::Mul, &tf, &dht, &dsg, Accumulate::Overwrite)?,
        elementwise::unary_backward(gpu, Unary::Tanh, &tf, &dtf, &df, Accumulate::Overwrite)?,
        elementwise::unary_backward(gpu, Unary::Sigmoid, &sg, &dsg, &dg, Accumulate::Overwrite)?,
    ];
    let t0 = Instant::now();
    gpu.run(&step)?;
    let secs = t0.elapsed().as_secs_f64();
    let tf_ref = elementwise::cpu::unary_forward(Unary::Tanh, &f);
    let sg_ref = elementwise::cpu::unary_forward(Unary::Sigmoid, &gg);
    let h_ref = elementwise::cpu::binary_forward(Binary::Mul, &tf_ref, &sg_ref);
    let (dtf_ref, dsg_ref) = elementwise::cpu::binary_backward(Binary::Mul, &tf_ref, &sg_ref, &dh);
    let df_ref = elementwise::cpu::unary_backward(Unary::Tanh, &f, &dtf_ref);
    let dg_ref = elementwise::cpu::unary_backward(Unary::Sigmoid, &gg, &dsg_ref);
    let tol = Tolerance::new(1e-6, 1e-5);
    for (what, t, r) in [
        ("gate H", &h, &h_ref),
        ("gate dF", &df, &df_ref),
        ("gate dG", &dg, &dg_ref),
    ] {
        compare_tensor(gpu, what, t, r, tol).map_err(|e| anyhow!(e))?;
    }
    println!("  gated unit tanh(F)*sigmoid(G) fwd+bwd on {n} elements  {:7.2} ms (first run, includes JIT)", secs * 1e3);
    Ok(())
}
