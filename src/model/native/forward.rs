//! The inference forward pass of the IASTGCN variants, one window at a time (see the
//! module above).

use super::{gemm, rows, sigmoid, softmax_strided, tanh, transposed, View};
use crate::graph::Graph;
use crate::model::config::{Family, ModelConfig};
use crate::model::network::ModelError;
use crate::model::params::{graph_basis, param_specs, Parameters};

/// One block's weights, copied out of the checkpoint in the layouts the products read.
struct BlockWeights {
    /// `[U1 [N], U2 [C_in,N], U3 [C_in], be [T,T], Ve [T,T]]` and
    /// `[W1 [T], W2 [C_in,T], W3 [C_in], bs [N,N], Vs [N,N]]` when the variant attends.
    temporal: Option<[Vec<f32>; 5]>,
    spatial: Option<[Vec<f32>; 5]>,
    theta: Vec<f32>,
    /// `gwc.W` `[C_in, C]`.
    w: Vec<f32>,
    /// `[filter; gate]` stacked: `[2C, C·K]` (`[C, C·K]` without a gate), then the biases.
    conv: Vec<f32>,
    conv_bias: Vec<f32>,
    res_weight: Vec<f32>,
    res_bias: Vec<f32>,
    gamma: Vec<f32>,
    beta: Vec<f32>,
    c_in: usize,
    dilation: usize,
}

/// The CPU forward pass of one IASTGCN-family checkpoint (`iastgcn`, `iastgcn-a`,
/// `iastgcn-t`, `iastgcn-s`) for one window at a time.
pub struct NativeForward {
    config: ModelConfig,
    /// `[terms, N, N]` (f32 of [`graph_basis`]).
    basis: Vec<f32>,
    blocks: Vec<BlockWeights>,
    head_weight: Vec<f32>,
    head_bias: Vec<f32>,
    /// Block input and output `[N, C, T]`, swapped after each block.
    x: Vec<f32>,
    y: Vec<f32>,
    scratch: Scratch,
}

/// Working memory, sized for the largest block.
struct Scratch {
    /// X_t `[N, C_in, T]`.
    xt: Vec<f32>,
    /// M = Q·X_t `[N, C_in, T]`.
    m: Vec<f32>,
    /// Z `[N, C, T]`.
    z: Vec<f32>,
    /// The unfolding of every node `[C·K, N·T]`.
    col: Vec<f32>,
    /// `[filter; gate]` pre-activations `[2C, N·T]`, and one node's residual `[C, T]`.
    g: Vec<f32>,
    r: Vec<f32>,
    /// Attention intermediates: `[C_in, T]` or `[N, C_in]`, lhs, rhs, and the scores and
    /// weights, `[T, T]` or `[N, N]`.
    reduced: Vec<f32>,
    lhs: Vec<f32>,
    rhs: Vec<f32>,
    scores: Vec<f32>,
    weights: Vec<f32>,
    /// Ψ and Q `[N, N]`.
    psi: Vec<f32>,
    q: Vec<f32>,
    /// The head's input `[N·C]`.
    h: Vec<f32>,
    /// LayerNorm mean and 1/σ per step `[T]`.
    mean: Vec<f32>,
    var: Vec<f32>,
}

impl NativeForward {
    /// True when this path covers `config`'s variant (the four IASTGCN variants; not
    /// ST-GAT or the baselines).
    pub fn supports(config: &ModelConfig) -> bool {
        config.variant.family() == Family::StBlocks && !config.variant.graph_attention()
    }

