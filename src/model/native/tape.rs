//! The training forward of one window: docs/model.md steps 1–7 with the training step's
//! dropout, and the head, keeping on a [`Tape`] everything `backward.rs` reads. The order
//! is the device's: X_t = X·(E' + I), Q = Ψ·(I + S'), M = Q·X_t, Z = ReLU(Wᵀ·M) per node,
//! and in the last block steps 4–7 at the last time step only (the one the head reads;
//! its dropout bits are the ones that step has in the whole tensor). Beyond the device,
//! the last block computes X_t, M and Z only at the K steps its convolution reads there
//! ([`Cols`]), and its spatial attention is taken from X and E' instead of X_t (the same
//! sums: X_t·W1 = X·((I + E')·W1), W3ᵀ·X_t[m] = (W3ᵀ·X[m])·(I + E')).

use super::graph_attention::GatTape;
use super::slots::{BlockSlots, Slots};
use rayon::prelude::*;

use super::{
    flushing_subnormals, gemm, par_gemm, rows, sigmoid, softmax_columns, softmax_rows, tanh,
    transposed, View, PAR_MIN_MACS,
};
use crate::model::config::ModelConfig;
use crate::ops::dropout::{keep, Dropout};
use multiversion::multiversion;

/// The time steps a block computes X_t, M and Z at: `len` steps from `first`, `stride`
/// apart. Every step, except in the last block (steps 4–7 at T − 1 only), whose
/// convolution reads Z at T − 1 − d·lag for lag < K, d its dilation: those taps only
/// (`taps`), where M and Z are laid out tap-major, `[N, len, C]`, so that M = Q·X_t and
/// Z = M·W are one product each for all nodes.
#[derive(Clone, Copy, Debug)]
pub(super) struct Cols {
    pub first: usize,
    pub stride: usize,
    pub len: usize,
    pub taps: bool,
}

impl Cols {
    fn every(t: usize) -> Cols {
        Cols {
            first: 0,
            stride: 1,
            len: t,
            taps: false,
        }
    }

    /// The taps at or after step 0 of a kernel of `k` with dilation `d` ending at `t0`.
    fn taps(t0: usize, d: usize, k: usize) -> Cols {
        let len = k.min(t0 / d + 1);
        Cols {
            first: t0 - d * (len - 1),
            stride: d,
            len,
            taps: true,
        }
    }

    /// `[N, C, len]` to the taps' layout `[N, len, C]` (`back`: the other way).
    pub fn transpose(&self, n: usize, c: usize, src: &[f32], out: &mut [f32], back: bool) {
        let size = c * self.len;
        for (s, o) in src[..n * size].chunks(size).zip(out.chunks_mut(size)) {
            for ch in 0..c {
                for j in 0..self.len {
                    let (a, b) = (ch * self.len + j, j * c + ch);
                    if back {
                        o[a] = s[b];
                    } else {
                        o[b] = s[a];
                    }
                }
            }
        }
    }

    /// `out[r][j] = src[r][first + stride·j]` for rows of `t` in `src`, of `len` in `out`.
    #[inline(always)]
    fn gather(&self, src: &[f32], t: usize, out: &mut [f32]) {
        for (o, s) in out.chunks_mut(self.len).zip(src.chunks(t)) {
            for (j, o) in o.iter_mut().enumerate() {
                *o = s[self.first + self.stride * j];
            }
        }
    }

    /// `dst[r][first + stride·j] += src[r][j]`, the adjoint of [`Cols::gather`].
    #[inline(always)]
    pub fn scatter_add(&self, src: &[f32], t: usize, dst: &mut [f32]) {
        for (s, d) in src.chunks(self.len).zip(dst.chunks_mut(t)) {
            if self.stride == 1 {
                for (d, s) in d[self.first..][..self.len].iter_mut().zip(s) {
                    *d += s;
                }
            } else {
                for (j, s) in s.iter().enumerate() {
                    d[self.first + self.stride * j] += s;
                }
            }
        }
    }

