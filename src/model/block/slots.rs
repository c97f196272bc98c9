//! Where each block's tensors sit in the parameter list (`param_specs` order), so that the
//! training path reads the weights and writes the gradients in place, without copies.

use crate::model::config::ModelConfig;
use crate::model::error::ModelError;
use crate::model::params::ParamSpec;

/// The parameter indices of one ST block.
pub(crate) struct BlockSlots {
    /// `[U1, U2, U3, be, Ve]` of the temporal attention and `[W1, W2, W3, bs, Vs]` of the
    /// spatial one, when the variant attends.
    pub temporal: Option<[usize; 5]>,
    pub spatial: Option<[usize; 5]>,
    /// `gwc.theta` (`None` in `st-gat`, whose step 3 is [`BlockSlots::gat`]).
    pub theta: Option<usize>,
    /// `gwc.W` `[C_in, C]` (`gat.W` in `st-gat`).
    pub w: usize,
    /// `st-gat`'s graph attention in place of Ψ.
    pub gat: Option<GatShape>,
    /// `tcn.filter.weight` `[C, C·K]` and its bias.
    pub filter: (usize, usize),
    /// `tcn.gate.weight` and bias (`None` in `iastgcn-t`).
    pub gate: Option<(usize, usize)>,
    /// `res.weight` `[C, C_in]` and `res.bias`.
    pub res: (usize, usize),
    pub gamma: usize,
    pub beta: usize,
    pub c_in: usize,
    pub dilation: usize,
}

/// Every block's slots and the head's.
pub(crate) struct Slots {
    pub blocks: Vec<BlockSlots>,
    pub head_weight: usize,
    pub head_bias: usize,
}

impl Slots {
    /// Looks up every tensor of `config` in `specs`; an error names a missing one.
    pub fn new(config: &ModelConfig, specs: &[ParamSpec]) -> Result<Slots, ModelError> {
        let find = |name: String| {
            specs
                .iter()
                .position(|s| s.name == name)
                .ok_or_else(|| ModelError::Config(format!("the parameters lack {name}")))
        };
        let mut blocks = Vec::with_capacity(config.blocks);
        for l in 0..config.blocks {
            let p = |s: &str| find(format!("blocks.{l}.{s}"));
            let five = |names: [&str; 5]| -> Result<[usize; 5], ModelError> {
                Ok([
                    p(names[0])?,
                    p(names[1])?,
                    p(names[2])?,
                    p(names[3])?,
                    p(names[4])?,
                ])
            };
            let attention = config.variant.attention();
            let gat = config.variant.graph_attention();
            let w = if gat { p("gat.W")? } else { p("gwc.W")? };
            blocks.push(BlockSlots {
                temporal: if attention {
                    Some(five(["tat.U1", "tat.U2", "tat.U3", "tat.be", "tat.Ve"])?)
                } else {
                    None
                },
                spatial: if attention {
                    Some(five(["sat.W1", "sat.W2", "sat.W3", "sat.bs", "sat.Vs"])?)
                } else {
                    None
                },
                theta: if gat { None } else { Some(p("gwc.theta")?) },
                w,
                gat: if gat {
                    Some(GatShape {
                        nodes: config.nodes,
                        c_in: config.block_input(l),
                        channels: config.channels,
                        steps: config.window,
                        heads: config.heads,
                        w,
                        a_src: p("gat.a_src")?,
                        a_dst: p("gat.a_dst")?,
                    })
                } else {
                    None
                },
                filter: (p("tcn.filter.weight")?, p("tcn.filter.bias")?),
                gate: if config.variant.gated() {
                    Some((p("tcn.gate.weight")?, p("tcn.gate.bias")?))
                } else {
                    None
                },
                res: (p("res.weight")?, p("res.bias")?),
                gamma: p("ln.gamma")?,
                beta: p("ln.beta")?,
                c_in: config.block_input(l),
                dilation: config.dilation(l),
            });
        }
        Ok(Slots {
            blocks,
            head_weight: find("head.weight".into())?,
            head_bias: find("head.bias".into())?,
        })
    }
}

/// The block's shapes and where its weights are.
#[derive(Clone, Copy)]
pub(crate) struct GatShape {
    pub nodes: usize,
    pub c_in: usize,
    pub channels: usize,
    pub steps: usize,
    pub heads: usize,
    /// `gat.W` `[C_in, C]`, `gat.a_src` and `gat.a_dst` `[C]` in the parameter list.
    pub w: usize,
    pub a_src: usize,
    pub a_dst: usize,
}
