//! Per-kernel profile of the network (`Network::profile`): every step of a pass, grouped
//! across blocks, with its share of the pass, its GFLOP/s and its ratio to the project's
//! best matmul measured in the same run. This is the "every heavy kernel at ≥ 70 % of
//! the best matmul" check of the GPU issue.
//!
//! `cargo bench --bench kernels` profiles the training step (forward + loss + backward)
//! and the inference forward at B = 64 for the paper shape (C 64, T 100, L 5) and the
//! small shape (C 16, T 48, L 3). Arguments pick a subset: `-- paper`, `-- small`,
//! `-- train`, `-- infer`; `-- alone` times each step submitted alone; `-- all` lists
//! every row (else those under 0.5 % of the pass are summed in one line).
//!
//! Where the device has timestamp queries (lavapipe and the usual Vulkan, DX12 and Metal
//! drivers), the whole pass runs in one submit as training runs it and each launch is
//! timed by timestamps at its start and end; the report adds the pass's wall time in
//! one untimed submit, the span from the first launch to the last, and the time between
//! launches (barriers, copies). Otherwise (or with `-- alone`) each step is submitted
//! alone and waited for, so every row carries a submit's cost (~0.25 ms on an H200,
//! ~0.5 ms on lavapipe). Best of two repeats either way; a heavy step takes at least 2 %
//! of its pass. The baseline is measured just before and just after each pass and their
//! mean is the reference. About 2 minutes for everything on the 2-core lavapipe machine.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use common::network;
use iastgcn::gpu::{Dispatch, Gpu, Recorder};
use iastgcn::model::{ModelConfig, Network, Pass, Profile, Timing};
use iastgcn::ops::matmul::Matmul;

mod common;

const BATCH: usize = 64;
/// A step taking at least this share of its pass is "heavy".
const HEAVY: f64 = 0.02;

/// GFLOP/s of the baseline product (`common::baseline`), best of 8 after a warm-up.
fn baseline(gpu: &Gpu, (mm, d): &(Matmul, Dispatch)) -> f64 {
    let mut best = Duration::MAX;
    for i in 0..9 {
        let mut rec = Recorder::new(gpu);
        rec.dispatch(d);
        let t0 = Instant::now();
        rec.submit().unwrap();
        gpu.wait().unwrap();
        if i > 0 {
            best = best.min(t0.elapsed());
        }
    }
    mm.flops() / best.as_secs_f64() / 1e9
}

/// `blocks.3.tcn.G_f` → `blocks.*.tcn.G_f`, so one row sums a role over the blocks.
fn role(target: &str) -> String {
    let mut parts: Vec<&str> = target.split('.').collect();
    if parts.len() > 2 && parts[0].ends_with("blocks") && parts[1].parse::<usize>().is_ok() {
        parts[1] = "*";
    }
    parts.join(".")
}

#[derive(Default)]
struct Row {
    steps: usize,
    time: Duration,
    flops: f64,
}

/// One untimed submit of a pass, best of 3 by wall time: the host's time to record its
/// launches into a command encoder, the submit call itself (where wgpu validates and
/// tracks every command), and the wall time from the submit until the device is done.
#[derive(Clone, Copy)]
struct Wall {
    record: Duration,
    submit: Duration,
    wall: Duration,
}

fn wall(gpu: &Gpu, net: &Network, pass: Pass) -> Wall {
    (0..3)
        .map(|_| {
            let t0 = Instant::now();
            let mut rec = Recorder::new(gpu);
            match pass {
                Pass::Train => {
                    net.record_train_forward(&mut rec).unwrap();
                    net.record_backward(&mut rec).unwrap();
                }
                Pass::Inference => net.record_forward(&mut rec).unwrap(),
            }
            let record = t0.elapsed();
            let t1 = Instant::now();
            rec.submit().unwrap();
            let submit = t1.elapsed();
            gpu.wait().unwrap();
            Wall {
                record,
                submit,
                wall: t1.elapsed(),
            }
        })
        .min_by_key(|w| w.wall)
        .unwrap()
}