    /// `rows` of E' `[T, T]` at the kept columns, as a `[T, len]` view (`transposed`: as
    /// `[len, T]`, E'[:, cols]ᵀ).
    pub fn of<'a>(&self, e: &'a [f32], t: usize, transposed: bool) -> View<'a> {
        let (rs, cs) = if transposed {
            (self.stride, t)
        } else {
            (t, self.stride)
        };
        View {
            data: &e[self.first..],
            rs,
            cs,
        }
    }
}

/// One block's intermediates for one window. Attention fields are empty in `iastgcn-a`.
pub(super) struct BlockTape {
    /// Step 1: `Σ_n U1[n]·X[n]` `[C_in, T]`, lhs `[T, N]`, rhs `[N, T]`, σ(lhs·rhs + be)
    /// `[T, T]`, E' `[T, T]`, X_t `[N, C_in, T]`.
    pub xu1: Vec<f32>,
    pub t_lhs: Vec<f32>,
    pub t_rhs: Vec<f32>,
    pub t_sig: Vec<f32>,
    pub e: Vec<f32>,
    pub xt: Vec<f32>,
    /// Scratch for E's column softmax: each column's max and sum `[2, T]`.
    pub e_cols: Vec<f32>,
    /// The steps X_t (`[N, C_in, cols.len]`; at the taps without attention, X's columns
    /// there), M and Z are kept at; at the taps, X_t again in their layout
    /// `[N, cols.len, C_in]`.
    pub cols: Cols,
    pub xtt: Vec<f32>,
    /// Step 2: at the taps (X_t not kept at every step), from X and E' instead, through
    /// v = (I + E')·W1 `[T]` and r[m] = W3ᵀ·X[m] `[N, T]` (empty otherwise); then
    /// `X_t·W1` `[N, C_in]`, lhs `[N, T]`, rhs `[N, T]`, σ(lhs·rhsᵀ + bs) `[N, N]`,
    /// S' `[N, N]`.
    pub sv: Vec<f32>,
    pub sr: Vec<f32>,
    pub xw1: Vec<f32>,
    pub s_lhs: Vec<f32>,
    pub s_rhs: Vec<f32>,
    pub s_sig: Vec<f32>,
    pub s: Vec<f32>,
    /// Step 3: Ψ and Q = Ψ·(I + S') `[N, N]`, M = Q·X_t `[N, C_in, cols.len]` and Z
    /// `[N, C, cols.len]` (at the taps `[N, cols.len, C_in]` and `[N, cols.len, C]`).
    pub psi: Vec<f32>,
    pub q: Vec<f32>,
    pub m: Vec<f32>,
    pub z: Vec<f32>,
    /// `st-gat`'s step 3 (its Z is [`BlockTape::z`]; Ψ, Q and M stay unused).
    pub gat: Option<GatTape>,
    /// Step 4 on the block's output steps (`steps` = T, or 1 in the last block): the
    /// gated variants' two weights stacked, `[W_f; W_g]` `[2C, C·K]` (one product for
    /// both), the unfolding `[C·K, N·steps]` and `[G_f; G_g]` `[outs, N·steps]`, the
    /// gated variants' after their activations: `[tanh(G_f); σ(G_g)]`.
    pub wcat: Vec<f32>,
    pub col: Vec<f32>,
    pub g: Vec<f32>,
    /// Step 6: ReLU(H + R) `[N, C, steps]`, and the mean and 1/σ `[N, steps]`.
    pub act: Vec<f32>,
    pub mean: Vec<f32>,
    pub rstd: Vec<f32>,
    /// Step 7's mask on the output steps `[N, C, steps]` (set by a training forward; the
    /// backward reads it instead of hashing again).
    pub kept: Vec<bool>,
    /// The block output after dropout `[N, C, T]` (empty in the last block: the head's
    /// input is [`Tape::h`]).
    pub y: Vec<f32>,
    /// The first output step and how many: (0, T), or (T − 1, 1) in the last block.
    pub t0: usize,
    pub steps: usize,
}

