//! The whole network on the device: parameters, gradients, activations, and the
//! forward / backward schedules for one batch size. Nothing is allocated and no
//! pipeline is created after [`Network::new`]; a training step reads nothing back.

use super::block::wgsl::{Block, DropoutSlots, Extent, MaskedStep, Table};
use super::config::Family;
use super::config::ModelConfig;
use super::conv_lstm::wgsl::ConvLstmBody;
use super::dense::wgsl::DenseBody;
use super::dense::Architecture;
use super::error::ModelError;
use super::head::wgsl::Head;
use super::params::{check_parameter_count, graph_basis, param_specs, ParamSpec, Parameters};
use super::recurrent::wgsl::{RecurrentBody, TimeLoop};
pub use super::schedule::Pass;
use super::schedule::{self, Profile, Scratch, Steps, Timing};
use crate::gpu::{DType, Gpu, GpuError, Recorder, Tensor};
use crate::graph::Graph;
use crate::ops::loss::PoseLoss;
use crate::ops::Accumulate;

/// A network (IASTGCN, an ablation or a dense baseline) on one device for a fixed batch
/// size.
pub struct Network {
    /// The model's `[model]` config (validated when the network was built).
    pub config: ModelConfig,
    /// Windows B per forward and backward pass; every activation has this leading axis.
    pub batch: usize,
    /// Windows per ensemble of the loss (docs/model.md "Refinement"); 1 = the plain loss.
    pub group: usize,
    /// The schedules built: [`Pass::Train`] for the inference forward, the training
    /// forward and the backward ([`Network::new`]); [`Pass::Inference`] for the inference
    /// forward only ([`Network::for_inference`]).
    pub built_for: Pass,
    /// Name and shape of every parameter tensor, in [`param_specs`] order
    /// (docs/model.md "Parameter names").
    pub specs: Vec<ParamSpec>,
    /// Parameters and their gradients, in [`param_specs`] order.
    pub params: Vec<Tensor>,
    /// ∂ℒ/∂parameter of the last backward pass, one per entry of `params` with the same
    /// shape; each backward overwrites them, and they hold the data term only (the
    /// optimiser adds the weight decay).
    pub grads: Vec<Tensor>,
    /// `x` [B, N, F, T] (write before recording a forward pass).
    pub input: Tensor,
    /// `y` [B, O] in standardised label space (for the loss).
    pub target: Tensor,
    /// `ŷ` [B, O].
    pub output: Tensor,
    /// The loss of the last backward pass, `[1]`.
    pub loss: Tensor,
    /// ∂ℒ/∂x [B, N, F, T], written by the backward pass.
    pub input_grad: Tensor,
    /// What runs between x and the head.
    body: Body,
    infer: Steps,
    train: Steps,
    backward: Steps,
    dropout: Vec<DropoutSlots>,
    /// Indices of the loss forward and backward dispatches in `backward`.
    loss_slots: [usize; 2],
}

