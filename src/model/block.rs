//! One ST block on the device (docs/model.md steps 1–7): its activation buffers and the
//! forward and backward schedules, op by op, in the order of docs/model.md.

use super::config::ModelConfig;
use super::schedule::{Scratch, Steps};
use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::ops::bias::Bias;
use crate::ops::dropout::Dropout;
use crate::ops::elementwise::{unary_backward, unary_forward, Unary};
use crate::ops::gated_dcc::{gate_backward_stacked, gate_forward, ReluOutput, Unfold};
use crate::ops::head::LastStep;
use crate::ops::layer_norm::LayerNorm;
use crate::ops::matmul::{Epilogue, Matmul};
use crate::ops::outer::{OuterPair, Second};
use crate::ops::softmax::Softmax;

/// Device parameters and their gradients, looked up by docs/model.md name.
pub trait ParamTable {
    fn param(&self, name: &str) -> &Tensor;
    fn grad(&self, name: &str) -> &Tensor;
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
    p: Tensor,
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
    p: Tensor,
    sig: Tensor,
    s: Tensor,
    sp: Tensor,
    /// Q[b] = Ψ·(I + S'[b]): the spatial attention and the graph mix in one matrix, so
    /// that M = Ψ·X_s = Q·X_t takes one small-K product instead of two.
    q: Tensor,
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
    psi: Tensor,
    m: Tensor,
    /// ReLU(G): the graph convolution's product applies it in its epilogue.
    z: Tensor,
    col: Tensor,
    f: Tensor,
    gg: Tensor,
    /// H, then ReLU(H + R + bias) once the residual product has accumulated onto it.
    s: Tensor,
    y: Tensor,
    mean: Tensor,
    rstd: Tensor,
    /// The input's last step `[B, N, C_in]`, for the residual of a trimmed block.
    x_last: Option<Tensor>,
    /// `[tcn.filter.weight; tcn.gate.weight]` as one `[2C, C·K]` matrix (gated variants),
    /// copied in each backward pass: the two convolutions' backward is one product.
    w_fg: Option<Tensor>,
    /// The block output `[B, N, C, to]`: `y` after dropout (training) or a copy of it
    /// (inference).
    pub output: Tensor,
}

/// Indices of a block's dropout dispatch in the forward and backward schedules.
pub struct DropoutSlots {
    pub dropout: Dropout,
    pub forward: usize,
    pub backward: usize,
}

