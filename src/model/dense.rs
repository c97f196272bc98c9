//! The dense baselines (docs/model.md "Baselines"): the instantaneous MLP and the three
//! offline pose→error models of Table V. Each reads only the window's last step (so no
//! history), picks its inputs from it, and runs a chain of fully connected layers into
//! the same head and loss as IASTGCN. Every layer is existing ops: the last-step gather of
//! the head, a matmul, a bias and an activation; a skip connection is a copy that the
//! matmul then accumulates onto. The f64 reference is `model::reference::dense`.

use super::config::{ModelConfig, Variant};
use super::schedule::ParamTable;
use super::schedule::Steps;
use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::graph::Graph;
use crate::ops::bias::Bias;
use crate::ops::elementwise::{binary_backward, unary_backward, unary_forward, Binary, Unary};
use crate::ops::head::LastStep;
use crate::ops::matmul::Matmul;
use crate::ops::Accumulate;

/// What a dense baseline reads from the last step of its window.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Inputs {
    /// All N·F features (the instantaneous MLP).
    EveryNode,
    /// The first feature (r, the low-passed value) of the named joint-input nodes
    /// (`ModelConfig::joint_inputs`; the offline pose→error models): with the pose a
    /// function of them, they are the commanded pose.
    JointInputs(Vec<String>),
}

/// One fully connected layer: `out = act(in · weightᵀ + bias) (+ skip)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// Parameter prefix: `<name>.weight [outputs, inputs]`, `<name>.bias [outputs]`.
    pub name: String,
    /// Width of its input.
    pub inputs: usize,
    /// Width of its output.
    pub outputs: usize,
    /// Its activation; `None` is linear.
    pub activation: Option<Unary>,
    /// The activation (0 = the selected input, i + 1 = layer i's output) added to this
    /// layer's output: the shortcut of a residual block.
    pub skip: Option<usize>,
}

/// A dense baseline: what it reads and its layers, the head last.
#[derive(Clone, Debug, PartialEq)]
pub struct Architecture {
    /// What it reads.
    pub inputs: Inputs,
    /// Its layers in order; the last is the head (`head.weight [O, ·]`, `head.bias [O]`).
    pub layers: Vec<Layer>,
}

impl Architecture {
    /// The network of a dense variant (docs/model.md "Baselines"); `None` for the
    /// ST-block variants. H = `config.hidden`.
    pub fn of(config: &ModelConfig) -> Option<Architecture> {
        let (h, o) = (config.hidden, config.outputs);
        let nf = config.nodes * config.features;
        let joints = config.joint_inputs.len();
        let joint_inputs = || Inputs::JointInputs(config.joint_inputs.clone());
        let layer = |name: &str, inputs, outputs, activation, skip| Layer {
            name: name.to_string(),
            inputs,
            outputs,
            activation,
            skip,
        };
        let head = |inputs| layer("head", inputs, o, None, None);
        let (inputs, layers) = match config.variant {
            Variant::Mlp => (
                Inputs::EveryNode,
                vec![
                    layer("dense.0", nf, h, Some(Unary::Relu), None),
                    layer("dense.1", h, h, Some(Unary::Relu), None),
                    head(h),
                ],
            ),
            Variant::BklsAnn => (
                joint_inputs(),
                vec![
                    layer("dense.0", joints, h, Some(Unary::Tanh), None),
                    layer("dense.1", h, h, Some(Unary::Tanh), None),
                    head(h),
                ],
            ),
            Variant::AnnBfpa => (
                joint_inputs(),
                vec![
                    layer("dense.0", joints, h, Some(Unary::Tanh), None),
                    head(h),
                ],
            ),
            Variant::Erc => (
                joint_inputs(),
                vec![
                    layer("stem", joints, h, Some(Unary::Relu), None),
                    layer("res.0.fc1", h, h, Some(Unary::Relu), None),
                    layer("res.0.fc2", h, h, None, Some(1)),
                    layer("res.1.fc1", h, h, Some(Unary::Relu), None),
                    layer("res.1.fc2", h, h, None, Some(3)),
                    head(h),
                ],
            ),
            Variant::Iastgcn
            | Variant::NoAttention
            | Variant::PlainTemporal
            | Variant::Chebyshev
            | Variant::Tgcn
            | Variant::EatGcn
            | Variant::StGat
            | Variant::ConvLstm => return None,
        };
        Some(Architecture { inputs, layers })
    }

    /// Width of the selected input (activation 0).
    pub fn input_width(&self) -> usize {
        self.layers[0].inputs
    }

