//! The native path's matrix products at the shapes of the paper-shape forward (C 64,
//! T 100, L 5, one window; docs/performance.md "The native CPU forward"), by the two
//! engines of `model/cpu/product.rs`: the `gemm` crate (training's) and the in-place
//! kernel that allocates nothing (the predictor's). Each row is one product shape with
//! its operand layout, `[m, k, n]`, A and B row-major (`r`) or seen transposed (`t`);
//! criterion's thrpt column is in FLOP/s. `cargo bench --bench products`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use iastgcn::model::product_for_bench;

/// (m, k, n, A transposed, B transposed), the forward's products weighted by their
/// share of its multiply-adds, the small ones it calls most often, a demo-shape
/// product, and ConvLSTM's two per step at the paper's shape.
const SHAPES: &[(usize, usize, usize, bool, bool)] = &[
    (128, 192, 1400, false, false),
    (896, 100, 100, false, false),
    (64, 64, 100, false, false),
    (64, 64, 100, true, false),
    (100, 100, 100, false, false),
    (14, 14, 6400, false, false),
    (14, 100, 14, false, true),
    (1, 64, 100, false, false),
    (896, 100, 1, false, false),
    (64, 3, 100, false, false),
    (16, 16, 48, false, false),
    (256, 576, 42, false, false),
    (256, 9, 42, false, false),
];

fn products(c: &mut Criterion) {
    let mut group = c.benchmark_group("products");
    for &(m, k, n, at, bt) in SHAPES {
        let a: Vec<f32> = (0..m * k).map(|i| (i % 97) as f32 * 0.01 - 0.4).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i % 89) as f32 * 0.01 - 0.4).collect();
        let mut out = vec![0f32; m * n];
        let (ars, acs) = if at { (1, m) } else { (k, 1) };
        let (brs, bcs) = if bt { (1, k) } else { (n, 1) };
        group.throughput(Throughput::Elements((2 * m * k * n) as u64));
        let layout = format!(
            "[{m},{k},{n}] {}{}",
            if at { 't' } else { 'r' },
            if bt { 't' } else { 'r' }
        );
        for (engine, in_place) in [("gemm crate", false), ("in place", true)] {
            group.bench_function(BenchmarkId::new(engine, &layout), |bench| {
                bench.iter(|| {
                    product_for_bench(
                        in_place,
                        (m, k, n),
                        (&a, ars, acs),
                        (&b, brs, bcs),
                        &mut out,
                        n,
                    )
                })
            });
        }
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .without_plots()
        .warm_up_time(std::time::Duration::from_millis(300))
        .measurement_time(std::time::Duration::from_secs(1));
    targets = products
}
criterion_main!(benches);
