//! One ST block on the device (docs/model.md steps 1–7): its activation buffers and the
//! shape of every op it runs, and the steps as named methods, one file per step holding
//! its `_forward` and its `_backward` side by side (as the native block,
//! `model::native::block`, does). [`Block::forward`] (`forward.rs`) calls the steps in
//! order and [`Block::backward`] (`backward.rs`) the same list reversed, each backward
//! step taking the gradient the later step left and returning what the earlier one needs
//! (its buffers from `Scratch`).
//!
//! | step | docs/model.md | native step |
//! |---|---|---|
//! | `temporal_attention` | 1: E' and X_t = X·(E' + I) | the same |
//! | `spatial_attention` | 2: S'; backward: dX_t, Qᵀ·dM (step 3's term) added last | S'; dX_t without Qᵀ·dM |
//! | `graph_conv` | 3: Ψ, Q = Ψ·(I + S'), M = Q·X_t, Z = ReLU(Wᵀ·M); backward from dG, past Z's ReLU | the same, backward from dZ |
//! | `graph_attention` | 3 of `st-gat`: Q = Wᵀ·X, α, Z = ReLU(Σ_j α_ij Q_j); backward from dG | inside `graph_conv` |
//! | `gated_dcc` | 4: the unfolding, G_f and G_g with their biases, and H = tanh(G_f) ⊙ σ(G_g) (ReLU(G_f) in `iastgcn-t`); backward to dG, Z's ReLU mask fused into the unfolding's backward | no H (`residual_layer_norm` forms it); backward to dZ |
//! | `residual_layer_norm` | 5–7: A = ReLU(H + R + b) accumulated onto H, then the whole LayerNorm with the dropout of a training step fused into its kernels | 5 and 6 up to the statistics; 6's affine map and 7 in `layer_norm_dropout` |
//!
//! The schedule is the one the single forward and backward functions built before the
//! split: the same ops in the same order on the same buffers. The native block's tests
//! (`model::native::block::tests`) run each step here too, against the same f64
//! reference values as the native step.

mod backward;
mod forward;
mod gated_dcc;
mod graph_attention;
mod graph_conv;
mod residual_layer_norm;
mod spatial_attention;
mod temporal_attention;

use super::config::ModelConfig;
use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::ops::bias::Bias;
use crate::ops::dropout::Dropout;
use crate::ops::gated_dcc::Unfold;
use crate::ops::graph_attention::GraphAttention;
use crate::ops::head::LastStep;
use crate::ops::layer_norm::LayerNorm;
use crate::ops::matmul::Matmul;
use crate::ops::outer::{OuterPair, Second};
use crate::ops::softmax::Softmax;

/// A pass through the network: which schedules a network is built with
/// ([`Network::built_for`](crate::model::Network::built_for)), and which one
/// [`Network::profile`](crate::model::Network::profile) times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pass {
    /// The inference forward.
    Inference,
    /// The training forward, the loss and the backward.
    Train,
}

/// Device parameters and their gradients, looked up by docs/model.md name.
pub trait ParamTable {
    fn param(&self, name: &str) -> &Tensor;
    fn grad(&self, name: &str) -> &Tensor;
}

/// Which steps a block computes its convolution, residual, norm and dropout for (the
/// attention and the graph convolution always run on all T steps, which the attention
/// needs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Extent {
    /// All T steps: the output is `[B, N, C, T]` (every block but the last).
    Window,
    /// The last step only, which is all the head reads: the output is `[B, N, C, 1]`,
    /// the same values as the last step of the whole computation (the last block).
    LastStep,
}

/// The shapes of one block.
#[derive(Clone, Copy, Debug)]
struct Dims {
    b: usize,
    n: usize,
    ci: usize,
    c: usize,
    t: usize,
    /// Steps the block computes its convolution, residual, norm and dropout for: T, or 1
    /// for the last block (the head reads only its last step).
    to: usize,
    k: usize,
    terms: usize,
}

/// Temporal-attention intermediates (step 1).
struct Temporal {
    xu1: Tensor,
    lhs: Tensor,
    rhs: Tensor,
    /// σ(lhs·rhs + be): the scores, bias and sigmoid applied in the product's epilogue.
    sig: Tensor,
    e: Tensor,
    ep: Tensor,
}

/// Spatial-attention intermediates (step 2).
struct Spatial {
    xt: Tensor,
    xw1: Tensor,
    lhs: Tensor,
    rhs: Tensor,
    /// σ(lhs·rhsᵀ + bs), as in the temporal attention.
    sig: Tensor,
    s: Tensor,
    sp: Tensor,
    /// Q[b] = Ψ·(I + S'[b]): the spatial attention and the graph mix in one matrix, so
    /// that M = Ψ·X_s = Q·X_t takes one small-K product instead of two.
    q: Tensor,
}

