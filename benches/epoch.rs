//! What a training epoch costs beyond its steps, on the demo's data and config.
//!
//! Writes a twin session with the `iastgcn` binary (a 60-pose calibration set, its EKF
//! calibration, three 2-minute recordings: the demo's training data), builds the
//! dataset of `assets/demo.toml`, and trains IASTGCN for a few epochs through
//! `train::run_stage`, writing the same files after each epoch as `iastgcn train`
//! (checkpoint when improved, training state, log CSV, loss PNG). Then, on the same
//! network, it times one isolated step (training forward + backward, submitted alone and
//! waited for, as in `cargo bench --bench model`) and prints:
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

use std::time::Instant;

use iastgcn::data::DataSources;
use iastgcn::gpu::{Gpu, Recorder};
use iastgcn::model::{NativeAdam, NativeStepShape, NativeTraining, Variant};
use iastgcn::progress::Silent;
use iastgcn::train::{self, fit, RunConfig, Trainer};

/// The training tests' twin session (calibration and recordings written by the CLI).
#[path = "../tests/common/mod.rs"]
mod twin;

const EPOCHS: usize = 3;

fn main() {
    let variant = std::env::args()
        .skip(1)
        .find_map(|a| Variant::parse(&a))
        .unwrap_or(Variant::Iastgcn);
    let dir = std::env::temp_dir().join(format!("iastgcn-epoch-bench-{}", std::process::id()));
    // The demo's training data: three 2-minute recordings.
    let (cal, recordings) = twin::twin_session(&dir, &["grid", "fermat", "hilbert"], 120.0);
    let backend = std::env::args()
        .skip(1)
        .find(|a| ["auto", "device", "native"].contains(&a.as_str()))
        .unwrap_or_else(|| "auto".into());
    let mut config = RunConfig::demo();
    config.model.variant = variant;
    config.train.backend = backend;
    config.train.max_epochs = EPOCHS;
    config.train.patience = EPOCHS;
    let sources = DataSources::new(recordings, cal);
    let (graph, data) = fit::build_dataset(&sources, &config, None).unwrap();
    let gpu = Gpu::new().expect("a GPU adapter (make bench installs lavapipe)");
    let init = iastgcn::model::Parameters::init(&config.model, config.train.seed);
    let mut trainer = Trainer::new(
        &gpu,
        &data,
        &graph,
        &config.model,
        &config.train,
        train::core_stage(&config),
        &init,
    )
    .unwrap();
    let out = dir.join("model.safetensors");
    let mut files = Vec::new();
    fit::run_stage(&mut trainer, "epoch bench", &mut Silent, |t, improved| {
        let began = Instant::now();
        fit::write_epoch_files(t, &config, &graph, &data, &out, improved)?;
        files.push(began.elapsed().as_secs_f64());
        Ok(())
    })
    .unwrap();

    // One step alone, as the model bench times it (mean of 5 after a warm-up).
    let isolated = match trainer.network() {
        Some(net) => {
            let step = || {
                let t0 = Instant::now();
                let mut rec = Recorder::new(&gpu);
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
            let mut native = NativeTraining::new(&config.model, &graph, shape, adam).unwrap();
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
    };
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
