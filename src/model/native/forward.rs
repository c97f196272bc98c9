//! The inference forward pass of the IASTGCN variants, the dense and the recurrent
//! baselines, one window at a time (see the module above): the training forward of
//! `block/` (or `dense.rs`, `recurrent.rs`) without dropout, on a tape that is allocated
//! once and reused window after window.

use crate::model::block::native::forward;
use crate::model::block::slots::Slots;
use crate::model::block::tape::Tape;
use crate::model::conv_lstm::native::{ConvLstmNet, ConvLstmTape};
use crate::model::cpu::flushing_subnormals;
use crate::model::cpu::{with_products, Products};
use crate::model::dense::native::{DenseNet, DenseTape};
use crate::model::recurrent::native::{RecurrentNet, RecurrentTape};

use crate::graph::Graph;
use crate::model::config::{Family, ModelConfig};
use crate::model::error::ModelError;
use crate::model::params::{graph_basis, param_specs, Parameters};

/// The CPU forward pass of one checkpoint of an IASTGCN variant (`iastgcn`, `iastgcn-a`,
/// `iastgcn-t`, `iastgcn-s`), a dense baseline (`mlp`, `bkls-ann`, `ann-bfpa`, `erc`) or
/// a recurrent baseline (`tgcn`, `eat-gcn`, `convlstm`) for one window at a time.
pub struct NativeForward {
    config: ModelConfig,
    /// The weights in `param_specs` order.
    params: Vec<Vec<f32>>,
    body: Body,
    /// The tasks one window is split into ([`NativeForward::set_threads`]).
    threads: usize,
}

/// What the network is built from, with the working memory of one window.
enum Body {
    /// ST blocks: `[terms, N, N]` (f32 of [`graph_basis`]), the tensors' slots, and every
    /// intermediate of one window.
    Blocks {
        basis: Vec<f32>,
        slots: Slots,
        tape: Box<Tape>,
    },
    /// Dense layers on the last step.
    Dense { net: DenseNet, tape: DenseTape },
    /// A graph-convolutional GRU over the steps.
    Recurrent {
        net: RecurrentNet,
        tape: Box<RecurrentTape>,
    },
    /// ConvLSTM over the steps.
    ConvLstm {
        net: ConvLstmNet,
        tape: Box<ConvLstmTape>,
    },
}

impl NativeForward {
    /// Copies the weights and sizes the working memory; the only allocations.
    pub fn new(
        config: &ModelConfig,
        graph: &Graph,
        params: &Parameters,
    ) -> Result<NativeForward, ModelError> {
        config.validate().map_err(ModelError::Config)?;
        let specs = param_specs(config);
        let values = values_in_spec_order(&specs, params)?;
        let body = if config.variant.family() == Family::Dense {
            let net = DenseNet::new(config, graph, &specs)?;
            Body::Dense {
                tape: net.tape(),
                net,
            }
        } else if config.variant.family() == Family::Recurrent {
            let net = RecurrentNet::new(config, graph, &specs)?;
            Body::Recurrent {
                tape: Box::new(net.tape(1)),
                net,
            }
        } else if config.variant.family() == Family::ConvRecurrent {
            let net = ConvLstmNet::new(config, &specs)?;
            Body::ConvLstm {
                tape: Box::new(net.tape()),
                net,
            }
        } else {
            let slots = Slots::new(config, &specs)?;
            Body::Blocks {
                basis: graph_basis(graph, config)
                    .iter()
                    .map(|&v| v as f32)
                    .collect(),
                tape: Box::new(Tape::new(config, &slots)),
                slots,
            }
        };
        Ok(NativeForward {
            body,
            params: values,
            config: config.clone(),
            threads: 1,
        })
    }

    /// Replaces the weights with `params` (same variant and shapes), keeping the working
    /// memory and the graph basis: cheaper than a new [`NativeForward`] where the
    /// weights change often (validation after every training epoch).
    pub fn set_parameters(&mut self, params: &Parameters) -> Result<(), ModelError> {
        self.params = values_in_spec_order(&param_specs(&self.config), params)?;
        Ok(())
    }

    /// Splits each window's large products (the gated convolution and X·E', in tasks of
    /// at least 2^19 multiply-adds) and its per-node loops (Z = ReLU(Wᵀ·M), the residual,
    /// gating and LayerNorm) into at most `threads` tasks on rayon's global pool; 1 (the
    /// default) runs on the calling thread alone. Small networks (the demo's C = 16) stay
    /// on one thread whatever is asked, where a task would cost more than it saves. The
    /// outputs do not depend on it: each value is the same sum in the same order. The
    /// baselines always run on one thread.
    pub fn set_threads(&mut self, threads: usize) {
        let threads = threads.max(1);
        if let Body::Blocks { tape, .. } = &mut self.body {
            tape.threads = threads;
        }
        self.threads = threads;
    }

    /// The threads one window is split over ([`NativeForward::set_threads`]).
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The network's shapes and variant.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// ŷ `[O]` (standardised label space) of one standardised window `x` `[N, F, T]`.
    pub fn forward(&mut self, x: &[f32], out: &mut [f32]) -> Result<(), ModelError> {
        let cfg = &self.config;
        let (n, f, t) = (cfg.nodes, cfg.features, cfg.window);
        if x.len() != n * f * t || out.len() != cfg.outputs {
            return Err(ModelError::Config(format!(
                "native forward: x has {} floats (expected N·F·T = {}), out {} (expected {})",
                x.len(),
                n * f * t,
                out.len(),
                cfg.outputs
            )));
        }
        flushing_subnormals(|| with_products(Products::InPlace, || self.run(x, out)));
        Ok(())
    }

    /// [`NativeForward::forward`] after its checks.
    fn run(&mut self, x: &[f32], out: &mut [f32]) {
        let cfg = &self.config;
        match &mut self.body {
            Body::Blocks { basis, slots, tape } => {
                forward(cfg, basis, slots, &self.params, x, None, tape);
                out.copy_from_slice(&tape.out);
            }
            Body::Dense { net, tape } => {
                net.forward(&self.params, x, tape);
                out.copy_from_slice(tape.output());
            }
            Body::Recurrent { net, tape } => {
                net.forward(&self.params, x, tape);
                out.copy_from_slice(tape.output());
            }
            Body::ConvLstm { net, tape } => {
                net.forward(&self.params, x, tape);
                out.copy_from_slice(tape.output());
            }
        }
    }
}

/// `params`' tensors in the order of `specs`, each checked against its shape.
fn values_in_spec_order(
    specs: &[crate::model::ParamSpec],
    params: &Parameters,
) -> Result<Vec<Vec<f32>>, ModelError> {
    specs
        .iter()
        .map(|spec| {
            let i = params
                .index(&spec.name)
                .ok_or_else(|| ModelError::Config(format!("the parameters lack {}", spec.name)))?;
            if params.values[i].len() != spec.numel() {
                return Err(ModelError::Config(format!(
                    "{} has {} values; the config's shape {:?} needs {}",
                    spec.name,
                    params.values[i].len(),
                    spec.shape,
                    spec.numel()
                )));
            }
            Ok(params.values[i].clone())
        })
        .collect()
}
