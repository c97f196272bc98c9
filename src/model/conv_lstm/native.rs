//! The ConvLSTM baseline (`model::conv_lstm`, docs/model.md "Baselines") on the CPU in
//! f32, one window at a time: an LSTM whose gates are k×k "same" convolutions over the
//! node × feature grid of every step, the head on the last state, and backpropagation
//! through time by hand — the arithmetic of the f64 reference
//! `model::conv_lstm::reference`. Per step t, with x_t the grid `[1, N, F]` and h, c
//! `[C, N, F]` (zero before step 0):
//!
//! ```text
//! z = Wx·unfold(x_t) + Wh·unfold(h) + b            ([4C, N·F]: gates i, f, o, g)
//! c' = σ(z_f) ⊙ c + σ(z_i) ⊙ tanh(z_g)             h' = σ(z_o) ⊙ tanh(c')
//! ```
//!
//! Each convolution is an unfolding (`[channels·k², N·F]`, zero outside the grid) and one
//! `sgemm`; the backward recomputes each step's unfoldings, as the device does.

use crate::model::config::ModelConfig;
use crate::model::cpu::{gemm, rows, sigmoid, tanh, transposed};
use crate::model::error::ModelError;
use crate::model::head::native::{backward_rows, forward_rows};
use crate::model::params::ParamSpec;

/// ConvLSTM's shapes and where its tensors are.
pub(crate) struct ConvLstmNet {
    /// N (grid rows), F (grid columns), C, k, T, O.
    n: usize,
    f: usize,
    c: usize,
    k: usize,
    t: usize,
    o: usize,
    /// Wx `[4C, k²]`, Wh `[4C, C·k²]`, bias `[4C]`, head weight `[O, C·N·F]`, head bias.
    wx: usize,
    wh: usize,
    bias: usize,
    head: (usize, usize),
}

/// One window's forward values and the backward pass's working memory.
pub(crate) struct ConvLstmTape {
    /// x_t of every step `[T, N·F]`.
    x: Vec<f32>,
    /// The gates' pre-activations of every step `[T, 4C, N·F]`.
    z: Vec<f32>,
    /// c_t and h_t of every step `[T, C, N·F]`.
    c: Vec<f32>,
    h: Vec<f32>,
    /// ŷ `[O]`.
    out: Vec<f32>,
    /// Unfoldings `[k², N·F]` and `[C·k², N·F]`; their gradient `[C·k², N·F]`.
    col_x: Vec<f32>,
    col_h: Vec<f32>,
    d_col: Vec<f32>,
    /// ∂ℒ/∂z `[4C, N·F]`; ∂ℒ/∂h, ∂ℒ/∂c of the current step `[C, N·F]`.
    dz: Vec<f32>,
    dh: Vec<f32>,
    dc: Vec<f32>,
    /// The zero state before step 0 `[C, N·F]`.
    zeros: Vec<f32>,
}

impl ConvLstmTape {
    /// ŷ `[O]` of the last forward pass.
    pub fn output(&self) -> &[f32] {
        &self.out
    }
}

impl ConvLstmNet {
    /// `config`'s shapes and its tensors in `specs`; an error names a missing tensor.
    pub fn new(config: &ModelConfig, specs: &[ParamSpec]) -> Result<ConvLstmNet, ModelError> {
        let find = |name: &str| {
            specs
                .iter()
                .position(|s| s.name == name)
                .ok_or_else(|| ModelError::Config(format!("the parameters lack {name}")))
        };
        Ok(ConvLstmNet {
            n: config.nodes,
            f: config.features,
            c: config.channels,
            k: config.kernel,
            t: config.window,
            o: config.outputs,
            wx: find("cell.wx")?,
            wh: find("cell.wh")?,
            bias: find("cell.bias")?,
            head: (find("head.weight")?, find("head.bias")?),
        })
    }

    /// N·F: the grid's cells.
    fn grid(&self) -> usize {
        self.n * self.f
    }

