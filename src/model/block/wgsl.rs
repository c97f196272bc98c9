//! One ST block on the device: its activation buffers (every step's saved tensors), the
//! shape of every op its steps launch, and the steps' call lists: [`Block::forward`] calls
//! each step's `<step>_forward` (in the step's `wgsl.rs`) in order, [`Block::backward`]
//! each `<step>_backward` in reverse, each backward step taking the gradient the later
//! step left and returning what the earlier one needs (its buffers from `Scratch`). Also
//! [`Table`], the parameters by name that every device network's schedule reads.

use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::model::block::gated_dcc::kernel::Unfold;
use crate::model::block::graph_attention::kernel::GraphAttention;
use crate::model::block::residual_layer_norm::dropout_kernel::Dropout;
use crate::model::block::residual_layer_norm::layer_norm_kernel::LayerNorm;
use crate::model::config::ModelConfig;
use crate::model::params::ParamSpec;
use crate::model::schedule::{ParamTable, Pass, Scratch, Steps};
use crate::ops::bias::Bias;
use crate::ops::head::LastStep;
use crate::ops::matmul::Matmul;
use crate::ops::outer::{OuterPair, Second};
use crate::ops::softmax::Softmax;

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
pub(crate) struct Dims {
    pub(crate) b: usize,
    pub(crate) n: usize,
    pub(crate) ci: usize,
    pub(crate) c: usize,
    pub(crate) t: usize,
    /// Steps the block computes its convolution, residual, norm and dropout for: T, or 1
    /// for the last block (the head reads only its last step).
    pub(crate) to: usize,
    pub(crate) k: usize,
    pub(crate) terms: usize,
}

/// Temporal-attention intermediates (step 1).
pub(crate) struct Temporal {
    pub(crate) xu1: Tensor,
    pub(crate) lhs: Tensor,
    pub(crate) rhs: Tensor,
    /// σ(lhs·rhs + be): the scores, bias and sigmoid applied in the product's epilogue.
    pub(crate) sig: Tensor,
    pub(crate) e: Tensor,
    pub(crate) ep: Tensor,
}

/// Spatial-attention intermediates (step 2).
pub(crate) struct Spatial {
    pub(crate) xt: Tensor,
    pub(crate) xw1: Tensor,
    pub(crate) lhs: Tensor,
    pub(crate) rhs: Tensor,
    /// σ(lhs·rhsᵀ + bs), as in the temporal attention.
    pub(crate) sig: Tensor,
    pub(crate) s: Tensor,
    pub(crate) sp: Tensor,
    /// Q[b] = Ψ·(I + S'[b]): the spatial attention and the graph mix in one matrix, so
    /// that M = Ψ·X_s = Q·X_t takes one small-K product instead of two.
    pub(crate) q: Tensor,
}

/// The graph attention of `st-gat` (step 3 in place of the graph convolution).
pub(crate) struct GatBuffers {
    /// Q = Wᵀ·X over channels `[B, N, C, T]`.
    pub(crate) q: Tensor,
    /// α `[B, T, heads, N, N]`.
    pub(crate) alpha: Tensor,
    /// The aggregate Σ_j α_ij q_j before its ReLU `[B, N, C, T]`.
    pub(crate) g: Tensor,
    pub(crate) heads: usize,
}

/// One block's buffers: everything its backward pass reads.
pub struct Block {
    pub(crate) index: usize,
    pub(crate) d: Dims,
    pub(crate) gated: bool,
    pub(crate) dilation: usize,
    pub(crate) eps: f32,
    pub(crate) dropout: Dropout,
    pub(crate) input: Tensor,
    pub(crate) tat: Option<Temporal>,
    pub(crate) sat: Option<Spatial>,
    /// `st-gat` only.
    pub(crate) gat: Option<GatBuffers>,
    pub(crate) psi: Tensor,
    pub(crate) m: Tensor,
    /// ReLU(G): the graph convolution's product applies it in its epilogue.
    pub(crate) z: Tensor,
    pub(crate) col: Tensor,
    pub(crate) f: Tensor,
    pub(crate) gg: Tensor,
    /// H, then ReLU(H + R + bias) once the residual product has accumulated onto it.
    pub(crate) s: Tensor,
    pub(crate) mean: Tensor,
    pub(crate) rstd: Tensor,
    /// The input's last step `[B, N, C_in]`, for the residual of a trimmed block.
    pub(crate) x_last: Option<Tensor>,
    /// `[tcn.filter.weight; tcn.gate.weight]` as one `[2C, C·K]` matrix (gated variants),
    /// copied in each backward pass: the two convolutions' backward is one product.
    pub(crate) w_fg: Option<Tensor>,
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

    pub(crate) fn name(&self, s: &str) -> String {
        format!("blocks.{}.{s}", self.index)
    }

    // The products of docs/model.md, named by what they compute.