impl Block {
    /// Allocates the buffers of block `index` reading `input` [B, N, C_in, T]. A `trimmed`
    /// block (the last one) computes steps 4–7 only at the last step, which is all the
    /// head reads: its output is `[B, N, C, 1]`, the same values as the last step of the
    /// whole computation (the attention and graph convolution still run on all T steps,
    /// which the attention needs).
    pub fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        index: usize,
        batch: usize,
        input: &Tensor,
        dropout_seed: u32,
        trimmed: bool,
    ) -> Block {
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
                xu1: z("tat.xu1", &[b, ci, t]),
                lhs: z("tat.lhs", &[b, t, n]),
                rhs: z("tat.rhs", &[b, n, t]),
                p: z("tat.P", &[b, t, t]),
                sig: z("tat.sig", &[b, t, t]),
                e: z("tat.E", &[b, t, t]),
                ep: z("tat.E'", &[b, t, t]),
            };
            let sat = Spatial {
                xt: z("X_t", &[b, n, ci, t]),
                xw1: z("sat.xw1", &[b, n, ci]),
                lhs: z("sat.lhs", &[b, n, t]),
                rhs: z("sat.rhs", &[b, n, t]),
                p: z("sat.P", &[b, n, n]),
                sig: z("sat.sig", &[b, n, n]),
                s: z("sat.S", &[b, n, n]),
                sp: z("sat.S'", &[b, n, n]),
                q: z("gwc.Q", &[b, n, n]),
            };
            (Some(tat), Some(sat))
        } else {
            (None, None)
        };
        let hidden = [b, n, c, t];
        let out = [b, n, c, d.to];
        let whole = Dropout::new(
            hidden.iter().product(),
            config.dropout,
            dropout_seed.wrapping_add(index as u32),
        );
        Block {
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
            psi: z("gwc.Psi", &[n, n]),
            m: z("gwc.M", &[b, n, ci, t]),
            z: z("Z", &hidden),
            col: z("tcn.col", &[b, n, c, d.k, d.to]),
            f: z("tcn.G_f", &out),
            gg: z("tcn.G_g", &out),
            s: z("relu(H+R)", &out),
            y: z("Y", &out),
            mean: z("ln.mean", &[b * n * d.to]),
            rstd: z("ln.rstd", &[b * n * d.to]),
            x_last: trimmed.then(|| z("x_last", &[b, n, ci])),
            w_fg: config
                .variant
                .gated()
                .then(|| z("tcn.W_fg", &[2 * c, c * d.k])),
            output: z("output", &out),
        }
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

    /// The forward pass. With `train`, dropout (whose step is set later through the
    /// returned slot) writes the output and G_g and Y are kept for the backward pass;
    /// otherwise the gate is fused into the gate product and LayerNorm writes the output.
    pub fn forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
        train: bool,
    ) -> Result<Option<usize>, GpuError> {
        let w = |s: &str| p.param(&self.name(s));
        let x = &self.input;
        let attention = match (&self.tat, &self.sat) {
            (Some(ta), Some(sa)) => {
                // 1. Temporal attention.
                steps.run(self.mm_u1().forward(gpu, w("tat.U1"), x, &ta.xu1, false))?;
                steps.run(
                    self.mm_u2()
                        .forward(gpu, &ta.xu1, w("tat.U2"), &ta.lhs, false),
                )?;
                steps.run(self.mm_u3().forward(gpu, w("tat.U3"), x, &ta.rhs, false))?;
                steps.run(self.mm_tp().forward(gpu, &ta.lhs, &ta.rhs, &ta.p, false))?;
                let be = self.temporal_score_bias();
                steps.run(be.forward(gpu, w("tat.be"), &ta.p))?;
                steps.run(unary_forward(gpu, Unary::Sigmoid, &ta.p, &ta.sig, false))?;
                steps.run(
                    self.mm_ve()
                        .forward(gpu, w("tat.Ve"), &ta.sig, &ta.e, false),
                )?;
                steps.run(self.temporal_softmax().forward(gpu, &ta.e, &ta.ep))?;
                steps.run(self.mm_xt().forward(gpu, x, &ta.ep, &sa.xt, false))?;
                // 2. Spatial attention.
                let xt = &sa.xt;
                steps.run(self.mm_w1().forward(gpu, xt, w("sat.W1"), &sa.xw1, false))?;
                steps.run(
                    self.mm_w2()
                        .forward(gpu, &sa.xw1, w("sat.W2"), &sa.lhs, false),
                )?;
                steps.run(self.mm_w3().forward(gpu, w("sat.W3"), xt, &sa.rhs, false))?;
                steps.run(self.mm_sp().forward(gpu, &sa.lhs, &sa.rhs, &sa.p, false))?;
                let bs = self.spatial_score_bias();
                steps.run(bs.forward(gpu, w("sat.bs"), &sa.p))?;
                steps.run(unary_forward(gpu, Unary::Sigmoid, &sa.p, &sa.sig, false))?;
                steps.run(
                    self.mm_vs()
                        .forward(gpu, w("sat.Vs"), &sa.sig, &sa.s, false),
                )?;
                steps.run(self.spatial_softmax().forward(gpu, &sa.s, &sa.sp))?;
                Some(sa)
            }
            _ => None,
        };
        // 3. Graph wavelet (or Chebyshev) convolution of X_s = X_t + S'·X_t (eq. 28–29 after
        // 32–34): M = Ψ·X_s = Q·X_t with Q = Ψ + Ψ·S'.
        steps.run(self.mm_psi().forward(
            gpu,
            w("gwc.theta"),
            p.param("graph.basis"),
            &self.psi,
            false,
        ))?;
        match attention {
            Some(sa) => {
                let plus_psi = Epilogue {
                    matrix: Some(&self.psi),
                    ..Epilogue::default()
                };
                let mq = self.mm_q();
                steps.run(mq.forward_with(gpu, &self.psi, &sa.sp, &sa.q, false, plus_psi))?;
                steps.run(self.mm_qx().forward(gpu, &sa.q, &sa.xt, &self.m, false))?;
            }
            None => {
                steps.run(self.mm_mix().forward(gpu, &self.psi, x, &self.m, false))?;
            }
        }
        let relu = Epilogue {
            bias: None,
            relu: true,
            ..Epilogue::default()
        };
        let mw = self.mm_w();
        steps.run(mw.forward_with(gpu, w("gwc.W"), &self.m, &self.z, false, relu))?;
        // 4. Gated dilated causal convolution (or the plain one of iastgcn-t).
        steps.run(self.unfold().forward(gpu, &self.z, &self.col))?;
        // The channel biases are added by the products themselves.
        let conv = self.mm_conv();
        let (col, f) = (&self.col, &self.f);
        let bias = |name: &str| Epilogue {
            bias: Some(w(name)),
            relu: false,
            ..Epilogue::default()
        };
        let filter = bias("tcn.filter.bias");
        steps.run(conv.forward_with(gpu, w("tcn.filter.weight"), col, f, false, filter))?;
        if self.gated && !train {
            // Inference keeps no G_g: the gate product applies tanh(G_f) ⊙ σ(·) itself.
            let gated = Epilogue {
                gate: Some(f),
                ..bias("tcn.gate.bias")
            };
            let gate_weight = w("tcn.gate.weight");
            steps.run(conv.forward_with(gpu, gate_weight, col, &self.s, false, gated))?;
        } else if self.gated {
            let (gg, gate) = (&self.gg, bias("tcn.gate.bias"));
            steps.run(conv.forward_with(gpu, w("tcn.gate.weight"), col, gg, false, gate))?;
            steps.run(gate_forward(gpu, f, gg, &self.s))?;
        } else {
            steps.run(unary_forward(gpu, Unary::Relu, f, &self.s, false))?;
        }
        // 5–6. Residual 1×1 convolution (+ bias) accumulated onto H, with the ReLU in the
        // product's epilogue; then LayerNorm.
        let residual = Epilogue {
            bias: Some(w("res.bias")),
            relu: true,
            ..Epilogue::default()
        };
        let x_res = match &self.x_last {
            Some(x_last) => {
                steps.run(self.input_last_step().forward(gpu, x, x_last))?;
                x_last
            }
            None => x,
        };
        steps.run(self.mm_res().forward_with(
            gpu,
            w("res.weight"),
            x_res,
            &self.s,
            true,
            residual,
        ))?;
        // Inference has no dropout: LayerNorm writes the block output itself.
        let y = if train { &self.y } else { &self.output };
        steps.run(self.layer_norm().forward(
            gpu,
            &self.s,
            w("ln.gamma"),
            w("ln.beta"),
            y,
            &self.mean,
            &self.rstd,
        ))?;
        // 7. Dropout.
        if train {
            Ok(Some(steps.run(self.dropout.apply(
                gpu,
                0,
                &self.y,
                &self.output,
                false,
            ))?))
        } else {
            Ok(None)
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

    pub fn dropout(&self) -> Dropout {
        self.dropout
    }

    /// The backward pass of a training forward: from `d_out` (∂ℒ/∂output) into the
    /// parameter gradients and `d_in` (∂ℒ/∂input, overwritten). Returns the index of
    /// the dropout dispatch.
    pub fn backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        d_out: &Tensor,
        d_in: &Tensor,
    ) -> Result<usize, GpuError> {
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let x = &self.input;
        let hidden = [d.b, d.n, d.c, d.t];
        let out = [d.b, d.n, d.c, d.to];
        let acts = [d.b, d.n, d.ci, d.t];
        // 7. Dropout: the same mask as the forward pass.
        let dy = scratch.get("dY", &out)?;
        let slot = steps.run(self.dropout.apply(gpu, 0, d_out, &dy, false))?;
        // 6. LayerNorm and the ReLU before it (its input was the ReLU's output; the mask
        // is applied by the LayerNorm backward).
        let ln = LayerNorm {
            relu_input: true,
            ..self.layer_norm()
        };
        let ds = scratch.get("dS", &out)?;
        steps.run(ln.backward_input(
            gpu,
            &self.s,
            w("ln.gamma"),
            &dy,
            &self.mean,
            &self.rstd,
            &ds,
            false,
        ))?;
        steps.run(ln.backward_params(
            gpu,
            &self.s,
            &dy,
            &self.mean,
            &self.rstd,
            dw("ln.gamma"),
            dw("ln.beta"),
            false,
        ))?;
        // 5. Residual: ∂/∂H = ∂/∂R = dS.
        let bias = self.channel_bias();
        let res = self.mm_res();
        steps.run(bias.backward(gpu, &ds, dw("res.bias"), false))?;
        match &self.x_last {
            Some(x_last) => {
                // Only the last step of the input reached the residual: its gradient
                // there, zero elsewhere (this writes all of d_in).
                let dx_last = scratch.get("dx_last", &[d.b, d.n, d.ci])?;
                steps.run(res.backward_a(gpu, x_last, &ds, dw("res.weight"), false))?;
                steps.run(res.backward_b(gpu, w("res.weight"), &ds, &dx_last, false))?;
                steps.run(self.input_last_step().backward(gpu, &dx_last, d_in))?;
            }
            None => {
                steps.run(res.backward_a(gpu, x, &ds, dw("res.weight"), false))?;
                steps.run(res.backward_b(gpu, w("res.weight"), &ds, d_in, false))?;
            }
        }
        // 4. Gate and convolutions.
        let conv = self.mm_conv();
        let dcol = scratch.get("dcol", &[d.b, d.n, d.c, d.k, d.to])?;
        if let Some(w_fg) = &self.w_fg {
            // Filter and gate stacked: one product each for the weights' gradient and
            // dcol, with twice the rows (K = 2C for dcol).
            let (c, ck) = (d.c, d.c * d.k);
            steps.copy_range((w("tcn.filter.weight"), 0), (w_fg, 0), c * ck);
            steps.copy_range((w("tcn.gate.weight"), 0), (w_fg, c * ck), c * ck);
            let dfg = scratch.get("dG_fg", &[d.b, d.n, 2 * c, d.to])?;
            let block = c * d.to;
            steps.run(gate_backward_stacked(
                gpu, &self.f, &self.gg, &ds, &dfg, block,
            ))?;
            let stacked_bias = Bias {
                channels: 2 * c,
                ..self.channel_bias()
            };
            let dbias = scratch.get("dbias_fg", &[2 * c])?;
            steps.run(stacked_bias.backward(gpu, &dfg, &dbias, false))?;
            steps.copy_range((&dbias, 0), (dw("tcn.filter.bias"), 0), c);
            steps.copy_range((&dbias, c), (dw("tcn.gate.bias"), 0), c);
            let fg = self.mm_conv_fg();
            let dw_fg = scratch.get("dW_fg", &[2 * c, ck])?;
            steps.run(fg.backward_a(gpu, &self.col, &dfg, &dw_fg, false))?;
            steps.copy_range((&dw_fg, 0), (dw("tcn.filter.weight"), 0), c * ck);
            steps.copy_range((&dw_fg, c * ck), (dw("tcn.gate.weight"), 0), c * ck);
            steps.run(fg.backward_b(gpu, w_fg, &dfg, &dcol, false))?;
        } else {
            let df = scratch.get("dG_f", &out)?;
            steps.run(unary_backward(gpu, Unary::Relu, &self.f, &ds, &df, false))?;
            steps.run(bias.backward(gpu, &df, dw("tcn.filter.bias"), false))?;
            let weight = dw("tcn.filter.weight");
            steps.run(conv.backward_a(gpu, &self.col, &df, weight, false))?;
            steps.run(conv.backward_b(gpu, w("tcn.filter.weight"), &df, &dcol, false))?;
        }
        // 3. Graph convolution: Z = ReLU(G), masked by the unfolding's backward.
        let dg = scratch.get("dG", &hidden)?;
        let z = ReluOutput(&self.z);
        steps.run(self.unfold().backward_through_relu(gpu, &dcol, z, &dg))?;
        let (mw, mix, mpsi) = (self.mm_w(), self.mm_mix(), self.mm_psi());
        let dm = scratch.get("dM", &acts)?;
        steps.run(mw.backward_a(gpu, &self.m, &dg, dw("gwc.W"), false))?;
        steps.run(mw.backward_b(gpu, w("gwc.W"), &dg, &dm, false))?;
        let dpsi = scratch.get("dPsi", &[d.n, d.n])?;
        let basis = p.param("graph.basis");
        let Some((ta, sa)) = self.tat.as_ref().zip(self.sat.as_ref()) else {
            // M = Ψ·X: dΨ, then dX accumulated onto the residual's contribution.
            steps.run(mix.backward_a(gpu, x, &dm, &dpsi, false))?;
            steps.run(mpsi.backward_a(gpu, basis, &dpsi, dw("gwc.theta"), false))?;
            steps.run(mix.backward_b(gpu, &self.psi, &dm, d_in, true))?;
            return Ok(slot);
        };
        // M = Q·X_t, Q = Ψ + Ψ·S': dQ, dΨ = Σ_b dQ·(I + S')ᵀ, dS' = Ψᵀ·dQ (dX_t = Qᵀ·dM + the
        // attention's terms, at the end).
        let nn = [d.b, d.n, d.n];
        let (dq, dsp, dss, dsig, dp) = (
            scratch.get("gwc.dQ", &nn)?,
            scratch.get("sat.dS'", &nn)?,
            scratch.get("sat.dS", &nn)?,
            scratch.get("sat.dsig", &nn)?,
            scratch.get("sat.dP", &nn)?,
        );
        let dxt = scratch.get("dX_t", &acts)?;
        let xt = &sa.xt;
        let (mq, mqx) = (self.mm_q(), self.mm_qx());
        steps.run(mqx.backward_a(gpu, xt, &dm, &dq, false))?;
        steps.run(mq.backward_a(gpu, &sa.sp, &dq, &dpsi, false))?;
        steps.run(self.batch_sum_nn().backward(gpu, &dq, &dpsi, true))?;
        steps.run(mpsi.backward_a(gpu, basis, &dpsi, dw("gwc.theta"), false))?;
        steps.run(mq.backward_b(gpu, &self.psi, &dq, &dsp, false))?;
        // 2. Spatial attention.
        steps.run(
            self.spatial_softmax()
                .backward(gpu, &sa.sp, &dsp, &dss, false),
        )?;
        let mvs = self.mm_vs();
        steps.run(mvs.backward_a(gpu, &sa.sig, &dss, dw("sat.Vs"), false))?;
        steps.run(mvs.backward_b(gpu, w("sat.Vs"), &dss, &dsig, false))?;
        steps.run(unary_backward(
            gpu,
            Unary::Sigmoid,
            &sa.sig,
            &dsig,
            &dp,
            false,
        ))?;
        let bs = self.spatial_score_bias();
        steps.run(bs.backward(gpu, &dp, dw("sat.bs"), false))?;
        let msp = self.mm_sp();
        let (dlhs, drhs) = (
            scratch.get("sat.dlhs", &[d.b, d.n, d.t])?,
            scratch.get("sat.drhs", &[d.b, d.n, d.t])?,
        );
        steps.run(msp.backward_a(gpu, &sa.rhs, &dp, &dlhs, false))?;
        steps.run(msp.backward_b(gpu, &sa.lhs, &dp, &drhs, false))?;
        let mw3 = self.mm_w3();
        steps.run(mw3.backward_a(gpu, xt, &drhs, dw("sat.W3"), false))?;
        let dxw1 = scratch.get("sat.dxw1", &[d.b, d.n, d.ci])?;
        let mw2 = self.mm_w2();
        steps.run(mw2.backward_a(gpu, w("sat.W2"), &dlhs, &dxw1, false))?;
        steps.run(mw2.backward_b(gpu, &sa.xw1, &dlhs, dw("sat.W2"), false))?;
        let mw1 = self.mm_w1();
        steps.run(mw1.backward_b(gpu, xt, &dxw1, dw("sat.W1"), false))?;
        // dX_t: the projections' two rank-1 terms (W3 ⊗ d rhs + d xw1 ⊗ W1) in one pass, then
        // Qᵀ·dM accumulated onto them.
        let pair = self.rank_one_pair(Second::RowsByCols);
        let factors = [w("sat.W3"), &drhs, &dxw1, w("sat.W1")];
        steps.run(pair.apply(gpu, factors, &dxt, false))?;
        steps.run(mqx.backward_b(gpu, &sa.q, &dm, &dxt, true))?;
        // 1. Temporal attention: X_t = X·(E' + I), so dX += dX_t·(E' + I)ᵀ.
        let tt = [d.b, d.t, d.t];
        let (dep, de, dsig, dp) = (
            scratch.get("tat.dE'", &tt)?,
            scratch.get("tat.dE", &tt)?,
            scratch.get("tat.dsig", &tt)?,
            scratch.get("tat.dP", &tt)?,
        );
        let mxt = self.mm_xt();
        steps.run(mxt.backward_b(gpu, x, &dxt, &dep, false))?;
        steps.run(mxt.backward_a(gpu, &ta.ep, &dxt, d_in, true))?;
        steps.run(
            self.temporal_softmax()
                .backward(gpu, &ta.ep, &dep, &de, false),
        )?;
        let mve = self.mm_ve();
        steps.run(mve.backward_a(gpu, &ta.sig, &de, dw("tat.Ve"), false))?;
        steps.run(mve.backward_b(gpu, w("tat.Ve"), &de, &dsig, false))?;
        steps.run(unary_backward(
            gpu,
            Unary::Sigmoid,
            &ta.sig,
            &dsig,
            &dp,
            false,
        ))?;
        let be = self.temporal_score_bias();
        steps.run(be.backward(gpu, &dp, dw("tat.be"), false))?;
        let mtp = self.mm_tp();
        let (dlhs, drhs) = (
            scratch.get("tat.dlhs", &[d.b, d.t, d.n])?,
            scratch.get("tat.drhs", &[d.b, d.n, d.t])?,
        );
        steps.run(mtp.backward_a(gpu, &ta.rhs, &dp, &dlhs, false))?;
        steps.run(mtp.backward_b(gpu, &ta.lhs, &dp, &drhs, false))?;
        let mu3 = self.mm_u3();
        steps.run(mu3.backward_a(gpu, x, &drhs, dw("tat.U3"), false))?;
        let dxu1 = scratch.get("tat.dxu1", &[d.b, d.ci, d.t])?;
        let mu2 = self.mm_u2();
        steps.run(mu2.backward_a(gpu, w("tat.U2"), &dlhs, &dxu1, false))?;
        steps.run(mu2.backward_b(gpu, &ta.xu1, &dlhs, dw("tat.U2"), false))?;
        let mu1 = self.mm_u1();
        steps.run(mu1.backward_a(gpu, x, &dxu1, dw("tat.U1"), false))?;
        // dX += U3 ⊗ d rhs + U1 ⊗ d xu1, the projections' two rank-1 terms in one pass.
        let pair = self.rank_one_pair(Second::NodeByMatrix { nodes: self.d.n });
        let factors = [w("tat.U3"), &drhs, w("tat.U1"), &dxu1];
        steps.run(pair.apply(gpu, factors, d_in, true))?;
        Ok(slot)
    }
}