    /// Copies the weights and sizes the working memory; the only allocations.
    pub fn new(
        config: &ModelConfig,
        graph: &Graph,
        params: &Parameters,
    ) -> Result<NativeForward, ModelError> {
        if !NativeForward::supports(config) {
            return Err(ModelError::Config(format!(
                "the native CPU forward covers iastgcn, iastgcn-a, iastgcn-t and iastgcn-s, not {}",
                config.variant
            )));
        }
        config.validate().map_err(ModelError::Config)?;
        for spec in param_specs(config) {
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
        }
        let get = |name: String| -> Result<Vec<f32>, ModelError> {
            params
                .index(&name)
                .map(|i| params.values[i].clone())
                .ok_or_else(|| ModelError::Config(format!("the parameters lack {name}")))
        };
        let (n, t, c, k) = (config.nodes, config.window, config.channels, config.kernel);
        let mut blocks = Vec::with_capacity(config.blocks);
        for l in 0..config.blocks {
            let p = |s: &str| get(format!("blocks.{l}.{s}"));
            let five = |names: [&str; 5]| -> Result<[Vec<f32>; 5], ModelError> {
                Ok([
                    p(names[0])?,
                    p(names[1])?,
                    p(names[2])?,
                    p(names[3])?,
                    p(names[4])?,
                ])
            };
            let (temporal, spatial) = if config.variant.attention() {
                (
                    Some(five(["tat.U1", "tat.U2", "tat.U3", "tat.be", "tat.Ve"])?),
                    Some(five(["sat.W1", "sat.W2", "sat.W3", "sat.bs", "sat.Vs"])?),
                )
            } else {
                (None, None)
            };
            let mut conv = p("tcn.filter.weight")?;
            let mut conv_bias = p("tcn.filter.bias")?;
            if config.variant.gated() {
                conv.extend(p("tcn.gate.weight")?);
                conv_bias.extend(p("tcn.gate.bias")?);
            }
            blocks.push(BlockWeights {
                temporal,
                spatial,
                theta: p("gwc.theta")?,
                w: p("gwc.W")?,
                conv,
                conv_bias,
                res_weight: p("res.weight")?,
                res_bias: p("res.bias")?,
                gamma: p("ln.gamma")?,
                beta: p("ln.beta")?,
                c_in: config.block_input(l),
                dilation: config.dilation(l),
            });
        }
        let wide = c.max(config.features);
        let z = |len: usize| vec![0f32; len];
        Ok(NativeForward {
            basis: graph_basis(graph, config)
                .iter()
                .map(|&v| v as f32)
                .collect(),
            blocks,
            head_weight: get("head.weight".into())?,
            head_bias: get("head.bias".into())?,
            x: z(n * wide * t),
            y: z(n * wide * t),
            scratch: Scratch {
                xt: z(n * wide * t),
                m: z(n * wide * t),
                z: z(n * c * t),
                col: z(c * k * n * t),
                g: z(2 * c * n * t),
                r: z(c * t),
                reduced: z(wide * t.max(n)),
                lhs: z(t * t.max(n)),
                rhs: z(t * n),
                scores: z(t.max(n) * t.max(n)),
                weights: z(t.max(n) * t.max(n)),
                psi: z(n * n),
                q: z(n * n),
                h: z(n * c),
                mean: z(t),
                var: z(t),
            },
            config: config.clone(),
        })
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
        let s = &mut self.scratch;
        self.x[..x.len()].copy_from_slice(x);
        let last = self.blocks.len() - 1;
        for (l, b) in self.blocks.iter().enumerate() {
            block(cfg, &self.basis, b, &self.x, &mut self.y, s, l == last);
            std::mem::swap(&mut self.x, &mut self.y);
        }
        // The head: ŷ = W_h·h + b, h = Y[:, :, T−1] (gathered by the last block).
        out.copy_from_slice(&self.head_bias);
        let nc = n * cfg.channels;
        gemm(
            cfg.outputs,
            nc,
            1,
            rows(&self.head_weight, nc),
            rows(&s.h, 1),
            1.0,
            out,
            1,
        );
        Ok(())
    }
}