    /// tat: xu1[b, (c,t)] = Σ_n U1[n] X[b, n, (c,t)].
    pub(crate) fn mm_u1(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.ci * d.t, d.n).batched(d.b).share_a(true)
    }
    /// tat: lhs[b] = xu1[b]ᵀ [T, C_in] · U2 [C_in, N].
    pub(crate) fn mm_u2(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.t, d.n, d.ci)
            .batched(d.b)
            .transpose_a(true)
            .share_b(true)
    }
    /// tat: rhs[b, n] = U3 [1, C_in] · X[b, n] [C_in, T].
    pub(crate) fn mm_u3(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.t, d.ci).batched(d.b * d.n).share_a(true)
    }
    /// tat: P[b] = lhs[b] [T, N] · rhs[b] [N, T].
    pub(crate) fn mm_tp(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.t, d.t, d.n).batched(d.b)
    }
    /// tat: E[b] = Ve · σ(P + be)[b].
    pub(crate) fn mm_ve(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.t, d.t, d.t).batched(d.b).share_a(true)
    }
    /// tat: X_t[b] = X[b] [N·C_in, T] · (E'[b] [T, T] + I), the identity's term (X) added
    /// in the product's epilogue (and dX_t in that of dX).
    pub(crate) fn mm_xt(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n * d.ci, d.t, d.t)
            .batched(d.b)
            .plus_identity(true)
    }
    /// sat: xw1[(b,n,c)] = X_t[(b,n,c), :] · W1.
    pub(crate) fn mm_w1(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.b * d.n * d.ci, 1, d.t)
    }
    /// sat: lhs[(b,n)] = xw1[(b,n), :] · W2 [C_in, T].
    pub(crate) fn mm_w2(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.b * d.n, d.t, d.ci)
    }
    /// sat: rhs[b, m] = W3 [1, C_in] · X_t[b, m] [C_in, T] (stored [B, N, T]).
    pub(crate) fn mm_w3(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.t, d.ci).batched(d.b * d.n).share_a(true)
    }
    /// sat: P[b] = lhs[b] [N, T] · rhs[b]ᵀ.
    pub(crate) fn mm_sp(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.n, d.t).batched(d.b).transpose_b(true)
    }
    /// sat: S[b] = Vs · σ(P + bs)[b].
    pub(crate) fn mm_vs(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.n, d.n).batched(d.b).share_a(true)
    }
    /// sat + gwc: Q[b] = Ψ [N, N] · S'[b] [N, N] (+ Ψ, in the epilogue).
    pub(crate) fn mm_q(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.n, d.n).batched(d.b).share_a(true)
    }
    /// gwc with attention: M[b] = Q[b] [N, N] · X_t[b] [N, C_in·T].
    pub(crate) fn mm_qx(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.ci * d.t, d.n).batched(d.b)
    }
    /// The input gradient of an attention's two rank-1 projections (W3, W1 on X_t or U3,
    /// U1 on X), over `[B·N, C_in, T]`.
    pub(crate) fn rank_one_pair(&self, second: Second) -> OuterPair {
        let d = self.d;
        OuterPair {
            items: d.b * d.n,
            rows: d.ci,
            cols: d.t,
            second,
        }
    }
    /// The batch sum of dQ, the gradient of Ψ's direct term in Q = Ψ + Ψ·S'.
    pub(crate) fn batch_sum_nn(&self) -> Bias {
        Bias {
            outer: self.d.b,
            channels: self.d.n * self.d.n,
            inner: 1,
        }
    }
    /// gwc: Ψ [1, N·N] = θ [1, terms] · basis [terms, N·N].
    pub(crate) fn mm_psi(&self) -> Matmul {
        let d = self.d;
        Matmul::new(1, d.n * d.n, d.terms)
    }
    /// gwc without attention: M[b] = Ψ [N, N] · X[b] [N, C_in·T].
    pub(crate) fn mm_mix(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.n, d.ci * d.t, d.n).batched(d.b).share_a(true)
    }
    /// gwc: G[b, n] = Wᵀ [C, C_in] · M[b, n] [C_in, T] (W stored [C_in, C]).
    pub(crate) fn mm_w(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.c, d.t, d.ci)
            .batched(d.b * d.n)
            .transpose_a(true)
            .share_a(true)
    }
    /// `st-gat`'s graph attention over the block's hidden tensor.
    pub(crate) fn graph_attention(&self, heads: usize) -> GraphAttention {
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
    pub(crate) fn mm_conv(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.c, d.to, d.c * d.k)
            .batched(d.b * d.n)
            .share_a(true)
    }
    /// res: R[b, n] = res.weight [C, C_in] · X[b, n] [C_in, T].
    pub(crate) fn mm_res(&self) -> Matmul {
        let d = self.d;
        Matmul::new(d.c, d.to, d.ci)
            .batched(d.b * d.n)
            .share_a(true)
    }

    /// tcn backward, filter and gate stacked: [dG_f; dG_g][b, n] [2C, to] from
    /// [W_f; W_g] [2C, C·K] · col[b, n] [C·K, to].
    pub(crate) fn mm_conv_fg(&self) -> Matmul {
        let d = self.d;
        Matmul::new(2 * d.c, d.to, d.c * d.k)
            .batched(d.b * d.n)
            .share_a(true)
    }

    /// The input's last step, read by the residual of a trimmed block.
    pub(crate) fn input_last_step(&self) -> LastStep {
        let d = self.d;
        LastStep {
            rows: d.b * d.n * d.ci,
            steps: d.t,
        }
    }

    pub(crate) fn unfold(&self) -> Unfold {
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

    pub(crate) fn channel_bias(&self) -> Bias {
        let d = self.d;
        Bias {
            outer: d.b * d.n,
            channels: d.c,
            inner: d.to,
        }
    }

    /// tat: be [T, T] added to P over the batch.
    pub(crate) fn temporal_score_bias(&self) -> Bias {
        Bias {
            outer: self.d.b,
            channels: self.d.t * self.d.t,
            inner: 1,
        }
    }

    /// sat: bs [N, N] added to P over the batch.
    pub(crate) fn spatial_score_bias(&self) -> Bias {
        Bias {
            outer: self.d.b,
            channels: self.d.n * self.d.n,
            inner: 1,
        }
    }

    pub(crate) fn layer_norm(&self) -> LayerNorm {
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

    pub(crate) fn temporal_softmax(&self) -> Softmax {
        Softmax {
            outer: self.d.b,
            len: self.d.t,
            inner: self.d.t,
        }
    }

    pub(crate) fn spatial_softmax(&self) -> Softmax {
        Softmax {
            outer: self.d.b * self.d.n,
            len: self.d.n,
            inner: 1,
        }
    }

    /// A buffer the steps read or write, by its role, for the tests that run one step
    /// alone (the step tests, `testing.rs`): `input`, `E'`, `X_t`, `S'`, `Psi`, `Z`,
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

impl Block {
    /// The forward pass. For [`Pass::Train`], LayerNorm writes the output through the
    /// dropout (its mask's step is set later through the returned dispatch) and G_g is
    /// kept for the backward pass; otherwise the gate is fused into the gate product and
    /// LayerNorm writes the output as it is.
    pub fn forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
        pass: Pass,
    ) -> Result<Option<MaskedStep>, GpuError> {
        self.temporal_attention_forward(gpu, p, steps)?;
        self.spatial_attention_forward(gpu, p, steps)?;
        if self.gat.is_some() {
            self.graph_attention_forward(gpu, p, steps)?;
        } else {
            self.graph_conv_forward(gpu, p, steps)?;
        }
        self.gated_dcc_forward(gpu, p, steps, pass)?;
        self.residual_layer_norm_forward(gpu, p, steps, pass)
    }
}

impl Block {
    /// The backward pass of a training forward: from `d_out` (∂ℒ/∂output) into the
    /// parameter gradients and `d_in` (∂ℒ/∂input, overwritten). Returns the two
    /// dispatches that read the dropout's mask.
    pub fn backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        d_out: &Tensor,
        d_in: &Tensor,
    ) -> Result<[MaskedStep; 2], GpuError> {
        // Writes all of d_in; the steps below add to it.
        let (dh, masked) =
            self.residual_layer_norm_backward(gpu, p, scratch, steps, d_out, d_in)?;
        let dg = self.gated_dcc_backward(gpu, p, scratch, steps, &dh)?;
        if self.gat.is_some() {
            self.graph_attention_backward(gpu, p, scratch, steps, &dg, d_in)?;
        } else if let Some(g) = self.graph_conv_backward(gpu, p, scratch, steps, &dg, d_in)? {
            self.spatial_attention_backward(gpu, p, scratch, steps, &g.dsp, &g.dxt)?;
            self.temporal_attention_backward(gpu, p, scratch, steps, &g.dxt, d_in)?;
        }
        Ok(masked)
    }
}

