//! `st-gat`'s step 3 on the CPU in f32, forward and backward side by side: in place of Ψ
//! and the two attentions, Q = Wᵀ·X per node, then on every head and step a graph
//! attention over the graph's edges, e_ij = a_src·q_i + a_dst·q_j, α_i = softmax over
//! j of LeakyReLU(e_ij), Z_i = ReLU(Σ_j α_ij·q_j) (`graph_attention::kernel`'s CPU reference,
//! in the block's `[N, C, T]` layout).

use crate::model::block::graph_attention::kernel::SLOPE;
use crate::model::block::native::Block;
use crate::model::block::slots::GatShape;
use crate::model::block::tape::{BlockTape, GatTape, Work};
use crate::model::cpu::{exp, gemm, rows, transposed};

impl Block<'_> {
    /// `st-gat`'s step 3 forward on this block: Z from the block input, the graph's
    /// edges its mask.
    pub(crate) fn graph_attention_forward(&self, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
        // invariant: the composition calls it only for st-gat, whose slots and tape have it.
        let (shape, tape) = (
            self.s.gat.expect("st-gat"),
            bt.gat.as_mut().expect("st-gat"),
        );
        shape.forward(p, self.basis, x, tape, &mut bt.z);
    }

    /// `st-gat`'s step 3 backward on this block from dG (`w.dz`, past Z's ReLU): the
    /// graph attention's gradients, and dX added into `w.dx` when `need_dx`.
    pub(crate) fn graph_attention_backward(
        &self,
        p: &[Vec<f32>],
        x: &[f32],
        bt: &BlockTape,
        need_dx: bool,
        grads: &mut [Vec<f32>],
        w: &mut Work,
    ) {
        // invariant: the composition calls it only for st-gat, whose slots and tape have it.
        let (shape, tape) = (
            self.s.gat.expect("st-gat"),
            bt.gat.as_ref().expect("st-gat"),
        );
        let (n, ci, t, c) = (self.n, self.ci, self.t, self.c);
        let dz = &w.dz[..n * c * bt.cols.len];
        let dx = if need_dx {
            Some(&mut w.dx[..n * ci * t])
        } else {
            None
        };
        let dq = &mut w.dm[..n * c * t];
        let work = &mut w.dred[..shape.work_len()];
        shape.backward(p, self.basis, x, tape, dz, dq, dx, grads, work);
    }
}

impl GatShape {
    pub fn tape(&self) -> GatTape {
        let (n, c, t, h) = (self.nodes, self.channels, self.steps, self.heads);
        GatTape {
            q: vec![0f32; n * c * t],
            ends: vec![0f32; 2 * h * n * t],
            e: vec![0f32; t * h * n * n],
            alpha: vec![0f32; t * h * n * n],
        }
    }

    /// Scratch of [`GatShape::backward`]: dα's row and the two score vectors' gradients.
    pub fn work_len(&self) -> usize {
        self.nodes + 2 * self.channels
    }

    /// Row of α and e for (step, head, node i).
    fn row(&self, t: usize, h: usize, i: usize) -> usize {
        ((t * self.heads + h) * self.nodes + i) * self.nodes
    }

    /// Z `[N, C, T]` from the block input `x` `[N, C_in, T]`; `mask` `[N, N]` is the
    /// graph's edges (> 0.5).
    pub fn forward(&self, p: &[Vec<f32>], mask: &[f32], x: &[f32], g: &mut GatTape, z: &mut [f32]) {
        let (n, ci, c, t, heads) = (self.nodes, self.c_in, self.channels, self.steps, self.heads);
        let width = c / heads;
        for (i, qi) in g.q.chunks_mut(c * t).enumerate() {
            let xi = &x[i * ci * t..][..ci * t];
            gemm(c, ci, t, transposed(&p[self.w], c), rows(xi, t), 0.0, qi, t);
        }
        let (src, dst) = g.ends.split_at_mut(heads * n * t);
        for (a, ends) in [(&p[self.a_src], src), (&p[self.a_dst], dst)] {
            ends.fill(0.0);
            for (hi, e) in ends.chunks_mut(t).enumerate() {
                let (h, i) = (hi / n, hi % n);
                let head = h * width..(h + 1) * width;
                for (ch, &ac) in head.clone().zip(&a[head]) {
                    let qc = &g.q[(i * c + ch) * t..][..t];
                    for (v, q) in e.iter_mut().zip(qc) {
                        *v += ac * q;
                    }
                }
            }
        }
        let (src, dst) = g.ends.split_at(heads * n * t);
        for s in 0..t {
            for h in 0..heads {
                for i in 0..n {
                    let r = self.row(s, h, i);
                    let on = |j: usize| mask[i * n + j] > 0.5;
                    let mut top = f32::NEG_INFINITY;
                    for j in 0..n {
                        let e = if on(j) {
                            src[(h * n + i) * t + s] + dst[(h * n + j) * t + s]
                        } else {
                            0.0
                        };
                        g.e[r + j] = e;
                        if on(j) {
                            top = top.max(leaky(e));
                        }
                    }
                    let mut sum = 0.0;
                    for j in 0..n {
                        let a = if on(j) {
                            exp(leaky(g.e[r + j]) - top)
                        } else {
                            0.0
                        };
                        g.alpha[r + j] = a;
                        sum += a;
                    }
                    if sum > 0.0 {
                        for a in &mut g.alpha[r..r + n] {
                            *a /= sum;
                        }
                    }
                }
            }
        }
        for (ic, zr) in z.chunks_mut(t).enumerate() {
            let (i, ch) = (ic / c, ic % c);
            let h = ch / width;
            for (s, v) in zr.iter_mut().enumerate() {
                let r = self.row(s, h, i);
                let sum: f32 = (0..n)
                    .map(|j| g.alpha[r + j] * g.q[(j * c + ch) * t + s])
                    .sum();
                *v = sum.max(0.0);
            }
        }
    }