    /// Positions `n·F + f` in a step's `[N, F]` features of the selected inputs, in order;
    /// the error names a joint input missing from the graph.
    pub fn input_indices(&self, graph: &Graph, features: usize) -> Result<Vec<usize>, String> {
        match &self.inputs {
            Inputs::EveryNode => Ok((0..graph.len() * features).collect()),
            Inputs::JointInputs(names) => names
                .iter()
                .map(|name| {
                    graph
                        .nodes
                        .iter()
                        .position(|n| n == name)
                        .map(|n| n * features)
                        .ok_or_else(|| {
                            format!(
                                "the offline baselines read the joint inputs {} (model.joint_inputs), and the graph has no node named {name}",
                                names.join(", ")
                            )
                        })
                })
                .collect(),
        }
    }

    /// Forward FLOPs for `batch` windows: every layer's product, plus the selection
    /// product of the joint inputs (see [`DenseBody`]).
    pub fn forward_flops(&self, config: &ModelConfig, batch: usize) -> f64 {
        let b = batch as f64;
        let layers: f64 = self
            .layers
            .iter()
            .map(|l| 2.0 * b * (l.inputs * l.outputs) as f64)
            .sum();
        let selection = match self.inputs {
            Inputs::EveryNode => 0.0,
            Inputs::JointInputs(_) => {
                2.0 * b * (config.nodes * config.features * self.input_width()) as f64
            }
        };
        layers + selection
    }
}

/// A dense baseline's tensors and ops for one batch size (part of a [`super::Network`]).
///
/// The selected input is the last step of x, `[B, N·F]`, times a constant 0/1 selection
/// matrix `[N·F, K]` when the model reads only the joint inputs (a tiny product that
/// reuses the matmul and its backward instead of a gather op of its own).
pub(super) struct DenseBody {
    arch: Architecture,
    /// The last step of x `[B, N·F]`, and its gradient.
    last: Tensor,
    last_grad: Tensor,
    /// The selection matrix `[N·F, K]`, when the model reads a subset.
    selection: Option<Tensor>,
    /// Activations: 0 = the selected input `[B, K]`, i + 1 = layer i's output (the last is
    /// the network's ŷ). A linear layer's output is its pre-activation.
    acts: Vec<Tensor>,
    /// Each layer's pre-activation `[B, outputs]` (the same tensor as its output when
    /// linear).
    pre: Vec<Tensor>,
    batch: usize,
    window: usize,
}