impl BlockTape {
    fn new(cfg: &ModelConfig, s: &BlockSlots, last: bool) -> BlockTape {
        let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
        let ci = s.c_in;
        let (t0, steps) = if last { (t - 1, 1) } else { (0, t) };
        let outs = if s.gate.is_some() { 2 * c } else { c };
        let att = |len: usize| vec![0f32; if s.temporal.is_some() { len } else { 0 }];
        let z = |len: usize| vec![0f32; len];
        // st-gat's graph attention computes Z at every step.
        let cols = if last && s.gat.is_none() {
            Cols::taps(t0, s.dilation, k)
        } else {
            Cols::every(t)
        };
        let kept = cols.len;
        let xt = if s.temporal.is_some() || cols.taps {
            n * ci * kept
        } else {
            0
        };
        // v and r of the spatial attention at the taps.
        let fewer = |len: usize| vec![0f32; if cols.taps { len } else { 0 }];
        BlockTape {
            xu1: att(ci * t),
            t_lhs: att(t * n),
            t_rhs: att(n * t),
            t_sig: att(t * t),
            e: att(t * t),
            xt: z(xt),
            e_cols: att(2 * t),
            cols,
            xtt: z(if cols.taps { n * ci * kept } else { 0 }),
            sv: fewer(t),
            sr: fewer(n * t),
            xw1: att(n * ci),
            s_lhs: att(n * t),
            s_rhs: att(n * t),
            s_sig: att(n * n),
            s: att(n * n),
            psi: z(n * n),
            q: z(n * n),
            m: z(n * ci * kept),
            z: z(n * c * kept),
            gat: s.gat.map(|g| g.tape()),
            wcat: z(if s.gate.is_some() { outs * c * k } else { 0 }),
            col: z(c * k * n * steps),
            g: z(outs * n * steps),
            act: z(n * c * steps),
            mean: z(n * steps),
            rstd: z(n * steps),
            kept: vec![false; n * c * steps],
            y: z(if last { 0 } else { n * c * t }),
            t0,
            steps,
        }
    }
}

/// Everything one window's training forward computed.
pub(super) struct Tape {
    pub blocks: Vec<BlockTape>,
    /// The head's input `[N·C]`: the last block's output at the last step, after dropout.
    pub h: Vec<f32>,
    /// ŷ `[O]`.
    pub out: Vec<f32>,
    /// Whether the last forward drew dropout masks (each block's [`BlockTape::kept`]).
    pub dropped: bool,
    /// Tasks the large products and the per-node loops of one window are split into, on
    /// rayon's global pool (1: none; the inference forward may set more, see
    /// `NativeForward::set_threads`; training parallelises over windows instead).
    pub threads: usize,
}

impl Tape {
    /// Sized for `config` (the only allocations; a tape is reused window after window).
    pub fn new(cfg: &ModelConfig, slots: &Slots) -> Tape {
        let last = slots.blocks.len() - 1;
        Tape {
            blocks: slots
                .blocks
                .iter()
                .enumerate()
                .map(|(l, s)| BlockTape::new(cfg, s, l == last))
                .collect(),
            h: vec![0f32; cfg.nodes * cfg.channels],
            out: vec![0f32; cfg.outputs],
            threads: 1,
            dropped: false,
        }
    }
}

/// The dropout of one training step, and where the window sits in its batch: block `l`
/// keeps element `i` of its output iff `keep(Dropout::new(B·N·C·T, p, seed + l), step,
/// item·N·C·T + i)` (the device's masks, docs/model.md step 7).
#[derive(Clone, Copy, Debug)]
pub(super) struct Masks {
    pub seed: u32,
    pub step: u32,
    pub batch: usize,
    pub item: usize,
}

impl Masks {
    /// Block `l`'s mask generator and the window's flat offset in its output.
    pub fn block(&self, cfg: &ModelConfig, l: usize) -> (Dropout, usize) {
        let per = cfg.nodes * cfg.channels * cfg.window;
        let d = Dropout::new(
            self.batch * per,
            cfg.dropout,
            self.seed.wrapping_add(l as u32),
        );
        (d, self.item * per)
    }
}

