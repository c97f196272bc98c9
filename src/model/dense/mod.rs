//! The dense baselines (docs/model.md "Baselines"): the instantaneous MLP and the three
//! offline pose→error models of Table V. Each reads only the window's last step (so no
//! history), picks its inputs from it, and runs a chain of fully connected layers into
//! the same head and loss as IASTGCN. Every layer is existing ops: the last-step gather of
//! the head, a matmul, a bias and an activation; a skip connection is a copy that the
//! matmul then accumulates onto.
//!
//! This folder holds all of it: the architectures here, the device schedule in
//! `wgsl.rs`, the f64 reference in `reference.rs`, the native f32 forward and backward in
//! `native.rs` (tested in tests/model_dense.rs and tests/native_*.rs).

pub(crate) mod native;
pub mod reference;
pub(crate) mod wgsl;

use super::config::{ModelConfig, Variant};
use crate::graph::Graph;
use crate::ops::elementwise::Unary;

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