impl Network {
    /// Allocates everything for training on `batch` windows and builds the schedules
    /// (inference, training forward, backward). Parameters start at zero: load them
    /// with [`Network::load_parameters`].
    pub fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        graph: &Graph,
        batch: usize,
        dropout_seed: u32,
    ) -> Result<Network, ModelError> {
        Network::build(gpu, config, graph, batch, 1, dropout_seed, Pass::Train)
    }

    /// Training on ensembles (docs/model.md refinement): `batch` windows = batch/group ensembles of `group` consecutive windows; the loss is the ensemble loss.
    pub fn for_ensembles(
        gpu: &Gpu,
        config: &ModelConfig,
        graph: &Graph,
        batch: usize,
        group: usize,
        dropout_seed: u32,
    ) -> Result<Network, ModelError> {
        Network::build(gpu, config, graph, batch, group, dropout_seed, Pass::Train)
    }

    /// The inference forward only: no training schedules, gradient scratch or dropout.
    pub fn for_inference(
        gpu: &Gpu,
        config: &ModelConfig,
        graph: &Graph,
        batch: usize,
    ) -> Result<Network, ModelError> {
        Network::build(gpu, config, graph, batch, 1, 0, Pass::Inference)
    }

    fn build(
        gpu: &Gpu,
        config: &ModelConfig,
        graph: &Graph,
        batch: usize,
        group: usize,
        dropout_seed: u32,
        built_for: Pass,
    ) -> Result<Network, ModelError> {
        let training = built_for == Pass::Train;
        config
            .validate()
            .and_then(|()| check_parameter_count(config))
            .map_err(ModelError::Config)?;
        if graph.len() != config.nodes {
            return Err(ModelError::Config(format!(
                "graph has {} nodes, the model config {}",
                graph.len(),
                config.nodes
            )));
        }
        if batch == 0 {
            return Err(ModelError::Config("batch size must be positive".into()));
        }
        if group == 0 || !batch.is_multiple_of(group) {
            return Err(ModelError::Config(format!(
                "batch of {batch} windows does not split into ensembles of {group}"
            )));
        }
        let specs = param_specs(config);
        let params: Vec<Tensor> = specs
            .iter()
            .map(|s| gpu.zeros(&s.name, &s.shape, DType::F32))
            .collect::<Result<_, GpuError>>()?;
        let grads: Vec<Tensor> = specs
            .iter()
            .map(|s| gpu.zeros(&format!("grad {}", s.name), &s.shape, DType::F32))
            .collect::<Result<_, GpuError>>()?;
        let (n, t, o) = (config.nodes, config.window, config.outputs);
        let basis_data: Vec<f32> = graph_basis(graph, config)
            .iter()
            .map(|&v| v as f32)
            .collect();
        let basis = match config.graph_terms() {
            0 => None,
            terms => Some(gpu.upload("graph.basis", &[terms, n, n], &basis_data)?),
        };
        let input = gpu.zeros("x", &[batch, n, config.features, t], DType::F32)?;
        let input_grad = gpu.zeros("dx", &[batch, n, config.features, t], DType::F32)?;
        let target = gpu.zeros("y", &[batch, o], DType::F32)?;
        let output = gpu.zeros("y_hat", &[batch, o], DType::F32)?;
        let loss = gpu.zeros("loss", &[1], DType::F32)?;
        let table = Table::new(&specs, &params, &grads, basis.as_ref());
        let io = Io {
            input: &input,
            input_grad: &input_grad,
            output: &output,
            target: &target,
            loss: &loss,
        };
        let s = match (Architecture::of(config), config.variant.family()) {
            (Some(arch), _) => {
                let indices = arch
                    .input_indices(graph, config.features)
                    .map_err(ModelError::Config)?;
                let body = DenseBody::new(gpu, config, arch, &indices, batch, &output)?;
                dense_schedules(gpu, config, group, training, &table, &io, body)?
            }
            (None, Family::Recurrent) => {
                let body = RecurrentBody::new(gpu, config, graph, batch)?;
                recurrent_schedules(gpu, config, group, training, &table, &io, &body)?
            }
            (None, Family::ConvRecurrent) => {
                let body = ConvLstmBody::new(gpu, config, batch)?;
                recurrent_schedules(gpu, config, group, training, &table, &io, &body)?
            }
            (None, _) => block_schedules(gpu, config, group, dropout_seed, training, &table, &io)?,
        };
        Ok(Network {
            config: config.clone(),
            batch,
            group,
            built_for,
            specs,
            params,
            grads,
            input,
            target,
            output,
            loss,
            input_grad,
            body: s.body,
            infer: s.infer,
            train: s.train,
            backward: s.backward,
            dropout: s.dropout,
            loss_slots: s.loss_slots,
        })
    }

    /// The loss and the backward schedule (docs/model.md order reversed).
    #[allow(clippy::too_many_arguments)]
    fn build_backward(
        gpu: &Gpu,
        config: &ModelConfig,
        group: usize,
        table: &Table,
        blocks: &[Block],
        fwd_slots: &[Option<MaskedStep>],
        input_grad: &Tensor,
        output: &Tensor,
        target: &Tensor,
        loss: &Tensor,
        h: &Tensor,
        backward: &mut Steps,
        dropout: &mut Vec<DropoutSlots>,
    ) -> Result<[usize; 2], ModelError> {
        let batch = input_grad.shape()[0];
        let (n, t, c) = (config.nodes, config.window, config.channels);
        let head = Head::new(config, batch, n * c);
        let (loss_slots, doutput) = loss_steps(gpu, config, group, output, target, loss, backward)?;
        let dh = gpu.zeros("head.dh", &[batch, n * c], DType::F32)?;
        head.backward(gpu, table, h, &doutput, &dh, backward)?;
        let hidden = [batch, n, c, t];
        let ping = [
            gpu.zeros("d block output (even)", &hidden, DType::F32)?,
            gpu.zeros("d block output (odd)", &hidden, DType::F32)?,
        ];
        let mut scratch = Scratch::new(gpu);
        for (l, block) in blocks.iter().enumerate().rev() {
            let d_in = if l == 0 {
                input_grad
            } else {
                &ping[(l + 1) % 2]
            };
            // The trimmed last block's output gradient is dh itself.
            let d_out = if l + 1 == blocks.len() {
                &dh
            } else {
                &ping[l % 2]
            };
            let masked = block.backward(gpu, table, &mut scratch, backward, d_out, d_in)?;
            dropout.push(DropoutSlots {
                // invariant: a training forward records its LayerNorm's dropout per block.
                forward: fwd_slots[l].expect("training forward has dropout"),
                backward: masked,
            });
        }
        Ok(loss_slots)
    }

    /// The attitude penalty P of the loss (default 1).
    pub fn set_attitude_penalty(&self, gpu: &Gpu, penalty: f64) -> Result<(), GpuError> {
        let pose = PoseLoss {
            batch: self.batch,
            outputs: self.config.outputs,
            penalty,
            group: self.group,
        };
        self.expect_training()?;
        for i in self.loss_slots {
            // invariant: loss_steps stores the indices of the two dispatches it recorded.
            let d = self.backward.dispatch(i).expect("loss slot is a dispatch");
            pose.set_penalty(gpu, d)?;
        }
        Ok(())
    }

    /// Copies host parameters to the device (names and shapes must match).
    pub fn load_parameters(&self, gpu: &Gpu, p: &Parameters) -> Result<(), ModelError> {
        if p.specs.len() != self.specs.len() {
            return Err(ModelError::Config(format!(
                "{} parameter tensors given, the {} model has {}",
                p.specs.len(),
                self.config.variant,
                self.specs.len()
            )));
        }
        for ((spec, values), (mine, t)) in p
            .specs
            .iter()
            .zip(&p.values)
            .zip(self.specs.iter().zip(&self.params))
        {
            if spec.name != mine.name || spec.shape != mine.shape || values.len() != mine.numel() {
                return Err(ModelError::Parameter {
                    name: spec.name.clone(),
                    message: format!(
                        "expected {} {:?}, got {} {:?} ({} values)",
                        mine.name,
                        mine.shape,
                        spec.name,
                        spec.shape,
                        values.len()
                    ),
                });
            }
            gpu.write(t, values)?;
        }
        Ok(())
    }

    /// Reads the parameters back.
    pub fn read_parameters(&self, gpu: &Gpu) -> Result<Parameters, GpuError> {
        Ok(Parameters {
            specs: self.specs.clone(),
            values: self.read_all(gpu, &self.params)?,
        })
    }

    /// Reads the gradients of the last backward pass, in [`param_specs`] order.
    pub fn read_gradients(&self, gpu: &Gpu) -> Result<Vec<Vec<f32>>, GpuError> {
        self.read_all(gpu, &self.grads)
    }

    fn read_all(&self, gpu: &Gpu, ts: &[Tensor]) -> Result<Vec<Vec<f32>>, GpuError> {
        ts.iter()
            .map(|t| {
                gpu.read_f32(t).map(|mut v| {
                    v.truncate(t.numel());
                    v
                })
            })
            .collect()
    }

    /// Records the forward pass (inference: no dropout).
    pub fn record_forward(&self, rec: &mut Recorder) -> Result<(), GpuError> {
        self.infer.record(rec)
    }

    /// Records the training forward pass (dropout with the mask of the current step).
    pub fn record_train_forward(&self, rec: &mut Recorder) -> Result<(), GpuError> {
        self.expect_training()?;
        self.train.record(rec)
    }

    /// Records the loss and the backward pass of the last training forward into
    /// [`Network::grads`], [`Network::loss`] and [`Network::input_grad`].
    pub fn record_backward(&self, rec: &mut Recorder) -> Result<(), GpuError> {
        self.expect_training()?;
        self.backward.record(rec)
    }

    fn expect_training(&self) -> Result<(), GpuError> {
        if self.built_for == Pass::Train {
            Ok(())
        } else {
            Err(GpuError::Device(
                "this network was built for inference only (Network::for_inference)".into(),
            ))
        }
    }

    /// Points every dropout mask at training step `step` (rewrites uniforms only).
    pub fn set_step(&self, gpu: &Gpu, step: u32) -> Result<(), GpuError> {
        for s in &self.dropout {
            let [input, params] = s.backward;
            for (steps, m) in [
                (&self.train, s.forward),
                (&self.backward, input),
                (&self.backward, params),
            ] {
                // invariant: the slots were recorded as dispatches when the schedule was built.
                let d = steps.dispatch(m.index).expect("dropout slot is a dispatch");
                m.layer_norm.set_step(gpu, d, step, Accumulate::Overwrite)?;
            }
        }
        Ok(())
    }

    /// Where the time of one pass goes, step by step: the training step (forward, loss
    /// and backward, recorded as training records them) or the inference forward, timed
    /// as `timing` says ([`Timing::best`] picks timestamps where the device has them).
    pub fn profile(
        &self,
        gpu: &Gpu,
        pass: Pass,
        timing: Timing,
        repeats: usize,
    ) -> Result<Profile, GpuError> {
        match pass {
            Pass::Inference => schedule::profile(gpu, &[&self.infer], timing, repeats),
            Pass::Train => {
                self.expect_training()?;
                schedule::profile(gpu, &[&self.train, &self.backward], timing, repeats)
            }
        }
    }

    /// Number of dispatches and copies in (inference, training forward, backward).
    pub fn schedule_sizes(&self) -> (usize, usize, usize) {
        (self.infer.len(), self.train.len(), self.backward.len())
    }

    /// Number of ST blocks L (0 for a baseline).
    pub fn blocks(&self) -> usize {
        match &self.body {
            Body::Blocks(b) => b.len(),
            Body::Dense | Body::Recurrent => 0,
        }
    }

    /// True for a dense baseline (layers on the last step instead of ST blocks).
    pub fn is_dense(&self) -> bool {
        matches!(self.body, Body::Dense)
    }

    /// Convenience for tests and tools: runs the inference forward on `x` and reads ŷ.
    pub fn predict(&self, gpu: &Gpu, x: &[f32]) -> Result<Vec<f32>, GpuError> {
        gpu.write(&self.input, x)?;
        let mut rec = Recorder::new(gpu);
        self.record_forward(&mut rec)?;
        rec.submit()?;
        let mut y = gpu.read_f32(&self.output)?;
        y.truncate(self.output.numel());
        Ok(y)
    }

    /// Convenience for tests: training forward + backward at dropout step `step`.
    pub fn gradients(&self, gpu: &Gpu, x: &[f32], y: &[f32], step: u32) -> Result<(), GpuError> {
        gpu.write(&self.input, x)?;
        gpu.write(&self.target, y)?;
        self.set_step(gpu, step)?;
        let mut rec = Recorder::new(gpu);
        self.record_train_forward(&mut rec)?;
        self.record_backward(&mut rec)?;
        rec.submit()?;
        gpu.wait()
    }
}