/// The training forward of window `x` `[N, F, T]` into `tape` (`params` in
/// `param_specs` order, `basis` `[terms, N, N]`).
pub(super) fn forward(
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
        block(
            cfg,
            basis,
            &slots.blocks[l],
            params,
            input,
            &mut rest[0],
            mask,
            h,
            threads,
        );
    }
    let nc = cfg.nodes * cfg.channels;
    tape.out.copy_from_slice(&params[slots.head_bias]);
    gemm(
        cfg.outputs,
        nc,
        1,
        rows(&params[slots.head_weight], nc),
        rows(&tape.h, 1),
        1.0,
        &mut tape.out,
        1,
    );
}

/// One block on `x` `[N, C_in, T]`; the output goes to `bt.y`, or to `h` in the last block.
/// `threads` > 1 splits the large products and the per-node loops (see [`Tape::threads`]).
#[allow(clippy::too_many_arguments)]
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn block(
    cfg: &ModelConfig,
    basis: &[f32],
    s: &BlockSlots,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &mut BlockTape,
    mask: Option<((Dropout, usize), u32)>,
    h: Option<&mut [f32]>,
    threads: usize,
) {
    let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
    let ci = s.c_in;
    // The per-node loops split only where a node's product is worth a task (the paper's
    // C = 64: 410k multiply-adds; the demo's C = 16: 12k, which stays on one thread).
    let split = |node_macs: usize| {
        if node_macs >= PAR_MIN_MACS / 2 {
            threads
        } else {
            1
        }
    };
    if let (Some(shape), Some(tape)) = (s.gat, bt.gat.as_mut()) {
        // `st-gat`: step 3 is a graph attention on the input, `basis` its edges.
        shape.forward(p, basis, x, tape, &mut bt.z);
    } else {
        graph_conv(n, ci, t, c, basis, s, p, x, bt, threads, split(c * ci * t));
    }
    // Step 4 on the output steps: unfold every node, then G = W·col + bias.
    let (t0, steps) = (bt.t0, bt.steps);
    let wide = n * steps;
    let d = s.dilation;
    let kept = bt.cols.len;
    for ch in 0..c {
        for lag in 0..k {
            let row = &mut bt.col[(ch * k + lag) * wide..][..wide];
            if bt.cols.taps {
                // One output step; Z `[N, taps, C]` holds lag's tap at kept − 1 − lag.
                for (i, v) in row.iter_mut().enumerate() {
                    *v = if lag < kept {
                        bt.z[(i * kept + kept - 1 - lag) * c + ch]
                    } else {
                        0.0
                    };
                }
                continue;
            }
            let shift = d * lag;
            let zeros = shift.saturating_sub(t0).min(steps);
            for (i, seg) in row.chunks_mut(steps).enumerate() {
                seg[..zeros].fill(0.0);
                if zeros < steps {
                    let from = t0 + zeros - shift;
                    seg[zeros..].copy_from_slice(&bt.z[(i * c + ch) * t + from..][..steps - zeros]);
                }
            }
        }
    }
    let ck = c * k;
    let biases = std::iter::once(s.filter.1).chain(s.gate.map(|g| g.1));
    let bias_rows = biases.flat_map(|b| p[b].iter());
    for (row, &bias) in bt.g.chunks_mut(wide).zip(bias_rows) {
        row.fill(bias);
    }
    let weights: &[f32] = match s.gate {
        Some((gate, _)) => {
            let (f, g) = bt.wcat.split_at_mut(c * ck);
            f.copy_from_slice(&p[s.filter.0]);
            g.copy_from_slice(&p[gate]);
            &bt.wcat
        }
        None => &p[s.filter.0],
    };
    par_gemm(
        threads,
        weights.len() / ck,
        ck,
        wide,
        rows(weights, ck),
        rows(&bt.col, wide),
        1.0,
        &mut bt.g,
        wide,
    );
    // The gate's activations, once over the whole of G (kept for the backward).
    let gated = s.gate.is_some();
    if gated {
        let (f, q) = bt.g.split_at_mut(c * wide);
        for v in f.iter_mut() {
            *v = tanh(*v);
        }
        for v in q.iter_mut() {
            *v = sigmoid(*v);
        }
    }
    // Steps 5–6 per node: A = ReLU(H + R), then LayerNorm over C at each step.
    let eps = cfg.eps as f32;
    let (res_w, res_b) = (&p[s.res.0], &p[s.res.1]);
    let one_step = steps == 1;
    if one_step {
        // R = X[:, :, t0]·W_rᵀ + b_r `[N, C]` for all nodes at once.
        for (a, b) in bt.act.iter_mut().zip(res_b.iter().cycle()) {
            *a = *b;
        }
        let xv = View {
            data: &x[t0..],
            rs: ci * t,
            cs: t,
        };
        gemm(n, ci, c, xv, transposed(res_w, ci), 1.0, &mut bt.act, c);
    }
    let g = &bt.g;
    let node = |i: usize, a: &mut [f32], mean: &mut [f32], rstd: &mut [f32]| {
        if !one_step {
            for (row, &bias) in a.chunks_mut(steps).zip(res_b) {
                row.fill(bias);
            }
            let xv = View {
                data: &x[i * ci * t + t0..],
                rs: t,
                cs: 1,
            };
            gemm(c, ci, steps, rows(res_w, ci), xv, 1.0, a, steps);
        }
        // Contiguous runs of steps, so that the gate's exp and divisions vectorise.
        for (o, a) in a.chunks_mut(steps).enumerate() {
            let f = &g[o * wide + i * steps..][..steps];
            if gated {
                let q = &g[(c + o) * wide + i * steps..][..steps];
                for ((v, f), q) in a.iter_mut().zip(f).zip(q) {
                    *v = (*v + f * q).max(0.0);
                }
            } else {
                for (v, f) in a.iter_mut().zip(f) {
                    *v = (*v + f.max(0.0)).max(0.0);
                }
            }
        }
        mean.fill(0.0);
        rstd.fill(0.0);
        for row in a.chunks(steps) {
            for (m, v) in mean.iter_mut().zip(row) {
                *m += v;
            }
        }
        for m in mean.iter_mut() {
            *m /= c as f32;
        }
        for row in a.chunks(steps) {
            for ((q, v), m) in rstd.iter_mut().zip(row).zip(mean.iter()) {
                *q += (v - m) * (v - m);
            }
        }
        for q in rstd.iter_mut() {
            *q = 1.0 / (*q / c as f32 + eps).sqrt();
        }
    };
    let tasks = split(c * ci * steps);
    if tasks > 1 {
        // Nodes in `tasks` groups of `per` consecutive ones.
        let per = n.div_ceil(tasks);
        let act = bt.act.par_chunks_mut(per * c * steps);
        act.zip(bt.mean.par_chunks_mut(per * steps))
            .zip(bt.rstd.par_chunks_mut(per * steps))
            .enumerate()
            .for_each(|(j, ((a, m), r))| {
                flushing_subnormals(|| {
                    let nodes = a
                        .chunks_mut(c * steps)
                        .zip(m.chunks_mut(steps))
                        .zip(r.chunks_mut(steps));
                    for (u, ((a, m), r)) in nodes.enumerate() {
                        node(j * per + u, a, m, r);
                    }
                })
            });
    } else {
        let act = bt.act.chunks_mut(c * steps);
        for (i, ((a, m), r)) in act
            .zip(bt.mean.chunks_mut(steps))
            .zip(bt.rstd.chunks_mut(steps))
            .enumerate()
        {
            node(i, a, m, r);
        }
    }
    // Step 6's affine map and step 7's dropout, into Y (or h at the last step).
    let scale = 1.0 / (1.0 - cfg.dropout as f32);
    let (gamma, beta) = (&p[s.gamma], &p[s.beta]);
    let mut out = h;
    for i in 0..n {
        let mean = &bt.mean[i * steps..][..steps];
        let rstd = &bt.rstd[i * steps..][..steps];
        for o in 0..c {
            let a = &bt.act[(i * c + o) * steps..][..steps];
            // Where (node i, channel o, step t0) sits in the whole [N, C, T] output.
            let full = (i * c + o) * t + t0;
            let dst = match out.as_deref_mut() {
                Some(h) => &mut h[i * c + o..][..steps],
                None => &mut bt.y[full..][..steps],
            };
            for (((d, a), m), r) in dst.iter_mut().zip(a).zip(mean).zip(rstd) {
                *d = gamma[o] * (a - m) * r + beta[o];
            }
            if let Some(((drop, offset), step)) = &mask {
                let kept = &mut bt.kept[(i * c + o) * steps..][..steps];
                for (tau, k) in kept.iter_mut().enumerate() {
                    *k = keep(drop, *step, offset + full + tau);
                }
                for (d, &k) in dst.iter_mut().zip(kept.iter()) {
                    *d = if k { *d * scale } else { 0.0 };
                }
            }
        }
    }
}