/// The graph attention of `st-gat` (step 3 in place of the graph convolution).
struct GatBuffers {
    /// Q = Wᵀ·X over channels `[B, N, C, T]`.
    q: Tensor,
    /// α `[B, T, heads, N, N]`.
    alpha: Tensor,
    /// The aggregate Σ_j α_ij q_j before its ReLU `[B, N, C, T]`.
    g: Tensor,
    heads: usize,
}

/// One block's buffers: everything its backward pass reads.
pub struct Block {
    index: usize,
    d: Dims,
    gated: bool,
    dilation: usize,
    eps: f32,
    dropout: Dropout,
    input: Tensor,
    tat: Option<Temporal>,
    sat: Option<Spatial>,
    /// `st-gat` only.
    gat: Option<GatBuffers>,
    psi: Tensor,
    m: Tensor,
    /// ReLU(G): the graph convolution's product applies it in its epilogue.
    z: Tensor,
    col: Tensor,
    f: Tensor,
    gg: Tensor,
    /// H, then ReLU(H + R + bias) once the residual product has accumulated onto it.
    s: Tensor,
    mean: Tensor,
    rstd: Tensor,
    /// The input's last step `[B, N, C_in]`, for the residual of a trimmed block.
    x_last: Option<Tensor>,
    /// `[tcn.filter.weight; tcn.gate.weight]` as one `[2C, C·K]` matrix (gated variants),
    /// copied in each backward pass: the two convolutions' backward is one product.
    w_fg: Option<Tensor>,
    /// The block output `[B, N, C, to]`: LayerNorm's, through the dropout in training.
    pub output: Tensor,
}

/// A dispatch that reads the dropout's mask: the LayerNorm it was built from (with the
/// fused dropout) and its index in its schedule, so that its mask can follow the
/// training step ([`LayerNorm::set_step`]).
#[derive(Clone, Copy, Debug)]
pub struct MaskedStep {
    pub layer_norm: LayerNorm,
    pub index: usize,
}

/// A block's dispatches that read the dropout's mask: the forward's LayerNorm, and the
/// backward's input and parameter gradients.
pub struct DropoutSlots {
    pub forward: MaskedStep,
    pub backward: [MaskedStep; 2],
}

