//! The ST blocks of the IASTGCN variants and ST-GAT on the CPU in f32, one window at a
//! time: [`forward`] and [`backward`] (the network's blocks and head), and one block's
//! call list, [`forward_block`] calling each step's `<step>_forward` (in the step's
//! `native.rs`) in order and [`backward_block`] the same list reversed.
//!
//! The forward keeps on a [`Tape`] everything the backward reads (`tape.rs`, with the
//! backward's working memory [`Work`]). The order is the device's: X_t =
//! X·(E' + I), Q = Ψ·(I + S'), M = Q·X_t, Z = ReLU(Wᵀ·M) per node, and in the last block
//! steps 4–7 at the last time step only (the one the head reads; its dropout bits are the
//! ones that step has in the whole tensor). Beyond the device, the last block computes
//! X_t, M and Z only at the K steps its convolution reads there (`tape::Cols`), and its
//! spatial attention is taken from X and E' instead of X_t (the same sums: X_t·W1 =
//! X·((I + E')·W1), W3ᵀ·X_t[m] = (W3ᵀ·X[m])·(I + E')). The backward is the same algebra
//! as the f64 reference, with every contraction a `gemm` product.
//!
//! Every step function is compiled for AVX-512 and AVX2/FMA besides baseline x86-64 and
//! chosen at its first call (`multiversion`), each its own function: the closures inside
//! a step (the per-node loops) get its target features only from the function they are
//! written in, not from one they are inlined into. The steps' methods are thin calls of
//! those functions.

use rayon::prelude::*;

use crate::model::block::residual_layer_norm::dropout_kernel::Dropout;
use crate::model::block::slots::{BlockSlots, Slots};
use crate::model::block::tape::{BlockTape, Masks, Tape, Work};
use crate::model::config::ModelConfig;
use crate::model::cpu::{flushing_subnormals, gemm, rows, transposed, PAR_MIN_MACS};
use crate::model::head;
use multiversion::multiversion;

/// What every step of one block reads besides the tensors: its shapes, its tensor slots
/// and the graph basis `[terms, N, N]` (`st-gat`: its edges). The parameters (in
/// `param_specs` order) and the block input X `[N, C_in, T]` are the steps' own
/// arguments, so that the compiler knows that nothing the steps write changes them (a
/// reference read out of a struct carries no such promise, and the loops that index
/// them then reload them every iteration, and stay scalar).
#[derive(Clone, Copy)]
pub(crate) struct Block<'a> {
    pub(crate) cfg: &'a ModelConfig,
    pub(crate) basis: &'a [f32],
    pub(crate) s: &'a BlockSlots,
    /// Tasks the large products and the per-node loops are split into ([`Tape::threads`];
    /// 1 in the backward, which training runs one window per thread).
    pub(crate) threads: usize,
    pub(crate) n: usize,
    pub(crate) t: usize,
    pub(crate) c: usize,
    pub(crate) k: usize,
    pub(crate) ci: usize,
}

impl<'a> Block<'a> {
    pub(crate) fn new(
        cfg: &'a ModelConfig,
        basis: &'a [f32],
        s: &'a BlockSlots,
        threads: usize,
    ) -> Block<'a> {
        Block {
            cfg,
            basis,
            s,
            threads,
            n: cfg.nodes,
            t: cfg.window,
            c: cfg.channels,
            k: cfg.kernel,
            ci: s.c_in,
        }
    }

    /// The tasks a per-node loop is split into: [`Block::threads`] where a node's
    /// product is worth a task (the paper's C = 64: 410k multiply-adds; the demo's
    /// C = 16: 12k, which stays on one thread), else 1.
    pub(crate) fn node_tasks(&self, node_macs: usize) -> usize {
        if node_macs >= PAR_MIN_MACS / 2 {
            self.threads
        } else {
            1
        }
    }
}

/// The training forward of window `x` `[N, F, T]` into `tape` (`params` in
/// `param_specs` order, `basis` `[terms, N, N]`): the blocks, then the head.
pub(crate) fn forward(
    cfg: &ModelConfig,
    basis: &[f32],
    slots: &Slots,
    params: &[Vec<f32>],
    x: &[f32],
    masks: Option<Masks>,
    tape: &mut Tape,
) {
    let last = slots.blocks.len() - 1;
    let threads = tape.threads;
    tape.dropped = masks.is_some();
    for l in 0..slots.blocks.len() {
        let (done, rest) = tape.blocks.split_at_mut(l);
        let input = if l == 0 { x } else { &done[l - 1].y[..] };
        let mask = masks.map(|m| (m.block(cfg, l), m.step));
        let h = if l == last {
            Some(&mut tape.h[..])
        } else {
            None
        };
        let b = Block::new(cfg, basis, &slots.blocks[l], threads);
        forward_block(&b, params, input, &mut rest[0], mask, h);
    }
    let head = (slots.head_weight, slots.head_bias);
    head::native::forward(params, head, &tape.h, &mut tape.out);
}

