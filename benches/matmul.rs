//! Matmul GFLOP/s at shapes the model runs, against a single-threaded CPU loop measured in
//! the same run, plus the fixed costs of one dispatch and of one submit (+ readback).
//!
//! Criterion's "thrpt" column is in FLOP/s for the matmul groups (elements = FLOPs).

use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use iastgcn::gpu::{DType, Dispatch, Gpu, Readback, Recorder};
use iastgcn::ops::elementwise::{self, Unary};
use iastgcn::ops::matmul::Matmul;
use iastgcn::ops::Accumulate;
use iastgcn::testing::{rng, to_f32, uniform};

/// Records `d` `iters` times into one submit and waits: per-dispatch time with the submit
/// amortised away.
fn time_dispatches(gpu: &Gpu, d: &Dispatch, iters: u64) -> Duration {
    let t0 = Instant::now();
    let mut rec = Recorder::new(gpu);
    for _ in 0..iters {
        rec.dispatch(d);
    }
    rec.submit().unwrap();
    gpu.wait().unwrap();
    t0.elapsed()
}

/// Which pass of the product is timed.
#[derive(Clone, Copy)]
enum Pass {
    Forward,
    GradA,
    GradB,
}

fn gpu_case(gpu: &Gpu, mm: Matmul, pass: Pass) -> Dispatch {
    let mut g = rng(1);
    let a = gpu
        .upload(
            "a",
            &[mm.a_len()],
            &to_f32(&uniform(&mut g, mm.a_len(), -1.0, 1.0)),
        )
        .unwrap();
    let b = gpu
        .upload(
            "b",
            &[mm.b_len()],
            &to_f32(&uniform(&mut g, mm.b_len(), -1.0, 1.0)),
        )
        .unwrap();
    let c = gpu
        .upload(
            "c",
            &[mm.c_len()],
            &to_f32(&uniform(&mut g, mm.c_len(), -1.0, 1.0)),
        )
        .unwrap();
    match pass {
        Pass::Forward => mm.forward(gpu, &a, &b, &c, Accumulate::Overwrite),
        Pass::GradA => mm.backward_a(
            gpu,
            &b,
            &c,
            &gpu.zeros("da", &[mm.a_len()], DType::F32).unwrap(),
            Accumulate::Overwrite,
        ),
        Pass::GradB => mm.backward_b(
            gpu,
            &a,
            &c,
            &gpu.zeros("db", &[mm.b_len()], DType::F32).unwrap(),
            Accumulate::Overwrite,
        ),
    }
    .unwrap()
}

/// Plain single-threaded ikj loop over f32: the in-run baseline.
fn cpu_matmul(m: usize, n: usize, k: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    c.fill(0.0);
    for i in 0..m {
        let ci = &mut c[i * n..(i + 1) * n];
        for kk in 0..k {
            let av = a[i * k + kk];
            let bk = &b[kk * n..(kk + 1) * n];
            for (cj, bj) in ci.iter_mut().zip(bk) {
                *cj += av * bj;
            }
        }
    }
}

fn matmul(c: &mut Criterion) {
    let gpu = Gpu::new().expect("a GPU adapter (make bench installs lavapipe)");
    let rows = 64 * 14 * 100; // B·N·T of the paper's shape
    let cases = [
        (
            "conv1x1 fwd [89600,64]x[64,64]",
            Matmul::new(rows, 64, 64),
            Pass::Forward,
        ),
        (
            "conv1x1 dX [89600,64]x[64,64]^T",
            Matmul::new(rows, 64, 64),
            Pass::GradA,
        ),
        (
            "conv1x1 dW [89600,64]^T x[89600,64]",
            Matmul::new(rows, 64, 64),
            Pass::GradB,
        ),
        (
            "attention 64x[100,14]x[14,100]",
            Matmul::new(100, 100, 14).batched(64),
            Pass::Forward,
        ),
        (
            "square [512,512]x[512,512]",
            Matmul::new(512, 512, 512),
            Pass::Forward,
        ),
    ];
    let mut group = c.benchmark_group("matmul");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for (name, mm, pass) in cases {
        let d = gpu_case(&gpu, mm, pass);
        gpu.run(std::slice::from_ref(&d)).unwrap(); // JIT-compile outside the timing
        group.throughput(Throughput::Elements(mm.flops() as u64));
        group.bench_function(BenchmarkId::new("gpu", name), |bch| {
            bch.iter_custom(|iters| time_dispatches(&gpu, &d, iters))
        });
    }
    for (name, (m, n, k)) in [
        ("conv1x1 fwd [89600,64]x[64,64]", (rows, 64, 64)),
        ("square [512,512]x[512,512]", (512, 512, 512)),
    ] {
        let mut g = rng(2);
        let a = to_f32(&uniform(&mut g, m * k, -1.0, 1.0));
        let b = to_f32(&uniform(&mut g, k * n, -1.0, 1.0));
        let mut out = vec![0.0f32; m * n];
        group.throughput(Throughput::Elements(Matmul::new(m, n, k).flops() as u64));
        group.bench_function(BenchmarkId::new("cpu-1thread-baseline", name), |bch| {
            bch.iter(|| cpu_matmul(m, n, k, &a, &b, std::hint::black_box(&mut out)))
        });
    }
    group.finish();
}

fn fixed_costs(c: &mut Criterion) {
    let gpu = Gpu::new().expect("a GPU adapter (make bench installs lavapipe)");
    let x = gpu.upload("x", &[64], &[0.5; 64]).unwrap();
    let y = gpu.zeros("y", &[64], DType::F32).unwrap();
    let tiny =
        elementwise::unary_forward(&gpu, Unary::Relu, &x, &y, Accumulate::Overwrite).unwrap();
    gpu.run(std::slice::from_ref(&tiny)).unwrap();
    let rb = Readback::new(&gpu, "y", 4).unwrap();
    let scalar = gpu.zeros("loss", &[1], DType::F32).unwrap();
    let mut group = c.benchmark_group("fixed_cost");
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(3));
    group.bench_function("dispatch in a shared pass (64-element relu)", |bch| {
        bch.iter_custom(|iters| time_dispatches(&gpu, &tiny, iters))
    });
    group.bench_function("submit + wait (1 dispatch)", |bch| {
        bch.iter(|| {
            let mut rec = Recorder::new(&gpu);
            rec.dispatch(&tiny);
            rec.submit().unwrap();
            gpu.wait().unwrap();
        })
    });
    group.bench_function("submit + wait + 4-byte readback (1 dispatch)", |bch| {
        bch.iter(|| {
            let mut rec = Recorder::new(&gpu);
            rec.dispatch(&tiny);
            rec.read_into(&scalar, &rb).unwrap();
            rec.submit().unwrap();
            rb.read_f32(&gpu).unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, matmul, fixed_costs);
criterion_main!(benches);
