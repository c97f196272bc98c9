//! Embedding the forward pass in controller code.
//!
//! ```text
//! cargo run --release --example predict -- [model.safetensors]
//! ```
//!
//! Loads a checkpoint (or, without an argument, initialises a small untrained model so
//! the example runs anywhere), creates a predictor on the default adapter (override with
//! IASTGCN_ADAPTER), and predicts the pose residual three ways: one window, a batch of
//! windows, and step by step through the ring buffer, as a controller would each tick.

use std::sync::Arc;

use iastgcn::gpu::Gpu;
use iastgcn::graph::Graph;
use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters, Predictor};

fn main() -> anyhow::Result<()> {
    let checkpoint = match std::env::args().nth(1) {
        Some(path) => Checkpoint::load(path.as_ref())?,
        None => {
            let config = ModelConfig {
                window: 48,
                channels: 16,
                blocks: 3,
                ..ModelConfig::default()
            };
            Checkpoint {
                parameters: Parameters::init(&config, 1),
                normalization: Normalization::identity(&config),
                graph: Graph::default_asset(),
                config,
            }
        }
    };
    let gpu = Arc::new(Gpu::new()?);
    let c = checkpoint.config.clone();
    println!(
        "{} (C={}, T={}, L={}) on {}",
        c.variant,
        c.channels,
        c.window,
        c.blocks,
        gpu.info().name
    );
    // Up to 8 windows per submit; builds every buffer and pipeline now (the warm-up).
    // On a CPU adapter (lavapipe) it builds the native CPU forward instead.
    let mut predictor = Predictor::new(gpu, &checkpoint, 8)?;
    println!("runs on: {:?}", predictor.backend());

    // Synthetic raw features [N, F, T]: a slow sine per node and feature.
    let (n, f, t) = (c.nodes, c.features, c.window);
    let feature = |node: usize, k: usize, step: usize| -> f32 {
        ((step as f32 * 0.05) + node as f32 * 0.3 + k as f32).sin()
    };
    let window_at = |end: usize| -> Vec<f32> {
        let mut w = Vec::with_capacity(n * f * t);
        for node in 0..n {
            for k in 0..f {
                w.extend((0..t).map(|s| feature(node, k, end + 1 + s - t)));
            }
        }
        w
    };

    let one = predictor.predict(&window_at(t - 1))?;
    println!("one window:  {}", show(&one));

    let batch: Vec<f32> = (0..20).flat_map(|i| window_at(t - 1 + i)).collect();
    let mut residuals = Vec::new();
    predictor.predict_batch(&batch, iastgcn::model::Features::Raw, &mut residuals)?;
    println!(
        "batch of {}: first {}",
        residuals.len(),
        show(&residuals[0])
    );

    // A controller tick: push the newest step [N, F]; a residual comes once T steps are in.
    let mut step = vec![0.0f32; n * f];
    for s in 0..t + 2 {
        for (row, v) in step.iter_mut().enumerate() {
            *v = feature(row / f, row % f, s);
        }
        if let Some(r) = predictor.push(&step)? {
            println!("tick {s:3}:    {}", show(&r));
        }
    }
    Ok(())
}

fn show(r: &[f64; 6]) -> String {
    format!(
        "dx {:8.2} dy {:8.2} dz {:8.2} µm   rx {:8.2} ry {:8.2} rz {:8.2} mdeg",
        r[0], r[1], r[2], r[3], r[4], r[5]
    )
}
