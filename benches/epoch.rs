//! What a training epoch costs beyond its steps, on the demo's data and config.
//!
//! Writes a twin session with the `iastgcn` binary (a 60-pose calibration set, its EKF
//! calibration, three 2-minute recordings: the demo's training data), builds the
//! dataset of `assets/demo.toml`, and trains IASTGCN for a few epochs through
//! `train::run_stage`, writing the epoch files when `iastgcn train` does
//! (`fit::EpochFiles`: checkpoint when improved, training state, log CSV, loss PNG, after
//! the first and the last epoch and at most every 2 s between). Before the epochs, on
//! the same network, it times one isolated step (training forward + backward, submitted
//! alone and waited for, as in `cargo bench --bench model`); after them it prints:
//!
//! - epoch time against steps × isolated step time (what pipelining, input writes and
//!   Adam add or save);
//! - each epoch's validation, readbacks and files as a share of its steps (the 10 %
//!   target of docs/performance.md).
//!
//! `cargo bench --bench epoch` takes about two minutes on the 2-core lavapipe machine.
//! The variant and the backend (`[train] backend`: auto, device or native) can be
//! chosen: `cargo bench --bench epoch -- tgcn`, `cargo bench --bench epoch -- device`.
//! On the native path the isolated step is `NativeTraining::step` on the same batch size.
//!
//! `cargo bench --bench epoch -- paper` times one epoch at the paper's sizes
//! (`assets/paper.toml`: C 64, T 100, L 5, batch 64) on a dataset of the paper protocol's
//! size: three recordings of 405 000 rows (135 min at 50 Hz), every row labelled, so
//! 60 714 windows of which 42 513 train (the twin's give 60 705 and 42 510: a few rows
//! lack a tracker reading). Their features and labels are random numbers: recording
//! them takes ~5 minutes and building their features ~2 more on one core, which a GPU
//! machine lent for minutes cannot spare, and an epoch's time does not depend on the
//! values. The losses it prints mean nothing. On a CPU adapter this is ~16 minutes.

use std::time::Instant;

use iastgcn::data::{DataSources, Dataset, Prepared};
use iastgcn::gpu::{Device, Gpu, Recorder};
use iastgcn::model::{NativeAdam, NativeStepShape, NativeTraining, Variant};
use iastgcn::progress::Silent;
use iastgcn::testing::{rng, uniform};
use iastgcn::train::{self, fit, RunConfig, Trainer};

/// The training tests' twin session (calibration and recordings written by the CLI).
#[path = "../tests/common/mod.rs"]
mod twin;

const EPOCHS: usize = 3;
/// Rows of each of the paper protocol's three recordings (135 min at 50 Hz).
const PAPER_ROWS: usize = 405_000;

