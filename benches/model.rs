//! Whole-network throughput: inference forward at B = 1 (latency; on the device and on
//! the native CPU path `model::NativeForward`, on one thread and
//! split over every core as `Predictor::set_threads` allows) and B = 64, and one
//! training step at B = 64 (on the device and on the native
//! CPU path `model::NativeTraining` with every core), for the paper shape (C 64, T 100, L 5) and a small shape
//! (C 16, T 48, L 3), the native training step at the demo's shape (C 16, T 48, L 2), then the same three for each baseline (tgcn, eat-gcn, mlp,
//! bkls-ann, ann-bfpa, erc) at both windows, against the project's best matmul measured in the
//! same run.
//!
//! Criterion's "thrpt" column is in windows/s (elements = batch) for the model groups and
//! in FLOP/s for the baseline. Each benchmark also prints to stderr its FLOPs
//! (`model::flops`: GEMM-like contractions only), the achieved GFLOP/s and the ratio to
//! the matmul baseline; each model group first prints its per-family FLOP breakdown, and
//! a summary table ends the run.
//!
//! `IASTGCN_BENCH_GROUPS=prefix,prefix,…` runs only the groups whose names start with one
//! of the prefixes (criterion's own filter would still build every group's networks).
//! With `IASTGCN_BENCH_CSV=path` set, the summary is also written to that file as CSV
//! (`benchmark,mean_s,windows,flops`); `make bench-compare` reads it
//! (benches/pytorch/compare.py).
//!
//! A training step is the training forward + backward (loss and every gradient),
//! recorded into one command buffer, submitted and waited for (natively:
//! `NativeTraining::gradients`). No optimiser runs, so the step updates no parameter
//! (and the device's dropout step is set once, outside the loop). Networks, parameters (`Parameters::init(config, 1)`) and random inputs are
//! built once, outside the timing. `cargo bench --bench model` takes about 6 minutes on
//! the 2-core lavapipe machine.

use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::network;
use criterion::measurement::WallTime;
use criterion::{
    criterion_group, criterion_main, BenchmarkGroup, BenchmarkId, Criterion, SamplingMode,
    Throughput,
};
use iastgcn::gpu::{Gpu, Recorder};
use iastgcn::model::{
    flops, Backend, Checkpoint, ModelConfig, NativeAdam, NativeForward, NativeStepShape,
    NativeTraining, Network, Normalization, Parameters, Pass, Predictor, Variant,
};
use iastgcn::testing::{rng, to_f32, uniform};

mod common;

/// One finished benchmark, for the ratios and the closing table.
struct Row {
    name: String,
    mean: Duration,
    /// None for the matmul baseline (its throughput is reported in FLOP/s).
    windows: Option<usize>,
    flops: f64,
}

static ROWS: Mutex<Vec<Row>> = Mutex::new(Vec::new());
/// GFLOP/s of the matmul baseline, once measured.
static BASELINE: Mutex<Option<f64>> = Mutex::new(None);

const BATCH: usize = 64;

fn gpu() -> Gpu {
    Gpu::new().expect("a GPU adapter (make bench installs lavapipe)")
}

fn ratio_text(gflops: f64) -> String {
    match *BASELINE.lock().unwrap() {
        Some(base) => format!("{:.2}× the matmul baseline", gflops / base),
        None => "no matmul baseline in this run".into(),
    }
}