    /// A tape sized for this network (the only allocations).
    pub fn tape(&self) -> ConvLstmTape {
        let (g, c, kk, t) = (self.grid(), self.c, self.k * self.k, self.t);
        let z = |len: usize| vec![0f32; len];
        ConvLstmTape {
            x: z(t * g),
            z: z(t * 4 * c * g),
            c: z(t * c * g),
            h: z(t * c * g),
            out: z(self.o),
            col_x: z(kk * g),
            col_h: z(c * kk * g),
            d_col: z(c * kk * g),
            dz: z(4 * c * g),
            dh: z(c * g),
            dc: z(c * g),
            zeros: z(c * g),
        }
    }

    /// For each unfolding row (channel, ky, kx) and grid cell (y, x): the image offset
    /// it reads, `None` outside the grid ("same" padding), as `ops::unfold2d`.
    fn source(&self, row: usize, pos: usize) -> Option<usize> {
        let (k, w, h) = (self.k, self.f, self.n);
        let (ch, ky, kx) = (row / (k * k), (row % (k * k)) / k, row % k);
        let half = k / 2;
        let y = (pos / w + ky).checked_sub(half).filter(|&y| y < h)?;
        let x = (pos % w + kx).checked_sub(half).filter(|&x| x < w)?;
        Some((ch * h + y) * w + x)
    }

    /// `col [channels·k², N·F]` of the image `[channels, N, F]`.
    fn unfold(&self, img: &[f32], col: &mut [f32]) {
        let g = self.grid();
        for (row, out) in col.chunks_exact_mut(g).enumerate() {
            for (pos, v) in out.iter_mut().enumerate() {
                *v = self.source(row, pos).map_or(0.0, |s| img[s]);
            }
        }
    }

    /// The adjoint of [`ConvLstmNet::unfold`]: `d_img = fold(d_col)` (overwritten).
    fn fold(&self, d_col: &[f32], d_img: &mut [f32]) {
        let g = self.grid();
        d_img.fill(0.0);
        for (row, col) in d_col.chunks_exact(g).enumerate() {
            for (pos, v) in col.iter().enumerate() {
                if let Some(s) = self.source(row, pos) {
                    d_img[s] += v;
                }
            }
        }
    }

    /// The forward pass of one standardised window `x` `[N, F, T]` into `tape`.
    pub fn forward(&self, params: &[Vec<f32>], x: &[f32], tape: &mut ConvLstmTape) {
        let (g, c, t) = (self.grid(), self.c, self.t);
        let (kk, m) = (self.k * self.k, c * g);
        for (cell, row) in x.chunks_exact(t).enumerate() {
            for (step, &v) in row.iter().enumerate() {
                tape.x[step * g + cell] = v;
            }
        }
        let (wx, wh, bias) = (&params[self.wx], &params[self.wh], &params[self.bias]);
        for step in 0..t {
            let (c_done, c_rest) = tape.c.split_at_mut(step * m);
            let (h_done, h_rest) = tape.h.split_at_mut(step * m);
            let (h_prev, c_prev): (&[f32], &[f32]) = if step == 0 {
                (&tape.zeros, &tape.zeros)
            } else {
                (&h_done[(step - 1) * m..], &c_done[(step - 1) * m..])
            };
            self.unfold(&tape.x[step * g..][..g], &mut tape.col_x);
            self.unfold(h_prev, &mut tape.col_h);
            let z = &mut tape.z[step * 4 * m..][..4 * m];
            gemm(4 * c, kk, g, rows(wx, kk), rows(&tape.col_x, g), 0.0, z, g);
            gemm(
                4 * c,
                c * kk,
                g,
                rows(wh, c * kk),
                rows(&tape.col_h, g),
                1.0,
                z,
                g,
            );
            for (row, b) in z.chunks_exact_mut(g).zip(bias) {
                for v in row.iter_mut() {
                    *v += b;
                }
            }
            let (zi, rest) = z.split_at(m);
            let (zf, rest) = rest.split_at(m);
            let (zo, zg) = rest.split_at(m);
            let (cs, hs) = (&mut c_rest[..m], &mut h_rest[..m]);
            for j in 0..m {
                let cell = sigmoid(zf[j]) * c_prev[j] + sigmoid(zi[j]) * tanh(zg[j]);
                cs[j] = cell;
                hs[j] = sigmoid(zo[j]) * tanh(cell);
            }
        }
        let last = &tape.h[(t - 1) * m..];
        forward_rows(params, self.head, last, &mut tape.out);
    }