impl Block {
    /// Allocates the buffers of block `index` reading `input` [B, N, C_in, T]. A block
    /// of [`Extent::LastStep`] (the last one) is *trimmed*: it computes steps 4–7 only
    /// at the last step, which is all the head reads.
    pub fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        index: usize,
        batch: usize,
        input: &Tensor,
        dropout_seed: u32,
        extent: Extent,
    ) -> Result<Block, GpuError> {
        let trimmed = extent == Extent::LastStep;
        let d = Dims {
            b: batch,
            n: config.nodes,
            ci: config.block_input(index),
            c: config.channels,
            t: config.window,
            to: if trimmed { 1 } else { config.window },
            k: config.kernel,
            terms: config.graph_terms(),
        };
        let name = |s: &str| format!("blocks.{index}.{s}");
        let z = |s: &str, shape: &[usize]| gpu.zeros(&name(s), shape, DType::F32);
        let (b, n, ci, c, t) = (d.b, d.n, d.ci, d.c, d.t);
        let (tat, sat) = if config.variant.attention() {
            let tat = Temporal {
                xu1: z("tat.xu1", &[b, ci, t])?,
                lhs: z("tat.lhs", &[b, t, n])?,
                rhs: z("tat.rhs", &[b, n, t])?,
                sig: z("tat.sig", &[b, t, t])?,
                e: z("tat.E", &[b, t, t])?,
                ep: z("tat.E'", &[b, t, t])?,
            };
            let sat = Spatial {
                xt: z("X_t", &[b, n, ci, t])?,
                xw1: z("sat.xw1", &[b, n, ci])?,
                lhs: z("sat.lhs", &[b, n, t])?,
                rhs: z("sat.rhs", &[b, n, t])?,
                sig: z("sat.sig", &[b, n, n])?,
                s: z("sat.S", &[b, n, n])?,
                sp: z("sat.S'", &[b, n, n])?,
                q: z("gwc.Q", &[b, n, n])?,
            };
            (Some(tat), Some(sat))
        } else {
            (None, None)
        };
        let hidden = [b, n, c, t];
        let out = [b, n, c, d.to];
        let gat = if config.variant.graph_attention() {
            Some(GatBuffers {
                q: z("gat.Q", &hidden)?,
                alpha: z("gat.alpha", &[b, t, config.heads, n, n])?,
                g: z("gat.G", &hidden)?,
                heads: config.heads,
            })
        } else {
            None
        };
        let whole = Dropout::new(
            hidden.iter().product(),
            config.dropout,
            dropout_seed.wrapping_add(index as u32),
        );
        Ok(Block {
            index,
            d,
            gated: config.variant.gated(),
            dilation: config.dilation(index),
            eps: config.eps as f32,
            // Element (b, n, c) of a trimmed block is element (b, n, c, T − 1) of the whole.
            dropout: if trimmed {
                whole.strided(b * n * c, t, t - 1)
            } else {
                whole
            },
            input: input.clone(),
            tat,
            sat,
            gat,
            psi: z("gwc.Psi", &[n, n])?,
            m: z("gwc.M", &[b, n, ci, t])?,
            z: z("Z", &hidden)?,
            col: z("tcn.col", &[b, n, c, d.k, d.to])?,
            f: z("tcn.G_f", &out)?,
            gg: z("tcn.G_g", &out)?,
            s: z("relu(H+R)", &out)?,
            mean: z("ln.mean", &[b * n * d.to])?,
            rstd: z("ln.rstd", &[b * n * d.to])?,
            x_last: trimmed.then(|| z("x_last", &[b, n, ci])).transpose()?,
            w_fg: config
                .variant
                .gated()
                .then(|| z("tcn.W_fg", &[2 * c, c * d.k]))
                .transpose()?,
            output: z("output", &out)?,
        })
    }

    fn name(&self, s: &str) -> String {
        format!("blocks.{}.{s}", self.index)
    }

    // The products of docs/model.md, named by what they compute.

    /// tat: xu1[b, (c,t)] = Σ_n U1[n] X[b, n, (c,t)].
    fn mm_u1(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.ci * d.t, d.n).batched(d.b).share_a(true)
    }
    /// tat: lhs[b] = xu1[b]ᵀ [T, C_in] · U2 [C_in, N].
    fn mm_u2(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.t, d.n, d.ci)
            .batched(d.b)
            .transpose_a(true)
            .share_b(true)
    }
    /// tat: rhs[b, n] = U3 [1, C_in] · X[b, n] [C_in, T].
    fn mm_u3(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.t, d.ci).batched(d.b * d.n).share_a(true)
    }
    /// tat: P[b] = lhs[b] [T, N] · rhs[b] [N, T].
    fn mm_tp(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.t, d.t, d.n).batched(d.b)
    }
    /// tat: E[b] = Ve · σ(P + be)[b].
    fn mm_ve(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.t, d.t, d.t).batched(d.b).share_a(true)
    }
    /// tat: X_t[b] = X[b] [N·C_in, T] · (E'[b] [T, T] + I), the identity's term (X) added
    /// in the product's epilogue (and dX_t in that of dX).
    fn mm_xt(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n * d.ci, d.t, d.t)
            .batched(d.b)
            .plus_identity(true)
    }
    /// sat: xw1[(b,n,c)] = X_t[(b,n,c), :] · W1.
    fn mm_w1(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.b * d.n * d.ci, 1, d.t)
    }
    /// sat: lhs[(b,n)] = xw1[(b,n), :] · W2 [C_in, T].
    fn mm_w2(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.b * d.n, d.t, d.ci)
    }
    /// sat: rhs[b, m] = W3 [1, C_in] · X_t[b, m] [C_in, T] (stored [B, N, T]).
    fn mm_w3(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.t, d.ci).batched(d.b * d.n).share_a(true)
    }
    /// sat: P[b] = lhs[b] [N, T] · rhs[b]ᵀ.
    fn mm_sp(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.n, d.t).batched(d.b).transpose_b(true)
    }
    /// sat: S[b] = Vs · σ(P + bs)[b].
    fn mm_vs(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.n, d.n).batched(d.b).share_a(true)
    }
    /// sat + gwc: Q[b] = Ψ [N, N] · S'[b] [N, N] (+ Ψ, in the epilogue).
    fn mm_q(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.n, d.n).batched(d.b).share_a(true)
    }
    /// gwc with attention: M[b] = Q[b] [N, N] · X_t[b] [N, C_in·T].
    fn mm_qx(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.ci * d.t, d.n).batched(d.b)
    }
    /// The input gradient of an attention's two rank-1 projections (W3, W1 on X_t or U3,
    /// U1 on X), over `[B·N, C_in, T]`.
    fn rank_one_pair(&self, second: Second) -> OuterPair {
        let d = self.d;
        OuterPair {
            items: d.b * d.n,
            rows: d.ci,
            cols: d.t,
            second,
        }
    }
    /// The batch sum of dQ, the gradient of Ψ's direct term in Q = Ψ + Ψ·S'.
    fn batch_sum_nn(&self) -> Bias {
        Bias {
            outer: self.d.b,
            channels: self.d.n * self.d.n,
            inner: 1,
        }
    }
    /// gwc: Ψ [1, N·N] = θ [1, terms] · basis [terms, N·N].
    fn mm_psi(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.n * d.n, d.terms)
    }
    /// gwc without attention: M[b] = Ψ [N, N] · X[b] [N, C_in·T].
    fn mm_mix(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.ci * d.t, d.n).batched(d.b).share_a(true)
    }
    /// gwc: G[b, n] = Wᵀ [C, C_in] · M[b, n] [C_in, T] (W stored [C_in, C]).
    fn mm_w(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.c, d.t, d.ci)
            .batched(d.b * d.n)
            .transpose_a(true)
            .share_a(true)
    }
    /// `st-gat`'s graph attention over the block's hidden tensor.
    fn graph_attention(&self, heads: usize) -> GraphAttention {
        let d = self.d;
        GraphAttention {
            batch: d.b,
            nodes: d.n,
            channels: d.c,
            steps: d.t,
            heads,
        }
    }
    /// tcn: G[b, n] = weight [C, C·K] · col[b, n] [C·K, T].
    fn mm_conv(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.c, d.to, d.c * d.k)
            .batched(d.b * d.n)
            .share_a(true)
    }
    /// res: R[b, n] = res.weight [C, C_in] · X[b, n] [C_in, T].
    fn mm_res(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.c, d.to, d.ci)
            .batched(d.b * d.n)
            .share_a(true)
    }

    /// tcn backward, filter and gate stacked: [dG_f; dG_g][b, n] [2C, to] from
    /// [W_f; W_g] [2C, C·K] · col[b, n] [C·K, to].
    fn mm_conv_fg(&self) -> Matmul {
        let d = self.d;
        Matmul::new(2 * d.c, d.to, d.c * d.k)
            .batched(d.b * d.n)
            .share_a(true)
    }

    /// The input's last step, read by the residual of a trimmed block.
    fn input_last_step(&self) -> LastStep {
        let d = self.d;
        LastStep {
            rows: d.b * d.n * d.ci,
            steps: d.t,
        }
    }

    fn unfold(&self) -> Unfold {
        let d = self.d;
        Unfold {
            rows: d.b * d.n,
            channels: d.c,
            kernel: d.k,
            steps: d.t,
            dilation: self.dilation,
            outputs: d.to,
        }
    }

    fn channel_bias(&self) -> Bias {
        let d = self.d;
        Bias {
            outer: d.b * d.n,
            channels: d.c,
            inner: d.to,
        }
    }

    /// tat: be [T, T] added to P over the batch.
    fn temporal_score_bias(&self) -> Bias {
        Bias {
            outer: self.d.b,
            channels: self.d.t * self.d.t,
            inner: 1,
        }
    }

    /// sat: bs [N, N] added to P over the batch.
    fn spatial_score_bias(&self) -> Bias {
        Bias {
            outer: self.d.b,
            channels: self.d.n * self.d.n,
            inner: 1,
        }
    }

    fn layer_norm(&self) -> LayerNorm {
        let d = self.d;
        LayerNorm {
            eps: self.eps,
            ..LayerNorm::new(d.b * d.n, d.c, d.to)
        }
    }

    /// The LayerNorm of a training step: the dropout fused in.
    pub(crate) fn layer_norm_dropout(&self) -> LayerNorm {
        LayerNorm {
            dropout: Some(self.dropout),
            ..self.layer_norm()
        }
    }

    fn temporal_softmax(&self) -> Softmax {
        Softmax {
            outer: self.d.b,
            len: self.d.t,
            inner: self.d.t,
        }
    }

    fn spatial_softmax(&self) -> Softmax {
        Softmax {
            outer: self.d.b * self.d.n,
            len: self.d.n,
            inner: 1,
        }
    }

    /// A buffer the steps read or write, by its role, for the tests that run one step
    /// alone (`model::native::block::tests`): `input`, `E'`, `X_t`, `S'`, `Psi`, `Z`,
    /// `G_f`, `G_g`, `H` (then A = ReLU(H + R + b)), `output`.
    #[cfg(test)]
    pub(crate) fn buffer(&self, role: &str) -> &Tensor {
        // invariant: test support: an attention buffer is asked for only in a variant with it.
        let attention = || self.sat.as_ref().expect("the variant attends");
        match role {
            "input" => &self.input,
            "E'" => &self.tat.as_ref().expect("the variant attends").ep,
            "X_t" => &attention().xt,
            "S'" => &attention().sp,
            "Psi" => &self.psi,
            "Z" => &self.z,
            "G_f" => &self.f,
            "G_g" => &self.gg,
            "H" => &self.s,
            "output" => &self.output,
            _ => panic!("no block buffer {role}"),
        }
    }
}