/// Steps 1–3 of the IASTGCN variants: Ψ = Σ_k θ_k basis_k, the attentions (when the
/// variant attends), M = Q·X_t and Z[i] = ReLU(Wᵀ·M[i]); `split` tasks for the per-node
/// products.
#[allow(clippy::too_many_arguments)]
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn graph_conv(
    n: usize,
    ci: usize,
    t: usize,
    c: usize,
    basis: &[f32],
    s: &BlockSlots,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &mut BlockTape,
    threads: usize,
    split: usize,
) {
    // invariant: every block but st-gat's has gwc.theta (slots::Slots::new).
    let theta = s.theta.expect("a graph convolution has gwc.theta");
    bt.psi.fill(0.0);
    for (theta, b) in p[theta].iter().zip(basis.chunks(n * n)) {
        for (v, b) in bt.psi.iter_mut().zip(b) {
            *v += theta * b;
        }
    }
    // Steps 1–2.
    let kept = bt.cols.len;
    if let (Some(ts), Some(ss)) = (s.temporal, s.spatial) {
        temporal_attention(n, ci, t, p, ts, x, bt, threads);
        spatial_attention(n, ci, t, p, ss, x, bt);
    } else {
        bt.q.copy_from_slice(&bt.psi);
        if bt.cols.taps {
            bt.cols.gather(x, t, &mut bt.xt);
        }
    }
    let width = ci * kept;
    let w = &p[s.w];
    if bt.cols.taps {
        // Step 3 at the taps, in their layout: M = Q·X_t, Z = ReLU(M·W), `[N·taps, ·]`.
        bt.cols.transpose(n, ci, &bt.xt, &mut bt.xtt, false);
        gemm(
            n,
            n,
            width,
            rows(&bt.q, n),
            rows(&bt.xtt, width),
            0.0,
            &mut bt.m,
            width,
        );
        gemm(
            n * kept,
            ci,
            c,
            rows(&bt.m, ci),
            rows(w, c),
            0.0,
            &mut bt.z,
            c,
        );
        for v in bt.z.iter_mut() {
            *v = v.max(0.0);
        }
        return;
    }
    let xt: &[f32] = if s.temporal.is_some() { &bt.xt } else { x };
    // Step 3: M = Q·X_t, Z[i] = ReLU(Wᵀ·M[i]).
    gemm(
        n,
        n,
        width,
        rows(&bt.q, n),
        rows(xt, width),
        0.0,
        &mut bt.m,
        width,
    );
    let mix = &bt.m;
    for_each_node(split, &mut bt.z, c * kept, |i, zi| {
        let mi = &mix[i * width..][..width];
        gemm(c, ci, kept, transposed(w, c), rows(mi, kept), 0.0, zi, kept);
        for v in zi.iter_mut() {
            *v = v.max(0.0);
        }
    });
}