    /// From `dz` = dL/dZ with Z's ReLU already applied: adds dW, da_src and da_dst to
    /// `grads`, leaves dQ `[N, C, T]` in `dq`, and adds dL/dX into `dx` when given.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        p: &[Vec<f32>],
        mask: &[f32],
        x: &[f32],
        g: &GatTape,
        dz: &[f32],
        dq: &mut [f32],
        dx: Option<&mut [f32]>,
        grads: &mut [Vec<f32>],
        work: &mut [f32],
    ) {
        let (n, ci, c, t, heads) = (self.nodes, self.c_in, self.channels, self.steps, self.heads);
        let width = c / heads;
        let (a_src, a_dst) = (&p[self.a_src], &p[self.a_dst]);
        let (da, dvec) = work.split_at_mut(n);
        let (da_src, da_dst) = dvec.split_at_mut(c);
        da_src.fill(0.0);
        da_dst.fill(0.0);
        dq.fill(0.0);
        let at = |i: usize, ch: usize, s: usize| (i * c + ch) * t + s;
        for s in 0..t {
            for h in 0..heads {
                let chans = h * width..(h + 1) * width;
                for i in 0..n {
                    let r = self.row(s, h, i);
                    // Values: Z_i = Σ_j α_ij q_j.
                    for (j, d) in da.iter_mut().enumerate() {
                        let mut acc = 0.0;
                        for ch in chans.clone() {
                            let gz = dz[at(i, ch, s)];
                            dq[at(j, ch, s)] += g.alpha[r + j] * gz;
                            acc += gz * g.q[at(j, ch, s)];
                        }
                        *d = acc;
                    }
                    // The softmax, the LeakyReLU, then the score's two dot products.
                    let dot: f32 = (0..n).map(|j| g.alpha[r + j] * da[j]).sum();
                    for j in (0..n).filter(|&j| mask[i * n + j] > 0.5) {
                        let de = g.alpha[r + j] * (da[j] - dot);
                        let ds = if g.e[r + j] > 0.0 { de } else { SLOPE * de };
                        for ch in chans.clone() {
                            dq[at(i, ch, s)] += ds * a_src[ch];
                            dq[at(j, ch, s)] += ds * a_dst[ch];
                            da_src[ch] += ds * g.q[at(i, ch, s)];
                            da_dst[ch] += ds * g.q[at(j, ch, s)];
                        }
                    }
                }
            }
        }
        for (v, d) in grads[self.a_src].iter_mut().zip(da_src.iter()) {
            *v += d;
        }
        for (v, d) in grads[self.a_dst].iter_mut().zip(da_dst.iter()) {
            *v += d;
        }
        // Q_i = Wᵀ·X_i: dW += X_i·dQ_iᵀ, dX_i += W·dQ_i.
        for i in 0..n {
            let xi = &x[i * ci * t..][..ci * t];
            let dqi = &dq[i * c * t..][..c * t];
            gemm(
                ci,
                t,
                c,
                rows(xi, t),
                transposed(dqi, t),
                1.0,
                &mut grads[self.w],
                c,
            );
        }
        if let Some(dx) = dx {
            for i in 0..n {
                let dqi = &dq[i * c * t..][..c * t];
                let dxi = &mut dx[i * ci * t..][..ci * t];
                gemm(ci, c, t, rows(&p[self.w], c), rows(dqi, t), 1.0, dxi, t);
            }
        }
    }
}

fn leaky(x: f32) -> f32 {
    if x > 0.0 {
        x
    } else {
        SLOPE * x
    }
}