/// Benchmarks `run` (one iteration: submit + wait) and prints its GFLOP/s.
///
/// The first call of `run`, untimed, JIT-compiles every pipeline. Criterion's own
/// warm-up is a single iteration (`warm_up_time` 1 ns), which the mean printed here
/// leaves out. A fast benchmark is timed once more to size a measurement of at least
/// 3 s; one whose first call took over 10 s (the paper-shape training step) gets a
/// 1 ms target, so criterion takes the minimum, 10 samples of one iteration each (and
/// warns that they take longer than the target), keeping the whole run under 10 minutes.
fn bench(
    group: &mut BenchmarkGroup<WallTime>,
    group_name: &str,
    name: &str,
    windows: Option<usize>,
    flops: f64,
    mut run: impl FnMut(),
) {
    let t0 = Instant::now();
    run();
    let first = t0.elapsed();
    if first > Duration::from_secs(10) {
        group.measurement_time(Duration::from_millis(1));
    } else {
        let t0 = Instant::now();
        run();
        let once = t0.elapsed();
        group.measurement_time(Duration::from_secs(3).max(once.mul_f64(8.0)));
    }
    group.throughput(Throughput::Elements(
        windows.map_or(flops as u64, |w| w as u64),
    ));
    let mut calls: Vec<(Duration, u64)> = Vec::new();
    group.bench_function(BenchmarkId::from_parameter(name), |b| {
        b.iter_custom(|iters| {
            let t0 = Instant::now();
            for _ in 0..iters {
                run();
            }
            let elapsed = t0.elapsed();
            calls.push((elapsed, iters));
            elapsed
        })
    });
    // The first call is criterion's warm-up; a filtered-out benchmark made no calls.
    let (total, iters) = calls
        .iter()
        .skip(1)
        .fold((Duration::ZERO, 0), |(t, n), &(d, i)| (t + d, n + i));
    if iters == 0 {
        return;
    }
    let mean = total / iters as u32;
    let gflops = flops / mean.as_secs_f64() / 1e9;
    let full = format!("{group_name}/{name}");
    let per_second = windows.map_or(String::new(), |w| {
        format!(" {:.1} windows/s,", w as f64 / mean.as_secs_f64())
    });
    eprintln!(
        "{full}: mean {mean:.3?} over {iters} iterations,{per_second} {:.3} GFLOP \
         -> {gflops:.2} GFLOP/s, {}",
        flops / 1e9,
        ratio_text(gflops),
    );
    ROWS.lock().unwrap().push(Row {
        name: full,
        mean,
        windows,
        flops,
    });
}

fn new_group<'c>(c: &'c mut Criterion, name: &str) -> BenchmarkGroup<'c, WallTime> {
    let mut group = c.benchmark_group(name);
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_nanos(1));
    group
}

/// The baseline product (`common::baseline`), timed like the models.
fn matmul_baseline(c: &mut Criterion) {
    if !selected("baseline") {
        return;
    }
    let gpu = gpu();
    let (mm, d) = common::baseline(&gpu);
    let mut group = new_group(c, "baseline");
    bench(
        &mut group,
        "baseline",
        "matmul conv 896x[64,192]x[192,100]",
        None,
        mm.flops(),
        || {
            let mut rec = Recorder::new(&gpu);
            rec.dispatch(&d);
            rec.submit().unwrap();
            gpu.wait().unwrap();
        },
    );
    group.finish();
    let rows = ROWS.lock().unwrap();
    if let Some(row) = rows.iter().find(|r| r.name.starts_with("baseline/")) {
        *BASELINE.lock().unwrap() = Some(row.flops / row.mean.as_secs_f64() / 1e9);
    }
}

fn forward(gpu: &Gpu, net: &Network) {
    let mut rec = Recorder::new(gpu);
    net.record_forward(&mut rec).unwrap();
    rec.submit().unwrap();
    gpu.wait().unwrap();
}

fn training_step(gpu: &Gpu, net: &Network) {
    let mut rec = Recorder::new(gpu);
    net.record_train_forward(&mut rec).unwrap();
    net.record_backward(&mut rec).unwrap();
    rec.submit().unwrap();
    gpu.wait().unwrap();
}

fn print_breakdown(name: &str, config: &ModelConfig, batch: usize) {
    let fwd = flops::breakdown(config, batch);
    let train = flops::training_breakdown(config, batch);
    let (total_f, total_t) = (
        flops::forward_flops(config, batch),
        flops::training_flops(config, batch),
    );
    eprintln!("\n{name} (B = {batch}): FLOPs per contraction family");
    eprintln!(
        "  {:<36} {:>12} {:>6} {:>12} {:>6}",
        "family", "forward", "%", "train step", "%"
    );
    for ((family, f), (_, t)) in fwd.iter().zip(&train) {
        if !flops::has_family(config.variant, family) {
            continue;
        }
        eprintln!(
            "  {family:<36} {:>12.4e} {:>6.2} {:>12.4e} {:>6.2}",
            f,
            100.0 * f / total_f,
            t,
            100.0 * t / total_t
        );
    }
    eprintln!(
        "  {:<36} {:>12.4e} {:>6} {:>12.4e}\n",
        "total", total_f, "", total_t
    );
}

/// Whether `IASTGCN_BENCH_GROUPS` (when set) selects the group `name`.
fn selected(name: &str) -> bool {
    std::env::var("IASTGCN_BENCH_GROUPS").map_or(true, |groups| {
        groups.split(',').any(|g| name.starts_with(g))
    })
}