/// The tensors every schedule reads or writes.
struct Io<'a> {
    input: &'a Tensor,
    input_grad: &'a Tensor,
    output: &'a Tensor,
    target: &'a Tensor,
    loss: &'a Tensor,
}

/// What runs between x and ŷ.
enum Body {
    /// IASTGCN's ST blocks; the head follows.
    Blocks(Vec<Block>),
    /// A dense baseline's layers, the head included (its schedules hold its tensors).
    Dense,
    /// A recurrent baseline's time loop (GRU or ConvLSTM); the head follows (its schedules
    /// hold its tensors).
    Recurrent,
}

impl Default for Body {
    fn default() -> Body {
        Body::Blocks(Vec::new())
    }
}

/// A body's schedules and the parts of it that they keep.
#[derive(Default)]
struct Schedules {
    body: Body,
    infer: Steps,
    train: Steps,
    backward: Steps,
    dropout: Vec<DropoutSlots>,
    loss_slots: [usize; 2],
}

/// A dense baseline's schedules: its forward (the same with and without training: no
/// dropout), the loss and its backward.
fn dense_schedules(
    gpu: &Gpu,
    config: &ModelConfig,
    group: usize,
    training: bool,
    table: &Table,
    io: &Io,
    body: DenseBody,
) -> Result<Schedules, ModelError> {
    let mut s = Schedules::default();
    body.forward(gpu, table, io.input, &mut s.infer)?;
    if training {
        body.forward(gpu, table, io.input, &mut s.train)?;
        let (slots, doutput) = loss_steps(
            gpu,
            config,
            group,
            io.output,
            io.target,
            io.loss,
            &mut s.backward,
        )?;
        s.loss_slots = slots;
        body.backward(gpu, table, &doutput, io.input_grad, &mut s.backward)?;
    }
    s.body = Body::Dense;
    Ok(s)
}