fn report(title: &str, profile: &Profile, host: Wall, base: f64, all_rows: bool) {
    let wall = host.wall;
    let times = &profile.steps;
    let copies = times.iter().filter(|t| t.kernel == "copy").count();
    let total = profile.launches();
    let mut rows: BTreeMap<(String, String), Row> = BTreeMap::new();
    for t in times.iter().filter(|t| t.kernel != "copy") {
        let kernel = t
            .kernel
            .rsplit("::")
            .next()
            .unwrap_or(&t.kernel)
            .to_string();
        let row = rows.entry((kernel, role(&t.target))).or_default();
        row.steps += 1;
        row.time += t.time;
        row.flops += t.flops;
    }
    let mut rows: Vec<_> = rows.into_iter().collect();
    rows.sort_by_key(|r| std::cmp::Reverse(r.1.time));
    let gemm_time: Duration = times.iter().filter(|t| t.flops > 0.0).map(|t| t.time).sum();
    let flops: f64 = times.iter().map(|t| t.flops).sum();
    let kernels = times.len() - copies;
    let launched: usize = times.iter().map(|t| t.launches).sum();
    match profile.timing {
        Timing::Timestamps => eprintln!(
            "\n{title}: {kernels} kernels ({launched} launches) and {copies} copies in one \
             submit: {wall:.3?} \
             wall, {:.3?} from the first launch's start to the last one's end, {total:.3?} \
             in launches, {:.3?} ({:.1}%) between them (barriers, the copies)",
            profile.span,
            profile.between_launches(),
            100.0 * profile.between_launches().as_secs_f64() / profile.span.as_secs_f64(),
        ),
        Timing::Alone => eprintln!(
            "\n{title}: {kernels} kernels ({launched} launches) and {copies} copies, \
             {total:.3?} when each is \
             timed alone ({wall:.3?} wall in one submit)",
        ),
    }
    eprintln!(
        "  on the host: {:.3?} to record the pass, {:.3?} in the submit call (within the wall)",
        host.record, host.submit
    );
    eprintln!(
        "  contractions {:.1}% of the launches' time at {:.2} GFLOP/s overall \
         ({:.2}× the baseline)",
        100.0 * gemm_time.as_secs_f64() / total.as_secs_f64(),
        flops / gemm_time.as_secs_f64() / 1e9,
        flops / gemm_time.as_secs_f64() / 1e9 / base,
    );
    eprintln!(
        "  {:<26} {:<34} {:>5} {:>10} {:>6} {:>8} {:>6}",
        "kernel", "writes", "steps", "time", "%", "GFLOP/s", "ratio"
    );
    let mut shown = Duration::ZERO;
    for ((kernel, target), r) in &rows {
        let share = r.time.as_secs_f64() / total.as_secs_f64();
        if share < 0.005 && !all_rows {
            continue;
        }
        shown += r.time;
        let (gflops, ratio) = if r.flops > 0.0 {
            let g = r.flops / r.time.as_secs_f64() / 1e9;
            (format!("{g:.2}"), format!("{:.2}", g / base))
        } else {
            ("-".into(), "-".into())
        };
        let mark = if share >= HEAVY && r.flops > 0.0 && gflops_ratio(r, base) < 0.7 {
            "  < 70%"
        } else {
            ""
        };
        eprintln!(
            "  {kernel:<26} {target:<34} {:>5} {:>10.3?} {:>6.2} {gflops:>8} {ratio:>6}{mark}",
            r.steps,
            r.time,
            100.0 * share,
        );
    }
    if !all_rows {
        eprintln!(
            "  (rows under 0.5% left out: {:.2?} in all; `-- all` lists them)",
            total.saturating_sub(shown)
        );
    }
}

fn gflops_ratio(r: &Row, base: f64) -> f64 {
    r.flops / r.time.as_secs_f64() / 1e9 / base
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let wants = |what: &str, all: &[&str]| {
        let named = args.iter().any(|a| all.contains(&a.as_str()));
        !named || args.iter().any(|a| a == what)
    };
    let gpu = Gpu::new().expect("a GPU adapter (make bench installs lavapipe)");
    let all_rows = std::env::args().any(|a| a == "all");
    let timing = if std::env::args().any(|a| a == "alone") {
        Timing::Alone
    } else {
        Timing::best(&gpu)
    };
    eprintln!(
        "timing: {}",
        match timing {
            Timing::Timestamps => "the whole pass in one submit, each launch between timestamps",
            Timing::Alone => "each step submitted alone and waited for",
        }
    );
    let product = common::baseline(&gpu);
    let shapes = [
        ("paper C64 T100 L5", "paper", ModelConfig::default()),
        ("small C16 T48 L3", "small", common::small_config()),
    ];
    for (name, key, config) in shapes {
        if !wants(key, &["paper", "small"]) {
            continue;
        }
        let net = network(&gpu, &config, BATCH);
        for (pass, pass_key, label) in [
            (Pass::Train, "train", "training step"),
            (Pass::Inference, "infer", "inference forward"),
        ] {
            if !wants(pass_key, &["train", "infer"]) {
                continue;
            }
            // Untimed once: the first dispatch of each pipeline JIT-compiles it.
            net.profile(&gpu, pass, timing, 1).unwrap();
            // The baseline just before and just after the pass, their mean counting: on a
            // shared machine the speed drifts within a run (by up to 1.7x within a minute
            // on 2026-11-22), and a baseline taken minutes away drifts the ratios with it.
            let before = baseline(&gpu, &product);
            let profile = net.profile(&gpu, pass, timing, 2).unwrap();
            let wall = wall(&gpu, &net, pass);
            let after = baseline(&gpu, &product);
            let base = 0.5 * (before + after);
            eprintln!(
                "\nbaseline matmul 896x[64,192]x[192,100] around this pass: \
                 {before:.2} / {after:.2} GFLOP/s"
            );
            report(
                &format!("{name} {label} B={BATCH}"),
                &profile,
                wall,
                base,
                all_rows,
            );
        }
    }
}