/// One block on `x` `[N, C_in, T]`, into `y` `[N, C, T]` (or, for the last block, into
/// `s.h` `[N·C]` at the last step only).
fn block(
    cfg: &ModelConfig,
    basis: &[f32],
    b: &BlockWeights,
    x: &[f32],
    y: &mut [f32],
    s: &mut Scratch,
    last: bool,
) {
    let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
    let ci = b.c_in;
    let x = &x[..n * ci * t];
    // Step 3's Ψ = Σ_k θ_k basis_k.
    let psi = &mut s.psi;
    psi.fill(0.0);
    for (theta, m) in b.theta.iter().zip(basis.chunks(n * n)) {
        for (p, v) in psi.iter_mut().zip(m) {
            *p += theta * v;
        }
    }
    // Steps 1–2, giving X_t and Q = Ψ·(I + S'); without attention X_t = X and Q = Ψ.
    let xt: &[f32] = if let (Some(ta), Some(sa)) = (&b.temporal, &b.spatial) {
        temporal_attention(n, ci, t, ta, x, s);
        spatial_attention(n, ci, t, sa, s);
        &s.xt[..n * ci * t]
    } else {
        s.q.copy_from_slice(&s.psi);
        x
    };
    // Step 3: M = Q·X_t, then Z[i] = ReLU(Wᵀ·M[i]) per node.
    let m = &mut s.m[..n * ci * t];
    gemm(
        n,
        n,
        ci * t,
        rows(&s.q, n),
        rows(xt, ci * t),
        0.0,
        m,
        ci * t,
    );
    let z = &mut s.z[..n * c * t];
    for i in 0..n {
        let zi = &mut z[i * c * t..][..c * t];
        gemm(
            c,
            ci,
            t,
            transposed(&b.w, c),
            rows(&m[i * ci * t..][..ci * t], t),
            0.0,
            zi,
            t,
        );
    }
    for v in z.iter_mut() {
        *v = v.max(0.0);
    }
    let gated = cfg.variant.gated();
    let outs = if gated { 2 * c } else { c };
    let ck = c * k;
    let d = b.dilation;
    let eps = cfg.eps as f32;
    // Steps 4–5 on the steps this block's output needs: all of them, or the last.
    let (t0, steps) = if last { (t - 1, 1) } else { (0, t) };
    let wide = n * steps;
    // Unfold every node at once: col[c·K + k][i·steps + τ] = Z[i][c][t0 + τ − d·k] (0
    // before the window), each segment a shifted copy of a row of Z; then one product
    // for all nodes, G = [W_f; W_g]·col + bias, `[outs, N·steps]`.
    let col = &mut s.col[..ck * wide];
    for ch in 0..c {
        for lag in 0..k {
            let row = &mut col[(ch * k + lag) * wide..][..wide];
            let shift = d * lag;
            // Output steps τ with t0 + τ < shift read before the window.
            let zeros = shift.saturating_sub(t0).min(steps);
            for (i, seg) in row.chunks_mut(steps).enumerate() {
                seg[..zeros].fill(0.0);
                if zeros < steps {
                    let from = t0 + zeros - shift;
                    seg[zeros..].copy_from_slice(&z[(i * c + ch) * t + from..][..steps - zeros]);
                }
            }
        }
    }
    let g = &mut s.g[..outs * wide];
    for (o, row) in g.chunks_mut(wide).enumerate() {
        row.fill(b.conv_bias[o]);
    }
    gemm(
        outs,
        ck,
        wide,
        rows(&b.conv, ck),
        rows(col, wide),
        1.0,
        g,
        wide,
    );
    for i in 0..n {
        let xi = &x[i * ci * t..][..ci * t];
        let g = |o: usize, tau: usize| s.g[o * wide + i * steps + tau];
        let r = &mut s.r[..c * steps];
        for (o, row) in r.chunks_mut(steps).enumerate() {
            row.fill(b.res_bias[o]);
        }
        let xv = View {
            data: &xi[t0..],
            rs: t,
            cs: 1,
        };
        gemm(c, ci, steps, rows(&b.res_weight, ci), xv, 1.0, r, steps);
        // A = ReLU(H + R) with H = tanh(G_f)·σ(G_g) (ReLU(G_f) in `iastgcn-t`), into r.
        for o in 0..c {
            for tau in 0..steps {
                let f = g(o, tau);
                let h = if gated {
                    tanh(f) * sigmoid(g(c + o, tau))
                } else {
                    f.max(0.0)
                };
                let a = &mut r[o * steps + tau];
                *a = (*a + h).max(0.0);
            }
        }
        // Step 6: LayerNorm over C at each step, row by row (rows are channels).
        let mean = &mut s.mean[..steps];
        let var = &mut s.var[..steps];
        mean.fill(0.0);
        var.fill(0.0);
        for row in r.chunks(steps) {
            for (m, v) in mean.iter_mut().zip(row) {
                *m += v;
            }
        }
        for m in mean.iter_mut() {
            *m /= c as f32;
        }
        for row in r.chunks(steps) {
            for ((q, v), m) in var.iter_mut().zip(row).zip(mean.iter()) {
                *q += (v - m) * (v - m);
            }
        }
        for q in var.iter_mut() {
            *q = 1.0 / (*q / c as f32 + eps).sqrt();
        }
        for (o, row) in r.chunks(steps).enumerate() {
            let (gamma, beta) = (b.gamma[o], b.beta[o]);
            let out = if last {
                &mut s.h[i * c + o..][..1]
            } else {
                &mut y[(i * c + o) * t..][..t]
            };
            for (((out, v), m), rstd) in out.iter_mut().zip(row).zip(mean.iter()).zip(var.iter()) {
                *out = gamma * (v - m) * rstd + beta;
            }
        }
    }
}