fn model_group(c: &mut Criterion, name: &str, config: &ModelConfig) {
    if !selected(name) {
        return;
    }
    let gpu = gpu();
    print_breakdown(name, config, BATCH);
    let one = network(&gpu, config, 1);
    let big = network(&gpu, config, BATCH);
    let mut group = new_group(c, name);
    bench(
        &mut group,
        name,
        "forward B=1",
        Some(1),
        flops::forward_flops(config, 1),
        || forward(&gpu, &one),
    );
    let graph = iastgcn::graph::Graph::default_asset();
    let len = config.nodes * config.features * config.window;
    let x = to_f32(&uniform(&mut rng(2), len, -1.0, 1.0));
    let mut y = vec![0f32; config.outputs];
    // One thread (the default), then every core (`Predictor::set_threads`).
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for (label, threads) in [
        ("native forward B=1", 1),
        ("native forward B=1 all cores", cores),
    ] {
        let mut native = NativeForward::new(config, &graph, &Parameters::init(config, 1)).unwrap();
        native.set_threads(threads);
        bench(
            &mut group,
            name,
            label,
            Some(1),
            flops::forward_flops(config, 1),
            || native.forward(&x, &mut y).unwrap(),
        );
    }
    bench(
        &mut group,
        name,
        "forward B=64",
        Some(BATCH),
        flops::forward_flops(config, BATCH),
        || forward(&gpu, &big),
    );
    bench(
        &mut group,
        name,
        "train step B=64",
        Some(BATCH),
        flops::training_flops(config, BATCH),
        || training_step(&gpu, &big),
    );
    native_train_step(&mut group, name, config);
    group.finish();
}

/// The native training step of `config` at B = 64 on every core, in `group`.
fn native_train_step(group: &mut BenchmarkGroup<WallTime>, name: &str, config: &ModelConfig) {
    let graph = iastgcn::graph::Graph::default_asset();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let shape = NativeStepShape {
        batch: BATCH,
        group: 1,
        seed: 1,
        penalty: 1.0,
        threads: cores,
    };
    let adam = NativeAdam {
        beta1: 0.9,
        beta2: 0.999,
        eps: 1e-8,
        weight_decay: 1e-4,
    };
    let mut native = NativeTraining::new(config, &graph, shape, adam).unwrap();
    native
        .load_parameters(&Parameters::init(config, 1))
        .unwrap();
    let len = config.nodes * config.features * config.window;
    let x = to_f32(&uniform(&mut rng(3), BATCH * len, -1.0, 1.0));
    let y = to_f32(&uniform(&mut rng(4), BATCH * config.outputs, -1.0, 1.0));
    let mut step = 0u32;
    bench(
        group,
        name,
        "native train step B=64",
        Some(BATCH),
        flops::training_flops(config, BATCH),
        // Forward, loss and backward, no update: what the device's step and
        // PyTorch's (make bench-compare) time.
        || {
            native.gradients(&x, &y, step).unwrap();
            step += 1;
        },
    );
}

fn small_shape(c: &mut Criterion) {
    model_group(c, "small C16 T48 L3", &common::small_config());
}

/// The demo's network (`assets/demo.toml`: L = 2), its native training step only (the
/// device's step at this shape is in `cargo bench --bench epoch`).
fn demo_shape(c: &mut Criterion) {
    let name = "demo C16 T48 L2";
    if !selected(name) {
        return;
    }
    let config = ModelConfig {
        blocks: 2,
        ..common::small_config()
    };
    print_breakdown(name, &config, BATCH);
    let mut group = new_group(c, name);
    native_train_step(&mut group, name, &config);
    group.finish();
}

fn paper_shape(c: &mut Criterion) {
    model_group(c, "paper C64 T100 L5", &ModelConfig::default());
}

/// The baselines (docs/model.md "Baselines") at the demo's and the paper's window, H = 64
/// in both. The recurrent time loops run T steps per pass (the group name says how many: the
/// cost of one step is the time over T); the dense ones read only the last step.
fn baselines(c: &mut Criterion) {
    for variant in Variant::SPATIO_TEMPORAL.into_iter().chain(Variant::DENSE) {
        for (shape, base) in [
            ("small", common::small_config()),
            ("paper", ModelConfig::default()),
        ] {
            let config = ModelConfig { variant, ..base };
            let name = format!("{shape} {variant} (T {})", config.window);
            model_group(c, &name, &config);
        }
    }
}