/// Adds dL/dθ of one window to `grads` (in `param_specs` order) from `dout` = dL/dŷ
/// `[O]` and the tape of its forward on `x` (its dropout masks too, when it drew them):
/// the head, then the blocks last to first.
#[allow(clippy::too_many_arguments)]
pub(crate) fn backward(
    cfg: &ModelConfig,
    basis: &[f32],
    slots: &Slots,
    p: &[Vec<f32>],
    x: &[f32],
    tape: &Tape,
    dout: &[f32],
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let nc = cfg.nodes * cfg.channels;
    let head = (slots.head_weight, slots.head_bias);
    head::native::backward(p, head, &tape.h, dout, grads, &mut w.dy[..nc]);
    for l in (0..slots.blocks.len()).rev() {
        let input = if l == 0 { x } else { &tape.blocks[l - 1].y[..] };
        let b = Block::new(cfg, basis, &slots.blocks[l], 1);
        backward_block(&b, p, input, &tape.blocks[l], tape.dropped, l > 0, grads, w);
        std::mem::swap(&mut w.dy, &mut w.dx);
    }
}

/// One block on its input `x`: the output goes to `bt.y`, or to `h` in the last block
/// (at its last step); `mask` is the block's dropout and the optimiser step, in training.
fn forward_block(
    b: &Block,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &mut BlockTape,
    mask: Option<((Dropout, usize), u32)>,
    h: Option<&mut [f32]>,
) {
    b.temporal_attention_forward(p, x, bt);
    b.spatial_attention_forward(p, x, bt);
    if b.s.gat.is_some() {
        b.graph_attention_forward(p, x, bt);
    } else {
        b.graph_conv_forward(p, x, bt);
    }
    b.gated_dcc_forward(p, bt);
    b.residual_layer_norm_forward(p, x, bt, mask, h);
}

/// [`forward_block`] backwards: dL/dθ of the block from `w.dy` (`[N, C, steps]`), and
/// dL/dX into `w.dx` when `need_dx`.
#[allow(clippy::too_many_arguments)]
fn backward_block(
    b: &Block,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &BlockTape,
    dropped: bool,
    need_dx: bool,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    b.residual_layer_norm_backward(p, x, bt, dropped, need_dx, grads, w);
    b.gated_dcc_backward(p, bt, grads, w);
    if b.s.gat.is_some() {
        b.graph_attention_backward(p, x, bt, need_dx, grads, w);
    } else {
        b.graph_conv_backward(p, x, bt, need_dx, grads, w);
    }
    b.spatial_attention_backward(p, x, bt, need_dx, grads, w);
    b.temporal_attention_backward(p, x, bt, need_dx, grads, w);
}

/// The score gate S = V·σ(P + bias) of both attentions, backward: from dS (`w.dscore`,
/// `[len, len]`) adds dV and dbias, leaves dP in `w.dsig`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(crate) fn score_gate_backward(
    len: usize,
    v: &[f32],
    sig: &[f32],
    grads: &mut [Vec<f32>],
    iv: usize,
    ib: usize,
    w: &mut Work,
) {
    let ds = &w.dscore[..len * len];
    gemm(
        len,
        len,
        len,
        rows(ds, len),
        transposed(sig, len),
        1.0,
        &mut grads[iv],
        len,
    );
    let dsig = &mut w.dsig[..len * len];
    gemm(
        len,
        len,
        len,
        transposed(v, len),
        rows(ds, len),
        0.0,
        dsig,
        len,
    );
    for ((g, &s), db) in dsig.iter_mut().zip(sig).zip(grads[ib].iter_mut()) {
        *g *= s * (1.0 - s);
        *db += *g;
    }
}

/// `f(i, chunk)` for each node's `size`-long chunk of `data`, in `tasks` rayon tasks of
/// consecutive nodes when `tasks` > 1.
#[inline(always)]
pub(crate) fn for_each_node(
    tasks: usize,
    data: &mut [f32],
    size: usize,
    f: impl Fn(usize, &mut [f32]) + Sync + Send,
) {
    if tasks > 1 {
        let per = (data.len() / size).div_ceil(tasks);
        data.par_chunks_mut(per * size)
            .enumerate()
            .for_each(|(j, group)| {
                flushing_subnormals(|| {
                    for (u, c) in group.chunks_mut(size).enumerate() {
                        f(j * per + u, c);
                    }
                })
            });
    } else {
        for (i, c) in data.chunks_mut(size).enumerate() {
            f(i, c);
        }
    }
}
