//! Interoperability with other frameworks (`iastgcn init` and `iastgcn forward`): a freshly
//! initialised checkpoint from a run config, and a checkpoint run on the tensor `x` of a
//! safetensors file with `y` written back, both in standardised units, so that another
//! implementation can be compared on the same weights.
//!
//! It sits above `model`, `graph` and `train` (it reads a run config's `[model]` table),
//! so that `model` keeps depending on neither.

use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::error::{ensure, write_file, Error, Result};
use crate::gpu::Gpu;
use crate::graph::Graph;
use crate::model::checkpoint::f32_values;
use crate::model::{Checkpoint, ModelConfig, Network, Normalization, Parameters, Variant};
use crate::train::RunConfig;

/// A safetensors file that cannot be used: the file, the tensor meant and why.
#[derive(Debug, thiserror::Error)]
#[error("{}: {}{message}", path.display(), tensor.as_ref().map(|t| format!("tensor {t}: ")).unwrap_or_default())]
pub struct TensorFileError {
    /// The safetensors file read or written.
    pub path: PathBuf,
    /// The tensor, when the problem is one tensor's.
    pub tensor: Option<String>,
    /// What is wrong (e.g. a missing tensor, a dtype other than F32, a wrong shape, a
    /// non-finite element).
    pub message: String,
}

impl crate::error::StageError for TensorFileError {}

impl TensorFileError {
    fn new(path: &Path, tensor: Option<&str>, message: impl Into<String>) -> TensorFileError {
        TensorFileError {
            path: path.to_path_buf(),
            tensor: tensor.map(str::to_string),
            message: message.into(),
        }
    }
}

/// A freshly initialised checkpoint (He uniform from `seed`: docs/model.md
/// "Initialisation") with identity normalisation statistics, for the `[model]` table of
/// the run config at `config` (the paper shape when `None`), its variant replaced by
/// `variant` when given, on the sensor graph at `graph` (the embedded 14-node graph when
/// `None`), whose node count must match the config's.
pub fn init(
    config: Option<&Path>,
    variant: Option<Variant>,
    graph: Option<&Path>,
    seed: u64,
) -> Result<Checkpoint> {
    let mut config = match config {
        Some(p) => RunConfig::load(p)?.model,
        None => ModelConfig::default(),
    };
    if let Some(v) = variant {
        config.variant = v;
    }
    let graph = Graph::load_or_default(graph, config.look_ahead)?;
    ensure(graph.len() == config.nodes, || {
        format!(
            "the graph has {} nodes, the config {}",
            graph.len(),
            config.nodes
        )
    })?;
    Ok(Checkpoint {
        normalization: Normalization::identity(&config),
        parameters: Parameters::init(&config, seed),
        config,
        graph,
    })
}

/// Tensor `name` (f32) of the safetensors file at `path`, as its shape and values.
pub fn read_tensor(path: &Path, name: &str) -> Result<(Vec<usize>, Vec<f32>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| {
        TensorFileError::new(path, None, format!("not a valid safetensors file: {e}"))
    })?;
    let t = st.tensor(name).map_err(|_| {
        let found = st.names().join(", ");
        TensorFileError::new(path, Some(name), format!("missing (found: {found})"))
    })?;
    if t.dtype() != Dtype::F32 {
        let message = format!("dtype {:?}, expected F32", t.dtype());
        return Err(TensorFileError::new(path, Some(name), message).into());
    }
    Ok((t.shape().to_vec(), f32_values(&t)))
}

/// Writes `values` as the f32 tensor `name` of shape `shape`, alone in a safetensors file
/// at `path` (atomically).
pub fn write_tensor(path: &Path, name: &str, shape: &[usize], values: &[f32]) -> Result<()> {
    let err =
        |e: safetensors::SafeTensorError| TensorFileError::new(path, Some(name), e.to_string());
    let view =
        TensorView::new(Dtype::F32, shape.to_vec(), bytemuck::cast_slice(values)).map_err(err)?;
    let file = safetensors::serialize([(name, view)], None).map_err(err)?;
    write_file(path, &file)
}

/// What [`forward`] wrote: `y` `[windows, outputs]` from a model of `variant`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Forwarded {
    /// Windows B run: the leading axis of the input `x` and of `y`.
    pub windows: usize,
    /// Outputs O per window (the checkpoint's `[model] outputs`).
    pub outputs: usize,
    /// The variant of the checkpoint that was run.
    pub variant: Variant,
}

/// The interoperability check: runs the checkpoint at `model` on the tensor `x`
/// `[B, N, F, T]` (f32, standardised features, every element finite) of the safetensors
/// file `input`, `batch` windows per submit, and writes `y` `[B, O]` in standardised
/// label space (the network's output, not de-standardised) to `out`.
pub fn forward(
    gpu: &Gpu,
    model: &Path,
    input: &Path,
    out: &Path,
    batch: usize,
) -> Result<Forwarded> {
    let checkpoint = Checkpoint::load(model)?;
    let config = &checkpoint.config;
    let (shape, x) = read_tensor(input, "x")?;
    let expected = [config.nodes, config.features, config.window];
    if shape.len() != 4 || shape[1..] != expected {
        let message = format!(
            "shape {shape:?}, expected [B, {}, {}, {}]",
            expected[0], expected[1], expected[2]
        );
        return Err(TensorFileError::new(input, Some("x"), message).into());
    }
    let windows = shape[0];
    if windows == 0 {
        let message = format!("shape {shape:?}: no window to run (B = 0)");
        return Err(TensorFileError::new(input, Some("x"), message).into());
    }
    if batch == 0 {
        return Err(Error::Setting {
            setting: "predict.batch",
            message: "at least 1 window per batch, got 0".into(),
        });
    }
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        let message = format!("element {i} is {}", x[i]);
        return Err(TensorFileError::new(input, Some("x"), message).into());
    }
    let y = forward_windows(gpu, &checkpoint, &x, batch)?;
    write_tensor(out, "y", &[windows, config.outputs], &y)?;
    Ok(Forwarded {
        windows,
        outputs: config.outputs,
        variant: config.variant,
    })
}

/// The network's output `[W, O]` (standardised label space) for the windows `x`
/// `[W, N, F, T]` (standardised features), `batch` windows per submit: the inference
/// [`Network`] itself, the last batch padded with zeros. Unlike
/// [`crate::model::Predictor`] it neither de-standardises nor needs O = 6.
pub fn forward_windows(
    gpu: &Gpu,
    checkpoint: &Checkpoint,
    x: &[f32],
    batch: usize,
) -> Result<Vec<f32>> {
    let config = &checkpoint.config;
    let len = config.nodes * config.features * config.window;
    ensure(batch > 0 && x.len().is_multiple_of(len), || {
        format!(
            "x: {} floats in batches of {batch}: not whole windows of N·F·T = {len}",
            x.len()
        )
    })?;
    let windows = x.len() / len;
    let capacity = windows.clamp(1, batch);
    let net = Network::for_inference(gpu, config, &checkpoint.graph, capacity)
        .map_err(|e| crate::train::batch_error(e, capacity))?;
    net.load_parameters(gpu, &checkpoint.parameters)?;
    let mut y = Vec::with_capacity(windows * config.outputs);
    let mut staging = vec![0.0f32; capacity * len];
    for chunk in x.chunks(capacity * len) {
        staging[..chunk.len()].copy_from_slice(chunk);
        staging[chunk.len()..].fill(0.0);
        let out = net.predict(gpu, &staging)?;
        y.extend_from_slice(&out[..chunk.len() / len * config.outputs]);
    }
    Ok(y)
}