impl DenseBody {
    /// Allocates the activations of `arch` for `batch` windows reading x `[B, N, F, T]` at
    /// `indices` (from [`Architecture::input_indices`]) and writing `output` `[B, O]`.
    pub(super) fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        arch: Architecture,
        indices: &[usize],
        batch: usize,
        output: &Tensor,
    ) -> Result<DenseBody, GpuError> {
        let nf = config.nodes * config.features;
        let k = indices.len();
        let last = gpu.zeros("dense.last_step", &[batch, nf], DType::F32)?;
        let last_grad = gpu.zeros("dense.d_last_step", &[batch, nf], DType::F32)?;
        let selection = match arch.inputs {
            Inputs::EveryNode => None,
            Inputs::JointInputs(_) => {
                let mut s = vec![0f32; nf * k];
                for (j, &i) in indices.iter().enumerate() {
                    s[i * k + j] = 1.0;
                }
                Some(gpu.upload("dense.selection", &[nf, k], &s)?)
            }
        };
        let mut acts = vec![match selection {
            Some(_) => gpu.zeros("dense.input", &[batch, k], DType::F32)?,
            None => last.clone(),
        }];
        let mut pre = Vec::new();
        for (i, l) in arch.layers.iter().enumerate() {
            let is_head = i + 1 == arch.layers.len();
            let z = if is_head {
                output.clone()
            } else {
                gpu.zeros(&format!("{}.z", l.name), &[batch, l.outputs], DType::F32)?
            };
            let a = match l.activation {
                Some(_) => gpu.zeros(&format!("{}.a", l.name), &[batch, l.outputs], DType::F32)?,
                None => z.clone(),
            };
            pre.push(z);
            acts.push(a);
        }
        Ok(DenseBody {
            arch,
            last,
            last_grad,
            selection,
            acts,
            pre,
            batch,
            window: config.window,
        })
    }

    fn gather(&self) -> LastStep {
        LastStep {
            rows: self.last.numel(),
            steps: self.window,
        }
    }

    fn selector(&self) -> Matmul {
        Matmul::new(self.batch, self.acts[0].shape()[1], self.last.shape()[1])
    }

    fn linear(&self, l: &Layer) -> (Matmul, Bias) {
        (
            Matmul::new(self.batch, l.outputs, l.inputs).transpose_b(true),
            Bias {
                outer: self.batch,
                channels: l.outputs,
                inner: 1,
            },
        )
    }

    /// Appends the forward pass from x (`input`) to ŷ.
    pub(super) fn forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        input: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        steps.run(self.gather().forward(gpu, input, &self.last))?;
        if let Some(s) = &self.selection {
            steps.run(self.selector().forward(
                gpu,
                &self.last,
                s,
                &self.acts[0],
                Accumulate::Overwrite,
            ))?;
        }
        for (i, l) in self.arch.layers.iter().enumerate() {
            let (mm, bias) = self.linear(l);
            let z = &self.pre[i];
            let accumulate = match l.skip {
                Some(j) => {
                    let n = z.numel();
                    steps.copy_range((&self.acts[j], 0), (z, 0), n);
                    Accumulate::Add
                }
                None => Accumulate::Overwrite,
            };
            let weight = table.param(&format!("{}.weight", l.name));
            steps.run(mm.forward(gpu, &self.acts[i], weight, z, accumulate))?;
            steps.run(bias.forward(gpu, table.param(&format!("{}.bias", l.name)), z))?;
            if let Some(act) = l.activation {
                steps.run(unary_forward(
                    gpu,
                    act,
                    z,
                    &self.acts[i + 1],
                    Accumulate::Overwrite,
                ))?;
            }
        }
        Ok(())
    }

    /// Appends the backward pass from ∂ℒ/∂ŷ (`d_output`) to the parameter gradients and
    /// ∂ℒ/∂x (`input_grad`).
    pub(super) fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        d_output: &Tensor,
        input_grad: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let layers = &self.arch.layers;
        // ∂ℒ/∂ activation i; the first contribution overwrites, later ones add.
        let d_acts: Vec<Tensor> = (0..=layers.len())
            .map(|i| {
                if i == layers.len() {
                    Ok(d_output.clone())
                } else if i == 0 && self.selection.is_none() {
                    Ok(self.last_grad.clone())
                } else {
                    gpu.zeros(&format!("dense.d_act{i}"), self.acts[i].shape(), DType::F32)
                }
            })
            .collect::<Result<_, GpuError>>()?;
        let mut written = vec![false; layers.len() + 1];
        written[layers.len()] = true;
        let mode = |written: &mut Vec<bool>, i: usize| {
            let m = if written[i] {
                Accumulate::Add
            } else {
                Accumulate::Overwrite
            };
            written[i] = true;
            m
        };
        for (i, l) in layers.iter().enumerate().rev() {
            let (mm, bias) = self.linear(l);
            let d_out = &d_acts[i + 1];
            if let Some(j) = l.skip {
                let m = mode(&mut written, j);
                steps.run(binary_backward(
                    gpu,
                    Binary::Add,
                    d_out,
                    d_out,
                    &d_acts[j],
                    m,
                ))?;
            }
            let dz = match l.activation {
                Some(act) => {
                    let dz = gpu.zeros(
                        &format!("{}.dz", l.name),
                        &[self.batch, l.outputs],
                        DType::F32,
                    )?;
                    let saved = if act.backward_uses_output() {
                        &self.acts[i + 1]
                    } else {
                        &self.pre[i]
                    };
                    steps.run(unary_backward(
                        gpu,
                        act,
                        saved,
                        d_out,
                        &dz,
                        Accumulate::Overwrite,
                    ))?;
                    dz
                }
                None => d_out.clone(),
            };
            steps.run(bias.backward(
                gpu,
                &dz,
                table.grad(&format!("{}.bias", l.name)),
                Accumulate::Overwrite,
            ))?;
            steps.run(mm.backward_b(
                gpu,
                &self.acts[i],
                &dz,
                table.grad(&format!("{}.weight", l.name)),
                Accumulate::Overwrite,
            ))?;
            let m = mode(&mut written, i);
            steps.run(mm.backward_a(
                gpu,
                table.param(&format!("{}.weight", l.name)),
                &dz,
                &d_acts[i],
                m,
            ))?;
        }
        if let Some(s) = &self.selection {
            steps.run(self.selector().backward_a(
                gpu,
                s,
                &d_acts[0],
                &self.last_grad,
                Accumulate::Overwrite,
            ))?;
        }
        steps.run(self.gather().backward(gpu, &self.last_grad, input_grad))?;
        Ok(())
    }
}
