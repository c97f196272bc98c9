//! `iastgcn init` (a freshly initialised checkpoint) and `iastgcn forward` (the
//! interop check: run a checkpoint on a tensor `x` from a safetensors file).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::Args;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use iastgcn::gpu::{Gpu, Readback, Recorder};
use iastgcn::graph::Graph;
use iastgcn::model::checkpoint::f32_values;
use iastgcn::model::{Checkpoint, ModelConfig, Network, Normalization, Parameters, Variant};

#[derive(Args)]
pub struct InitArgs {
    /// Run config (TOML); its `[model]` table holds the fields of docs/model.md's notation
    /// table: variant, nodes, features, window, channels, blocks, kernel, scale, …; the
    /// paper shape when absent.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the config's variant: iastgcn, iastgcn-a, iastgcn-t, iastgcn-s.
    #[arg(long)]
    pub variant: Option<String>,
    /// Sensor graph (TOML); the embedded 14-node graph when absent.
    #[arg(long)]
    pub graph: Option<PathBuf>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Args)]
pub struct ForwardArgs {
    /// Checkpoint (safetensors).
    #[arg(long)]
    pub model: PathBuf,
    /// safetensors file with the tensor `x` [B, N, F, T] (f32, standardised features).
    #[arg(long)]
    pub input: PathBuf,
    /// Output safetensors file with the tensor `y` [B, 6] (standardised label space).
    #[arg(long)]
    pub out: PathBuf,
    /// Windows per submit.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
}

/// The `[model]` table of a run config TOML (assets/demo.toml, assets/paper.toml);
/// errors name the file and field.
pub fn read_config(path: &Path) -> anyhow::Result<ModelConfig> {
    Ok(iastgcn::train::RunConfig::load(path)?.model)
}

pub fn init(args: &InitArgs) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(p) => read_config(p)?,
        None => ModelConfig::default(),
    };
    if let Some(v) = &args.variant {
        config.variant = Variant::parse(v).with_context(|| {
            format!("unknown variant {v:?} (iastgcn, iastgcn-a, iastgcn-t, iastgcn-s)")
        })?;
    }
    let graph = match &args.graph {
        Some(p) => Graph::load(p)?,
        None => Graph::default_asset(),
    };
    if graph.len() != config.nodes {
        bail!(
            "the graph has {} nodes, the config {}",
            graph.len(),
            config.nodes
        );
    }
    let parameters = Parameters::init(&config, args.seed);
    let checkpoint = Checkpoint {
        normalization: Normalization::identity(&config),
        config,
        graph,
        parameters,
    };
    checkpoint.save(&args.out)?;
    println!(
        "wrote {} ({}, {} parameters in {} tensors, seed {})",
        args.out.display(),
        checkpoint.config.variant,
        checkpoint.parameters.count(),
        checkpoint.parameters.specs.len(),
        args.seed
    );
    Ok(())
}

/// Reads tensor `name` (f32) from a safetensors file.
fn read_tensor(path: &Path, name: &str) -> anyhow::Result<(Vec<usize>, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let st = SafeTensors::deserialize(&bytes)
        .with_context(|| format!("{}: not a valid safetensors file", path.display()))?;
    let t = st.tensor(name).map_err(|_| {
        anyhow::anyhow!(
            "{}: no tensor {name:?} (found: {})",
            path.display(),
            st.names().join(", ")
        )
    })?;
    if t.dtype() != Dtype::F32 {
        bail!(
            "{}: tensor {name}: dtype {:?}, expected F32",
            path.display(),
            t.dtype()
        );
    }
    Ok((t.shape().to_vec(), f32_values(&t)))
}

pub fn forward(gpu: &Gpu, args: &ForwardArgs) -> anyhow::Result<()> {
    let checkpoint = Checkpoint::load(&args.model)?;
    let config = &checkpoint.config;
    let (shape, x) = read_tensor(&args.input, "x")?;
    let expected = [config.nodes, config.features, config.window];
    if shape.len() != 4 || shape[1..] != expected {
        bail!(
            "{}: tensor x has shape {shape:?}, expected [B, {}, {}, {}]",
            args.input.display(),
            expected[0],
            expected[1],
            expected[2]
        );
    }
    let windows = shape[0];
    if windows == 0 || args.batch == 0 {
        bail!("nothing to run: B = {windows}, --batch {}", args.batch);
    }
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        bail!("{}: x element {i} is {}", args.input.display(), x[i]);
    }
    let capacity = windows.min(args.batch);
    let net = Network::for_inference(gpu, config, &checkpoint.graph, capacity)?;
    net.load_parameters(gpu, &checkpoint.parameters)?;
    let len = expected.iter().product::<usize>();
    let mut y = Vec::with_capacity(windows * config.outputs);
    let mut staging = vec![0.0f32; capacity * len];
    let readback = Readback::new(gpu, "y", net.output.byte_len());
    let mut out = vec![0.0f32; net.output.numel()];
    for chunk in x.chunks(capacity * len) {
        staging[..chunk.len()].copy_from_slice(chunk);
        staging[chunk.len()..].fill(0.0);
        gpu.write(&net.input, &staging)?;
        let mut rec = Recorder::new(gpu);
        net.record_forward(&mut rec)?;
        rec.read_into(&net.output, &readback)?;
        rec.submit();
        readback.read_into(gpu, &mut out)?;
        y.extend_from_slice(&out[..chunk.len() / len * config.outputs]);
    }
    let bytes: &[u8] = bytemuck::cast_slice(&y);
    let view = TensorView::new(Dtype::F32, vec![windows, config.outputs], bytes)?;
    let file = safetensors::serialize([("y", view)], None)?;
    iastgcn::atomic::write(&args.out, &file)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "wrote {} (y [{windows}, {}], {} on {})",
        args.out.display(),
        config.outputs,
        config.variant,
        gpu.info().name
    );
    Ok(())
}