/// IASTGCN's schedules: the ST blocks (the last trimmed to the last step, which is all
/// the head reads), the head, and with training the loss and the backward pass.
fn block_schedules(
    gpu: &Gpu,
    config: &ModelConfig,
    group: usize,
    dropout_seed: u32,
    training: bool,
    table: &Table,
    io: &Io,
) -> Result<Schedules, ModelError> {
    let batch = io.input.shape()[0];
    let mut s = Schedules::default();
    let mut blocks: Vec<Block> = Vec::with_capacity(config.blocks);
    for l in 0..config.blocks {
        let x = blocks.last().map_or(io.input, |b| &b.output).clone();
        let extent = if l + 1 == config.blocks {
            Extent::LastStep
        } else {
            Extent::Window
        };
        blocks.push(Block::new(gpu, config, l, batch, &x, dropout_seed, extent)?);
    }
    // The trimmed last block's output [B, N, C, 1] is the head's input h [B, N·C].
    // invariant: ModelConfig::validate requires blocks >= 1.
    let h = blocks.last().expect("at least one block").output.clone();
    let head = Head::new(config, batch, config.nodes * config.channels);
    let mut fwd_slots = Vec::new();
    for block in &blocks {
        block.forward(gpu, table, &mut s.infer, Pass::Inference)?;
        if training {
            fwd_slots.push(block.forward(gpu, table, &mut s.train, Pass::Train)?);
        }
    }
    let head_steps = if training {
        vec![&mut s.infer, &mut s.train]
    } else {
        vec![&mut s.infer]
    };
    for steps in head_steps {
        head.forward(gpu, table, &h, io.output, steps)?;
    }
    if training {
        s.loss_slots = Network::build_backward(
            gpu,
            config,
            group,
            table,
            &blocks,
            &fwd_slots,
            io.input_grad,
            io.output,
            io.target,
            io.loss,
            &h,
            &mut s.backward,
            &mut s.dropout,
        )?;
    }
    s.body = Body::Blocks(blocks);
    Ok(s)
}