fn main() {
    let variant = std::env::args()
        .skip(1)
        .find_map(|a| Variant::parse(&a))
        .unwrap_or(Variant::Iastgcn);
    let dir = std::env::temp_dir().join(format!("iastgcn-epoch-bench-{}", std::process::id()));
    let paper = std::env::args().skip(1).any(|a| a == "paper");
    let backend = std::env::args()
        .skip(1)
        .find(|a| ["auto", "device", "native"].contains(&a.as_str()))
        .unwrap_or_else(|| "auto".into());
    let mut config = if paper {
        // Relative: cargo runs a bench in the package's folder.
        RunConfig::load(std::path::Path::new("assets/paper.toml")).unwrap()
    } else {
        RunConfig::demo()
    };
    let epochs = if paper { 1 } else { EPOCHS };
    config.model.variant = variant;
    config.train.backend = backend;
    config.train.max_epochs = epochs;
    config.train.patience = epochs;
    let (graph, data) = if paper {
        std::fs::create_dir_all(&dir).unwrap();
        paper_sized_dataset(&config)
    } else {
        // The demo's training data: three 2-minute recordings.
        let (cal, recordings) = twin::twin_session(&dir, &["grid", "fermat", "hilbert"], 120.0);
        let sources = DataSources::new(recordings, cal);
        fit::build_dataset(&sources, &config, None).unwrap()
    };
    let gpu =
        std::sync::Arc::new(Gpu::new().expect("a GPU adapter (make bench installs lavapipe)"));
    let device = Device::from(gpu.clone());
    let init = iastgcn::model::Parameters::init(&config.model, config.train.seed);
    let mut trainer = Trainer::new(
        &device,
        &data,
        &graph,
        &config.model,
        &config.train,
        train::core_stage(&config),
        &init,
    )
    .unwrap();
    // The isolated step first (on the initial weights; a step's time does not depend on
    // them), so that it is printed even when a paper-sized epoch outlasts a time limit.
    let isolated = isolated_step(&gpu, &trainer, &config, &graph, &data);
    let steps = trainer.steps_per_epoch();
    let on = if trainer.network().is_some() {
        "the device"
    } else {
        "the native CPU path"
    };
    eprintln!(
        "\n{variant} on {on}, {} ({} training and {} validation windows, batch {}, {steps} steps \
         per epoch); isolated step {:.1} ms",
        gpu.info().name,
        data.split_ranges()[0].len(),
        data.split_ranges()[1].len(),
        trainer.batch(),
        isolated * 1e3
    );

    let out = dir.join("model.safetensors");
    let mut files = Vec::new();
    let mut due = fit::EpochFiles::default();
    fit::run_stage(&mut trainer, "epoch bench", &mut Silent, |t, improved| {
        let began = Instant::now();
        if let Some(improved) = due.due(t, improved) {
            fit::write_epoch_files(t, &config, &graph, &data, &out, improved)?;
        }
        files.push(began.elapsed().as_secs_f64());
        Ok(())
    })
    .unwrap();
    eprintln!(
        "{:>5} {:>9} {:>13} {:>11} {:>10} {:>9} {:>9} {:>10}",
        "epoch", "steps s", "steps/isol.", "validation", "readbacks", "files", "total", "overhead"
    );
    for (r, f) in trainer.progress.history.iter().zip(&files) {
        let beyond = r.validation_seconds + r.readback_seconds + f;
        eprintln!(
            "{:>5} {:>9.2} {:>12.2}× {:>10.2}s {:>9.3}s {:>8.3}s {:>8.2}s {:>9.1}%",
            r.epoch,
            r.seconds,
            r.seconds / (steps as f64 * isolated),
            r.validation_seconds,
            r.readback_seconds,
            f,
            r.seconds + beyond,
            100.0 * beyond / r.seconds
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A dataset of the paper protocol's size on the default sensor graph, windowed and split
/// as `config` says, from random features and labels (every row labelled).
fn paper_sized_dataset(config: &RunConfig) -> (iastgcn::graph::Graph, Dataset) {
    let graph = iastgcn::graph::Graph::default_asset();
    let mut g = rng(11);
    let prepared: Vec<(String, Prepared)> = ["grid", "fermat", "hilbert"]
        .iter()
        .map(|name| {
            let features = (0..graph.nodes.len())
                .map(|_| std::array::from_fn(|_| uniform(&mut g, PAPER_ROWS, -1.0, 1.0)))
                .collect();
            let labels = uniform(&mut g, PAPER_ROWS * 6, -50.0, 50.0)
                .chunks(6)
                .map(|c| Some(std::array::from_fn(|i| c[i])))
                .collect();
            let axes = vec![Some([0.0, 0.0, 1.0]); PAPER_ROWS];
            let p = Prepared {
                features,
                labels,
                axes,
            };
            (name.to_string(), p)
        })
        .collect();
    let data = Dataset::from_prepared(
        &prepared,
        &graph.nodes,
        &fit::window_config(config),
        fit::split_mode(config),
        None,
    )
    .unwrap();
    eprintln!("{}", data.summary());
    (graph, data)
}

/// One training step alone, as the model bench times it (mean of 5 after a warm-up):
/// forward + backward on the device, or `NativeTraining::step` on the native path.
fn isolated_step(
    gpu: &Gpu,
    trainer: &Trainer,
    config: &RunConfig,
    graph: &iastgcn::graph::Graph,
    data: &Dataset,
) -> f64 {
    match trainer.network() {
        Some(net) => {
            let step = || {
                let t0 = Instant::now();
                let mut rec = Recorder::new(gpu);
                net.record_train_forward(&mut rec).unwrap();
                net.record_backward(&mut rec).unwrap();
                rec.submit().unwrap();
                gpu.wait().unwrap();
                t0.elapsed().as_secs_f64()
            };
            step();
            (0..5).map(|_| step()).sum::<f64>() / 5.0
        }
        None => {
            let c = &config.train;
            let shape = NativeStepShape {
                batch: trainer.batch(),
                group: 1,
                seed: 1,
                penalty: c.attitude_penalty,
                threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            };
            let adam = NativeAdam {
                beta1: c.beta1,
                beta2: c.beta2,
                eps: c.adam_eps,
                weight_decay: c.weight_decay,
            };
            let mut native = NativeTraining::new(&config.model, graph, shape, adam).unwrap();
            native.load_parameters(&trainer.best).unwrap();
            let positions: Vec<usize> = (0..trainer.batch()).collect();
            let (x, y) = data.gather(&positions);
            let mut step = |s: u64| {
                let t0 = Instant::now();
                native.step(&x, &y, s, 1e-4).unwrap();
                t0.elapsed().as_secs_f64()
            };
            step(0);
            (1..6).map(&mut step).sum::<f64>() / 5.0
        }
    }
}