    /// Adds ∂L/∂ every parameter to `grads` (`param_specs` order) for the upstream
    /// gradient `dout` `[O]` of the window whose forward pass is in `tape`.
    pub fn backward(
        &self,
        params: &[Vec<f32>],
        tape: &mut ConvLstmTape,
        dout: &[f32],
        grads: &mut [Vec<f32>],
    ) {
        let (g, c, t) = (self.grid(), self.c, self.t);
        let (kk, m) = (self.k * self.k, c * g);
        let last = &tape.h[(t - 1) * m..];
        backward_rows(params, self.head, last, dout, grads, &mut tape.dh);
        tape.dc.fill(0.0);
        for step in (0..t).rev() {
            let (h_prev, c_prev): (&[f32], &[f32]) = if step == 0 {
                (&tape.zeros, &tape.zeros)
            } else {
                (
                    &tape.h[(step - 1) * m..step * m],
                    &tape.c[(step - 1) * m..step * m],
                )
            };
            // The cell: ∂ℒ/∂z from ∂ℒ/∂h' and ∂ℒ/∂c'; ∂ℒ/∂c_prev into dc.
            let z = &tape.z[step * 4 * m..][..4 * m];
            let (dzi, rest) = tape.dz.split_at_mut(m);
            let (dzf, rest) = rest.split_at_mut(m);
            let (dzo, dzg) = rest.split_at_mut(m);
            for j in 0..m {
                let (i, f) = (sigmoid(z[j]), sigmoid(z[m + j]));
                let (o, gg) = (sigmoid(z[2 * m + j]), tanh(z[3 * m + j]));
                let tc = tanh(tape.c[step * m + j]);
                let dh = tape.dh[j];
                let dc = tape.dc[j] + dh * o * (1.0 - tc * tc);
                dzi[j] = dc * gg * i * (1.0 - i);
                dzf[j] = dc * c_prev[j] * f * (1.0 - f);
                dzo[j] = dh * tc * o * (1.0 - o);
                dzg[j] = dc * i * (1.0 - gg * gg);
                tape.dc[j] = dc * f;
            }
            for (db, row) in grads[self.bias].iter_mut().zip(tape.dz.chunks_exact(g)) {
                *db += row.iter().sum::<f32>();
            }
            // dWx += dz·col_xᵀ, dWh += dz·col_hᵀ (the unfoldings recomputed).
            self.unfold(&tape.x[step * g..][..g], &mut tape.col_x);
            self.unfold(h_prev, &mut tape.col_h);
            let dz = &tape.dz;
            gemm(
                4 * c,
                g,
                kk,
                rows(dz, g),
                transposed(&tape.col_x, g),
                1.0,
                &mut grads[self.wx],
                kk,
            );
            gemm(
                4 * c,
                g,
                c * kk,
                rows(dz, g),
                transposed(&tape.col_h, g),
                1.0,
                &mut grads[self.wh],
                c * kk,
            );
            // ∂ℒ/∂h_prev = fold(Whᵀ·dz).
            gemm(
                c * kk,
                4 * c,
                g,
                transposed(&params[self.wh], c * kk),
                rows(dz, g),
                0.0,
                &mut tape.d_col,
                g,
            );
            self.fold(&tape.d_col, &mut tape.dh);
        }
    }
}