/// Step 1 on `x` `[N, C_in, T]`: E', and X_t = X·(E' + I) at the kept steps, keeping
/// lhs, rhs, σ and E'.
#[allow(clippy::too_many_arguments)]
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn temporal_attention(
    n: usize,
    ci: usize,
    t: usize,
    p: &[Vec<f32>],
    ix: [usize; 5],
    x: &[f32],
    bt: &mut BlockTape,
    threads: usize,
) {
    let [u1, u2, u3, be, ve] = ix.map(|i| &p[i][..]);
    gemm(
        1,
        n,
        ci * t,
        rows(u1, n),
        rows(x, ci * t),
        0.0,
        &mut bt.xu1,
        ci * t,
    );
    gemm(
        t,
        ci,
        n,
        transposed(&bt.xu1, t),
        rows(u2, n),
        0.0,
        &mut bt.t_lhs,
        n,
    );
    for i in 0..n {
        let xi = &x[i * ci * t..][..ci * t];
        gemm(
            1,
            ci,
            t,
            rows(u3, ci),
            rows(xi, t),
            0.0,
            &mut bt.t_rhs[i * t..][..t],
            t,
        );
    }
    bt.t_sig.copy_from_slice(be);
    gemm(
        t,
        n,
        t,
        rows(&bt.t_lhs, n),
        rows(&bt.t_rhs, t),
        1.0,
        &mut bt.t_sig,
        t,
    );
    for v in bt.t_sig.iter_mut() {
        *v = sigmoid(*v);
    }
    gemm(t, t, t, rows(ve, t), rows(&bt.t_sig, t), 0.0, &mut bt.e, t);
    let (max, sum) = bt.e_cols.split_at_mut(t);
    softmax_columns(&mut bt.e, t, max, sum);
    let cols = bt.cols;
    cols.gather(x, t, &mut bt.xt);
    par_gemm(
        threads,
        n * ci,
        t,
        cols.len,
        rows(x, t),
        cols.of(&bt.e, t, false),
        1.0,
        &mut bt.xt,
        cols.len,
    );
}