/// The controller's streaming case: one new frame per tick through `Predictor::push`
/// (the ring keeps the older frames; each tick standardises the window and runs one
/// forward), at the paper's C 64 and L 5 for T = 25 … 200, natively and on the device.
fn streaming(c: &mut Criterion) {
    let name = "streaming C64 L5";
    if !selected(name) {
        return;
    }
    let gpu = std::sync::Arc::new(gpu());
    let mut group = new_group(c, name);
    for window in [25, 50, 100, 200] {
        let config = ModelConfig {
            window,
            ..ModelConfig::default()
        };
        let checkpoint = Checkpoint {
            parameters: Parameters::init(&config, 1),
            graph: iastgcn::graph::Graph::default_asset(),
            normalization: Normalization::identity(&config),
            config: config.clone(),
        };
        let frame = to_f32(&uniform(
            &mut rng(3),
            config.nodes * config.features,
            -1.0,
            1.0,
        ));
        for (label, mut predictor) in [
            ("native", Predictor::native(&checkpoint).unwrap()),
            (
                "device",
                Predictor::with_backend(gpu.clone(), &checkpoint, 1, Backend::Device).unwrap(),
            ),
        ] {
            for _ in 0..window {
                predictor.push_step(&frame).unwrap();
            }
            bench(
                &mut group,
                name,
                &format!("{label} push T={window}"),
                Some(1),
                flops::forward_flops(&config, 1),
                || {
                    predictor.push(&frame).unwrap();
                },
            );
        }
    }
    group.finish();
}

/// Device memory per window and the largest batch the adapter's limits allow
/// (`model::memory::footprint`), for the training and the inference network at both
/// shapes. Printed, not timed.
fn memory(_: &mut Criterion) {
    if !selected("memory") {
        return;
    }
    let gpu = gpu();
    let graph = iastgcn::graph::Graph::default_asset();
    let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
    eprintln!(
        "\n{:<20} {:<10} {:>10} {:>14} {:>12} {:>10}  largest buffer at B = {BATCH}",
        "shape", "network", "MiB at B=1", "MiB per window", "MiB at B=64", "max batch"
    );
    for (shape, config) in [
        ("small C16 T48 L3", common::small_config()),
        ("paper C64 T100 L5", ModelConfig::default()),
    ] {
        for (label, pass) in [("training", Pass::Train), ("inference", Pass::Inference)] {
            let f = iastgcn::model::memory::footprint(&gpu, &config, &graph, pass, BATCH).unwrap();
            eprintln!(
                "{shape:<20} {label:<10} {:>10.2} {:>14.3} {:>12.1} {:>10}  {} ({:.1} MiB; limit {:.0} MiB)",
                mib(f.bytes_at_one),
                mib(f.per_window_bytes()),
                mib(f.bytes),
                f.max_batch,
                f.largest.0,
                mib(f.largest.1),
                mib(f.limit_bytes),
            );
        }
    }
}

fn summary(_: &mut Criterion) {
    let rows = ROWS.lock().unwrap();
    if rows.is_empty() {
        return;
    }
    let base = *BASELINE.lock().unwrap();
    eprintln!(
        "\n{:<52} {:>12} {:>11} {:>9} {:>8}",
        "benchmark", "mean", "windows/s", "GFLOP/s", "ratio"
    );
    for r in rows.iter() {
        let secs = r.mean.as_secs_f64();
        let gflops = r.flops / secs / 1e9;
        let ratio = base.map_or("-".to_string(), |b| format!("{:.2}", gflops / b));
        let windows = r
            .windows
            .map_or("-".to_string(), |w| format!("{:.1}", w as f64 / secs));
        eprintln!(
            "{:<52} {:>12.3?} {:>11} {:>9.2} {:>8}",
            r.name, r.mean, windows, gflops, ratio
        );
    }
    if let Some(path) = std::env::var_os("IASTGCN_BENCH_CSV") {
        write_csv(std::path::Path::new(&path), &rows).expect("writing IASTGCN_BENCH_CSV");
        eprintln!("wrote {}", path.to_string_lossy());
    }
}

/// The summary rows as CSV, written atomically.
fn write_csv(path: &std::path::Path, rows: &[Row]) -> std::io::Result<()> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(["benchmark", "mean_s", "windows", "flops"])?;
    for r in rows {
        w.write_record([
            r.name.clone(),
            format!("{:e}", r.mean.as_secs_f64()),
            r.windows.map_or(String::new(), |w| w.to_string()),
            format!("{:e}", r.flops),
        ])?;
    }
    let bytes = w.into_inner().map_err(|e| e.into_error())?;
    iastgcn::atomic::write(path, &bytes)
}

criterion_group! {
    name = benches;
    // No plots: the plotters backend panics for want of a font on this machine.
    config = Criterion::default().without_plots();
    targets = matmul_baseline, memory, small_shape, demo_shape, paper_shape, streaming, baselines, summary
}
criterion_main!(benches);