/// A recurrent baseline's schedules: the time loop, the head on the last state (or the
/// attention's context), and with training the loss, the head's backward and
/// backpropagation through time.
fn recurrent_schedules(
    gpu: &Gpu,
    config: &ModelConfig,
    group: usize,
    training: bool,
    table: &Table,
    io: &Io,
    body: &dyn TimeLoop,
) -> Result<Schedules, ModelError> {
    let batch = io.input.shape()[0];
    let last = body.output();
    let head = Head::new(config, batch, last.numel() / batch);
    let mut s = Schedules::default();
    let passes = if training {
        vec![&mut s.infer, &mut s.train]
    } else {
        vec![&mut s.infer]
    };
    for steps in passes {
        body.forward(gpu, table, io.input, steps)?;
        head.forward(gpu, table, last, io.output, steps)?;
    }
    if training {
        let b = &mut s.backward;
        let (slots, doutput) = loss_steps(gpu, config, group, io.output, io.target, io.loss, b)?;
        s.loss_slots = slots;
        let d_last = gpu.zeros("d head input", last.shape(), DType::F32)?;
        head.backward(gpu, table, last, &doutput, &d_last, b)?;
        body.backward(gpu, table, &d_last, io.input_grad, b)?;
    }
    s.body = Body::Recurrent;
    Ok(s)
}

/// Appends the loss (eq. 39) and its gradient ∂ℒ/∂ŷ to `backward`: the indices of the two
/// dispatches (to change the attitude penalty) and the gradient tensor `[B, O]`.
fn loss_steps(
    gpu: &Gpu,
    config: &ModelConfig,
    group: usize,
    output: &Tensor,
    target: &Tensor,
    loss: &Tensor,
    backward: &mut Steps,
) -> Result<([usize; 2], Tensor), GpuError> {
    let batch = output.shape()[0];
    let pose = PoseLoss {
        batch,
        outputs: config.outputs,
        penalty: 1.0,
        group,
    };
    let doutput = gpu.zeros("d y_hat", &[batch, config.outputs], DType::F32)?;
    let slots = [
        backward.run(pose.forward(gpu, output, target, loss))?,
        backward.run(pose.backward(gpu, output, target, &doutput))?,
    ];
    Ok((slots, doutput))
}
