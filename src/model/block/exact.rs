//! One ST block in the f64 reference: its shapes and its parameters, which the steps'
//! references (`reference.rs` of each step's folder) read, and the channel mix
//! Q = X_s·W that the graph convolution and `st-gat`'s graph attention share.

use crate::model::exact::{axpy, dot, row, row_mut, Grads, Table};
use crate::model::ModelConfig;

/// Shapes of block `l`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Dims {
    pub(crate) b: usize,
    pub(crate) n: usize,
    /// C_in.
    pub(crate) ci: usize,
    pub(crate) c: usize,
    pub(crate) t: usize,
}

impl Dims {
    pub(crate) fn new(config: &ModelConfig, batch: usize, l: usize) -> Dims {
        Dims {
            b: batch,
            n: config.nodes,
            ci: config.block_input(l),
            c: config.channels,
            t: config.window,
        }
    }

    /// Index of the T-row (b, n, c) of a `[B,N,ch,T]` tensor.
    #[inline]
    pub(crate) fn r(&self, ch: usize, b: usize, n: usize, c: usize) -> usize {
        (b * self.n + n) * ch + c
    }
}

/// The parameters of block `l`.
pub(crate) struct BlockParams<'a> {
    pub(crate) prefix: String,
    /// The whole table, for the steps that look up their own parameters
    /// ([`BlockParams::get`]).
    table: Table<'a>,
    /// θ of the graph convolution (empty in `st-gat`).
    pub(crate) theta: &'a [f64],
    /// The channel mix W of step 3 (`gwc.W`, or `gat.W` in `st-gat`).
    pub(crate) w: &'a [f64],
    /// (a_src, a_dst) of `st-gat`'s graph attention.
    pub(crate) attention_vectors: Option<(&'a [f64], &'a [f64])>,
    pub(crate) filter_weight: &'a [f64],
    pub(crate) filter_bias: &'a [f64],
    /// (weight, bias) of the gate; `None` in `iastgcn-t`.
    pub(crate) gate: Option<(&'a [f64], &'a [f64])>,
    pub(crate) res_weight: &'a [f64],
    pub(crate) res_bias: &'a [f64],
    pub(crate) gamma: &'a [f64],
    pub(crate) beta: &'a [f64],
}

impl<'a> BlockParams<'a> {
    pub(crate) fn new(table: &Table<'a>, config: &ModelConfig, l: usize) -> BlockParams<'a> {
        let prefix = format!("blocks.{l}");
        let p = |s: &str| table.get(&format!("{prefix}.{s}"));
        let gat = config.variant.graph_attention();
        BlockParams {
            table: *table,
            theta: if gat { &[] } else { p("gwc.theta") },
            w: p(if gat { "gat.W" } else { "gwc.W" }),
            attention_vectors: gat.then(|| (p("gat.a_src"), p("gat.a_dst"))),
            filter_weight: p("tcn.filter.weight"),
            filter_bias: p("tcn.filter.bias"),
            gate: config
                .variant
                .gated()
                .then(|| (p("tcn.gate.weight"), p("tcn.gate.bias"))),
            res_weight: p("res.weight"),
            res_bias: p("res.bias"),
            gamma: p("ln.gamma"),
            beta: p("ln.beta"),
            prefix,
        }
    }

    /// The parameter `blocks.{l}.{s}`.
    pub(crate) fn get(&self, s: &str) -> &'a [f64] {
        self.table.get(&self.name(s))
    }

    pub(crate) fn name(&self, s: &str) -> String {
        format!("{}.{s}", self.prefix)
    }
}

/// Q = X_s·W over channels: `Q[b,j,o,t] = Σ_c X_s[b,j,c,t]·W[c,o]`.
pub(crate) fn channel_mix(d: &Dims, w: &[f64], xs: &[f64]) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut q = vec![0.0; nb * nn * nc * nt];
    for b in 0..nb {
        for j in 0..nn {
            for o in 0..nc {
                let qr = row_mut(&mut q, d.r(nc, b, j, o), nt);
                for c in 0..ci {
                    axpy(qr, w[c * nc + o], row(xs, d.r(ci, b, j, c), nt));
                }
            }
        }
    }
    q
}

/// Backward of [`channel_mix`] from dQ: returns dL/dX_s and adds dW to `grads`.
pub(crate) fn channel_mix_backward(
    d: &Dims,
    p: &BlockParams,
    xs: &[f64],
    dq: &[f64],
    grads: &mut Grads,
    name: &str,
) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut dw = vec![0.0; ci * nc];
    let mut dxs = vec![0.0; xs.len()];
    for b in 0..nb {
        for j in 0..nn {
            for o in 0..nc {
                let gr = row(dq, d.r(nc, b, j, o), nt);
                for c in 0..ci {
                    let r = d.r(ci, b, j, c);
                    dw[c * nc + o] += dot(row(xs, r, nt), gr);
                    axpy(row_mut(&mut dxs, r, nt), p.w[c * nc + o], gr);
                }
            }
        }
    }
    grads.add(&p.name(name), &dw);
    dxs
}
