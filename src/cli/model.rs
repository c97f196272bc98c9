//! `iastgcn init` (a freshly initialised checkpoint) and `iastgcn forward` (the
//! interop check: run a checkpoint on a tensor `x` from a safetensors file): arguments,
//! the library's `interop::init` and `interop::forward`, and their printout.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use iastgcn::gpu::Gpu;
use iastgcn::interop;
use iastgcn::model::Variant;

#[derive(Args)]
pub struct InitArgs {
    /// Run config (TOML); its `[model]` table holds the fields of docs/model.md's notation
    /// table: variant, nodes, features, window, channels, blocks, kernel, scale, …; the
    /// paper shape when absent.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the config's variant: iastgcn, iastgcn-a, iastgcn-t, iastgcn-s, or a baseline: convlstm, tgcn, eat-gcn, st-gat, mlp, bkls-ann, ann-bfpa, erc.
    #[arg(long)]
    pub variant: Option<String>,
    /// Sensor graph (TOML); the embedded 14-node graph when absent.
    #[arg(long)]
    pub graph: Option<PathBuf>,
    /// Seed of the He-uniform initialisation of the weights.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Checkpoint to write (safetensors: the weights, the model config, the graph).
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
    /// Most windows per submit (all of them when the input has fewer); refused with a
    /// smaller batch to try when the adapter cannot hold it.
    #[arg(long, default_value_t = 64, value_parser = super::count(1..))]
    pub batch: usize,
}

pub fn init(args: &InitArgs) -> anyhow::Result<()> {
    let variant = match &args.variant {
        Some(v) => Some(
            Variant::parse(v)
                .with_context(|| format!("unknown variant {v:?} ({})", Variant::names()))?,
        ),
        None => None,
    };
    let checkpoint = interop::init(
        args.config.as_deref(),
        variant,
        args.graph.as_deref(),
        args.seed,
    )?;
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

pub fn forward(gpu: &Gpu, args: &ForwardArgs) -> anyhow::Result<()> {
    let y = interop::forward(gpu, &args.model, &args.input, &args.out, args.batch)?;
    println!(
        "wrote {} (y [{}, {}], {} on {})",
        args.out.display(),
        y.windows,
        y.outputs,
        y.variant,
        gpu.info().name
    );
    Ok(())
}