/// Name lookups for the schedules of every network (also the step tests' table,
/// `model::block::testing`).
pub(crate) struct Table<'a> {
    specs: &'a [ParamSpec],
    params: &'a [Tensor],
    grads: &'a [Tensor],
    /// The graph basis (none for the dense baselines, which use no graph).
    basis: Option<&'a Tensor>,
}

impl<'a> Table<'a> {
    /// The table of `params` and `grads`, each in `specs` order, and the graph basis.
    pub(crate) fn new(
        specs: &'a [ParamSpec],
        params: &'a [Tensor],
        grads: &'a [Tensor],
        basis: Option<&'a Tensor>,
    ) -> Table<'a> {
        Table {
            specs,
            params,
            grads,
            basis,
        }
    }

    fn index(&self, name: &str) -> usize {
        // invariant: the schedules ask only for names of param_specs(config), from which the table is built.
        self.specs
            .iter()
            .position(|s| s.name == name)
            .unwrap_or_else(|| panic!("schedule asks for unknown parameter {name}"))
    }
}

impl ParamTable for Table<'_> {
    fn param(&self, name: &str) -> &Tensor {
        if name == "graph.basis" {
            // invariant: only ST blocks ask for graph.basis, and their configs have graph terms.
            return self.basis.expect("the ST blocks have a graph basis");
        }
        &self.params[self.index(name)]
    }

    fn grad(&self, name: &str) -> &Tensor {
        &self.grads[self.index(name)]
    }
}
