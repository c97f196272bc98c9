//! The memory of the ST blocks on the CPU, allocated once when a path is built and reused
//! window after window: what the training forward keeps for the backward ([`Tape`], one
//! [`BlockTape`] per block), the time steps each block computes at ([`Cols`]), the
//! dropout of a training step ([`Masks`]) and the backward's working memory ([`Work`]).

use crate::model::block::residual_layer_norm::dropout_kernel::Dropout;
use crate::model::block::slots::{BlockSlots, Slots};
use crate::model::config::ModelConfig;
use crate::model::cpu::View;

/// The time steps a block computes X_t, M and Z at: `len` steps from `first`, `stride`
/// apart. Every step, except in the last block (steps 4–7 at T − 1 only), whose
/// convolution reads Z at T − 1 − d·lag for lag < K, d its dilation: those taps only
/// (`taps`), where M and Z are laid out tap-major, `[N, len, C]`, so that M = Q·X_t and
/// Z = M·W are one product each for all nodes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cols {
    pub first: usize,
    pub stride: usize,
    pub len: usize,
    pub taps: bool,
}

impl Cols {
    pub(crate) fn every(t: usize) -> Cols {
        Cols {
            first: 0,
            stride: 1,
            len: t,
            taps: false,
        }
    }

    /// The taps at or after step 0 of a kernel of `k` with dilation `d` ending at `t0`.
    pub(crate) fn taps(t0: usize, d: usize, k: usize) -> Cols {
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
    pub fn gather(&self, src: &[f32], t: usize, out: &mut [f32]) {
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
pub(crate) struct BlockTape {
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
    /// Step 4's output H = tanh(G_f) ⊙ σ(G_g) (ReLU(G_f) in `iastgcn-t`) `[C, N·steps]`.
    pub hidden: Vec<f32>,
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
    pub(crate) fn new(cfg: &ModelConfig, s: &BlockSlots, last: bool) -> BlockTape {
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
            hidden: z(c * n * steps),
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
pub(crate) struct Tape {
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
pub(crate) struct Masks {
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

/// Working memory of the backward pass, sized for the widest block.
pub(crate) struct Work {
    /// dL/d(block output) and dL/d(block input), `[N, C_max, T]`, swapped per block.
    pub dy: Vec<f32>,
    pub dx: Vec<f32>,
    /// dA `[N, C, T]`, dG `[outs, N·T]`, d[W_f; W_g] `[outs, C·K]`, dcol `[C·K, N·T]`,
    /// dZ `[N, C, T]`.
    pub da: Vec<f32>,
    pub dg: Vec<f32>,
    pub dwcat: Vec<f32>,
    pub dcol: Vec<f32>,
    pub dz: Vec<f32>,
    /// dM and dX_t `[N, C_in, T]`, and dX_t in the taps' layout `[N, K, C_in]`.
    pub dm: Vec<f32>,
    pub dxt: Vec<f32>,
    pub taps: Vec<f32>,
    /// dQ, dΨ, dS', dS, dσ `[N, N]` or `[T, T]`.
    pub dq: Vec<f32>,
    pub dpsi: Vec<f32>,
    pub dsp: Vec<f32>,
    pub dscore: Vec<f32>,
    pub dsig: Vec<f32>,
    /// dE' `[T, T]`.
    pub de: Vec<f32>,
    /// The spatial attention's dv `[T]` and dr `[N, T]` (its v = (I + E')·W1 and
    /// r[m] = W3ᵀ·X[m], see `spatial_attention.rs`).
    pub dv: Vec<f32>,
    pub dr: Vec<f32>,
    /// Attention lhs/rhs gradients `[T, N]`/`[N, T]`, and `[C_in, T]` or `[N, C_in]`.
    pub dlhs: Vec<f32>,
    pub drhs: Vec<f32>,
    pub dred: Vec<f32>,
    /// The LayerNorm backward's per-step channel sums `[2, T]` and a node's x̂ `[C, T]`
    /// (`residual_layer_norm.rs`).
    pub ln: Vec<f32>,
    pub xhat: Vec<f32>,
    /// dγ and dβ at each (channel, step) `[2, C, T]` (`residual_layer_norm/native.rs`'s affine map).
    pub ln_params: Vec<f32>,
}

impl Work {
    pub fn new(cfg: &ModelConfig) -> Work {
        let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
        let wide = c.max(cfg.features);
        let big = t.max(n);
        let z = |len: usize| vec![0f32; len];
        Work {
            dy: z(n * wide * t),
            dx: z(n * wide * t),
            da: z(n * c * t),
            dg: z(2 * c * n * t),
            dwcat: z(2 * c * c * k),
            dcol: z(c * k * n * t),
            dz: z(n * c * t),
            dm: z(n * wide * t),
            dxt: z(n * wide * t),
            taps: z(n * wide * k),
            dq: z(n * n),
            dpsi: z(n * n),
            dsp: z(n * n),
            dscore: z(big * big),
            dsig: z(big * big),
            de: z(t * t),
            dv: z(t),
            dr: z(n * t),
            dlhs: z(t * n),
            drhs: z(n * t),
            // Also the graph attention's scratch (graph_attention::GatShape::work_len).
            dred: z((wide * big).max(n + 2 * c)),
            ln: z(2 * t),
            xhat: z(c * t),
            ln_params: z(2 * c * t),
        }
    }
}

/// One window's intermediates of the graph attention.
pub(crate) struct GatTape {
    /// Q = Wᵀ·X `[N, C, T]`.
    pub q: Vec<f32>,
    /// Each node's share of the scores, a_src·q_i then a_dst·q_i `[2, H, N, T]`.
    pub ends: Vec<f32>,
    /// The scores before the LeakyReLU (0 off the graph) and α `[T, H, N, N]`.
    pub e: Vec<f32>,
    pub alpha: Vec<f32>,
}