/// Step 2 on X_t = X·(I + E') (`bt.xt`, or `x` and `bt.e` when X_t is kept at fewer
/// steps than T): S' and Q = Ψ·(I + S').
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn spatial_attention(
    n: usize,
    ci: usize,
    t: usize,
    p: &[Vec<f32>],
    ix: [usize; 5],
    x: &[f32],
    bt: &mut BlockTape,
) {
    let [w1, w2, w3, bs, vs] = ix.map(|i| &p[i][..]);
    // With X_t at every step, from X_t; else from X and E': X_t·W1 = X·v with
    // v = (I + E')·W1, and W3ᵀ·X_t[m] = r[m]·(I + E') with r[m] = W3ᵀ·X[m].
    let every = !bt.cols.taps;
    let (src, w1v): (&[f32], &[f32]) = if every {
        (&bt.xt, w1)
    } else {
        bt.sv.copy_from_slice(w1);
        gemm(t, t, 1, rows(&bt.e, t), rows(w1, 1), 1.0, &mut bt.sv, 1);
        (x, &bt.sv)
    };
    gemm(
        n * ci,
        t,
        1,
        rows(src, t),
        rows(w1v, 1),
        0.0,
        &mut bt.xw1,
        1,
    );
    gemm(
        n,
        ci,
        t,
        rows(&bt.xw1, ci),
        rows(w2, t),
        0.0,
        &mut bt.s_lhs,
        t,
    );
    let r = if every { &mut bt.s_rhs } else { &mut bt.sr };
    for m in 0..n {
        let sm = &src[m * ci * t..][..ci * t];
        gemm(
            1,
            ci,
            t,
            rows(w3, ci),
            rows(sm, t),
            0.0,
            &mut r[m * t..][..t],
            t,
        );
    }
    if !every {
        bt.s_rhs.copy_from_slice(&bt.sr);
        gemm(
            n,
            t,
            t,
            rows(&bt.sr, t),
            rows(&bt.e, t),
            1.0,
            &mut bt.s_rhs,
            t,
        );
    }
    bt.s_sig.copy_from_slice(bs);
    gemm(
        n,
        t,
        n,
        rows(&bt.s_lhs, t),
        transposed(&bt.s_rhs, t),
        1.0,
        &mut bt.s_sig,
        n,
    );
    for v in bt.s_sig.iter_mut() {
        *v = sigmoid(*v);
    }
    gemm(n, n, n, rows(vs, n), rows(&bt.s_sig, n), 0.0, &mut bt.s, n);
    softmax_rows(&mut bt.s, n);
    bt.q.copy_from_slice(&bt.psi);
    gemm(n, n, n, rows(&bt.psi, n), rows(&bt.s, n), 1.0, &mut bt.q, n);
}

/// `f(i, chunk)` for each node's `size`-long chunk of `data`, in `tasks` rayon tasks of
/// consecutive nodes when `tasks` > 1.
#[inline(always)]
fn for_each_node(
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