/// Step 1 on `x` `[N, C_in, T]`: X_t = X·(E' + I) into `s.xt`.
fn temporal_attention(
    n: usize,
    ci: usize,
    t: usize,
    w: &[Vec<f32>; 5],
    x: &[f32],
    s: &mut Scratch,
) {
    let [u1, u2, u3, be, ve] = w;
    // Σ_n X[n,c,t]·U1[n] → [C_in, T]; lhs = (that)ᵀ·U2 → [T, N].
    let xu1 = &mut s.reduced[..ci * t];
    gemm(1, n, ci * t, rows(u1, n), rows(x, ci * t), 0.0, xu1, ci * t);
    let lhs = &mut s.lhs[..t * n];
    gemm(t, ci, n, transposed(xu1, t), rows(u2, n), 0.0, lhs, n);
    // rhs[n][t'] = Σ_c U3[c]·X[n,c,t'] → [N, T].
    let rhs = &mut s.rhs[..n * t];
    for i in 0..n {
        let xi = &x[i * ci * t..][..ci * t];
        gemm(
            1,
            ci,
            t,
            rows(u3, ci),
            rows(xi, t),
            0.0,
            &mut rhs[i * t..][..t],
            t,
        );
    }
    // σ(lhs·rhs + be), then E = Ve·σ(…), softmax over the first index.
    let sig = &mut s.scores[..t * t];
    sig.copy_from_slice(be);
    gemm(t, n, t, rows(lhs, n), rows(rhs, t), 1.0, sig, t);
    for v in sig.iter_mut() {
        *v = sigmoid(*v);
    }
    let e = &mut s.weights[..t * t];
    gemm(t, t, t, rows(ve, t), rows(sig, t), 0.0, e, t);
    for col in 0..t {
        softmax_strided(&mut e[col..], t, t);
    }
    // X_t = X + X·E'.
    let xt = &mut s.xt[..n * ci * t];
    xt.copy_from_slice(x);
    gemm(n * ci, t, t, rows(x, t), rows(e, t), 1.0, xt, t);
}

/// Step 2 on `s.xt`: S' and Q = Ψ·(I + S') into `s.q` (X_s itself is never formed:
/// step 3 computes Q·X_t).
fn spatial_attention(n: usize, ci: usize, t: usize, w: &[Vec<f32>; 5], s: &mut Scratch) {
    let [w1, w2, w3, bs, vs] = w;
    let xt = &s.xt[..n * ci * t];
    // Σ_u X_t[n,c,u]·W1[u] → [N, C_in]; lhs = that·W2 → [N, T].
    let xw1 = &mut s.reduced[..n * ci];
    gemm(n * ci, t, 1, rows(xt, t), rows(w1, 1), 0.0, xw1, 1);
    let lhs = &mut s.lhs[..n * t];
    gemm(n, ci, t, rows(xw1, ci), rows(w2, t), 0.0, lhs, t);
    // rhsᵀ[m][t] = Σ_c W3[c]·X_t[m,c,t] → [N, T].
    let rhs = &mut s.rhs[..n * t];
    for m in 0..n {
        let xm = &xt[m * ci * t..][..ci * t];
        gemm(
            1,
            ci,
            t,
            rows(w3, ci),
            rows(xm, t),
            0.0,
            &mut rhs[m * t..][..t],
            t,
        );
    }
    // σ(lhs·rhs + bs), S = Vs·σ(…), softmax over j.
    let sig = &mut s.scores[..n * n];
    sig.copy_from_slice(bs);
    gemm(n, t, n, rows(lhs, t), transposed(rhs, t), 1.0, sig, n);
    for v in sig.iter_mut() {
        *v = sigmoid(*v);
    }
    let sp = &mut s.weights[..n * n];
    gemm(n, n, n, rows(vs, n), rows(sig, n), 0.0, sp, n);
    for row in sp.chunks_mut(n) {
        softmax_strided(row, n, 1);
    }
    // Q = Ψ + Ψ·S'.
    s.q.copy_from_slice(&s.psi);
    gemm(n, n, n, rows(&s.psi, n), rows(sp, n), 1.0, &mut s.q, n);
}
