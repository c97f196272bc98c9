//! Multi-head graph attention (GAT) over the nodes of every window and step, the spatial
//! layer of the ST-GAT baseline (docs/model.md "Baselines"), forward and backward, with
//! the f64 CPU reference.
//!
//! `q` is `[B, N, C, T]`; head h owns channels h·C/H .. (h+1)·C/H. With `mask[i, j] = 1`
//! where node j is a neighbour of i (self loops included):
//!
//! ```text
//! e_ij = LeakyReLU(a_src·q_i + a_dst·q_j)     (the head's channels, one step t)
//! α_ij = softmax over the neighbours j of e_ij  (0 off the mask), α `[B, T, H, N, N]`
//! out_i = Σ_j α_ij q_j                          (channel by channel)
//! ```

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/graph_attention.wgsl`).
pub static SHADER: Shader = Shader {
    name: "graph_attention",
    source: include_str!("../../../../shaders/graph_attention.wgsl"),
    base: None,
};

static WEIGHTS: Kernel = Kernel {
    shader: &SHADER,
    entry: "gat_weights",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(4),
        Binding::read_write(5),
    ],
};
static AGGREGATE: Kernel = Kernel {
    shader: &SHADER,
    entry: "gat_aggregate",
    bindings: &[Binding::read(1), Binding::read(5), Binding::read_write(6)],
};
static BACKWARD_SCORES: Kernel = Kernel {
    shader: &SHADER,
    entry: "gat_backward_scores",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(4),
        Binding::read(5),
        Binding::read(6),
        Binding::read_write(7),
    ],
};
static BACKWARD_VALUES: Kernel = Kernel {
    shader: &SHADER,
    entry: "gat_backward_values",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(5),
        Binding::read(6),
        Binding::read(7),
        Binding::read_write(8),
    ],
};
static BACKWARD_PARAMS: Kernel = Kernel {
    shader: &SHADER,
    entry: "gat_backward_params",
    bindings: &[Binding::read(1), Binding::read(7), Binding::read_write(8)],
};

/// Invocations per workgroup of the element-wise kernels.
const WORKGROUP: u32 = 64;

/// The slope of the LeakyReLU on the scores (as in Veličković et al.'s GAT).
pub const SLOPE: f32 = 0.2;

crate::gpu::uniform! {
    pub(crate) struct Params = GatParams in SHADER {
        batch: u32,
        nodes: u32,
        channels: u32,
        steps: u32,
        heads: u32,
        accumulate: u32,
        slope: f32,
        _pad: u32,
    }
}

/// The shape of one graph attention.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GraphAttention {
    /// B: windows.
    pub batch: usize,
    /// N: nodes.
    pub nodes: usize,
    /// C: channels of q and of the output (a multiple of `heads`).
    pub channels: usize,
    /// T: steps, each attended on its own.
    pub steps: usize,
    /// H: heads, each over C/H channels.
    pub heads: usize,
}

impl GraphAttention {
    /// Elements of q and of the output, `B·N·C·T`.
    pub fn values(&self) -> usize {
        self.batch * self.nodes * self.channels * self.steps
    }

    /// Elements of α and of the score gradient, `B·T·H·N·N`.
    pub fn weights(&self) -> usize {
        self.batch * self.steps * self.heads * self.nodes * self.nodes
    }

    /// Rows of α: one thread each in the weight kernels.
    fn rows(&self) -> usize {
        self.batch * self.steps * self.heads * self.nodes
    }

    fn params(&self, accumulate: Accumulate) -> Result<Params, GpuError> {
        if self.heads == 0 || !self.channels.is_multiple_of(self.heads) {
            return Err(GpuError::Shape {
                tensor: "graph attention heads".into(),
                expected: format!("a divisor of the {} channels", self.channels),
                got: self.heads.to_string(),
            });
        }
        Ok(Params {
            batch: self.batch as u32,
            nodes: self.nodes as u32,
            channels: self.channels as u32,
            steps: self.steps as u32,
            heads: self.heads as u32,
            accumulate: accumulate.flag(),
            slope: SLOPE,
            _pad: 0,
        })
    }

    fn grid(&self, gpu: &Gpu, threads: usize) -> [u32; 3] {
        grid_1d(
            threads,
            WORKGROUP,
            gpu.limits().max_compute_workgroups_per_dimension,
        )
    }

    fn check_inputs(
        &self,
        q: &Tensor,
        a_src: &Tensor,
        a_dst: &Tensor,
        mask: &Tensor,
    ) -> Result<(), GpuError> {
        q.expect_len(self.values())?;
        a_src.expect_len(self.channels)?;
        a_dst.expect_len(self.channels)?;
        mask.expect_len(self.nodes * self.nodes)
    }

    /// α `[B, T, H, N, N]` (overwritten) from q and the attention vectors; `mask` `[N, N]`
    /// is 1 on the edges and the diagonal, 0 elsewhere.
    pub fn attention_weights(
        &self,
        gpu: &Gpu,
        q: &Tensor,
        a_src: &Tensor,
        a_dst: &Tensor,
        mask: &Tensor,
        alpha: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        self.check_inputs(q, a_src, a_dst, mask)?;
        alpha.expect_len(self.weights())?;
        alpha.expect_distinct([q, a_src, a_dst, mask])?;
        let params = self.params(Accumulate::Overwrite)?;
        let tensors = [q, a_src, a_dst, mask, alpha];
        gpu.dispatch(
            &WEIGHTS,
            &[],
            &params,
            &tensors,
            self.grid(gpu, self.rows()),
        )
    }

    /// `out (+)= Σ_j α_ij q_j` per channel and step.
    pub fn aggregate(
        &self,
        gpu: &Gpu,
        q: &Tensor,
        alpha: &Tensor,
        out: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        q.expect_len(self.values())?;
        alpha.expect_len(self.weights())?;
        out.expect_len(self.values())?;
        out.expect_distinct([q, alpha])?;
        let params = self.params(accumulate)?;
        let grid = self.grid(gpu, self.values());
        gpu.dispatch(&AGGREGATE, &[], &params, &[q, alpha, out], grid)
    }

    /// The backward pass from `d_out` (∂ℒ/∂out): `d_score` `[B, T, H, N, N]` (scratch,
    /// overwritten: ∂ℒ/∂ of the pre-LeakyReLU scores), `d_q` (+)= ∂ℒ/∂q through the values
    /// and the scores, and `d_a` `[2C]` (+)= [∂ℒ/∂a_src; ∂ℒ/∂a_dst]. Three dispatches.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        gpu: &Gpu,
        [q, a_src, a_dst, mask]: [&Tensor; 4],
        alpha: &Tensor,
        d_out: &Tensor,
        d_score: &Tensor,
        d_q: &Tensor,
        d_a: &Tensor,
        accumulate: Accumulate,
    ) -> Result<[Dispatch; 3], GpuError> {
        self.check_inputs(q, a_src, a_dst, mask)?;
        alpha.expect_len(self.weights())?;
        d_out.expect_len(self.values())?;
        d_score.expect_len(self.weights())?;
        d_q.expect_len(self.values())?;
        d_a.expect_len(2 * self.channels)?;
        for written in [d_score, d_q, d_a] {
            written.expect_distinct([q, a_src, a_dst, mask, alpha, d_out])?;
        }
        let overwrite = self.params(Accumulate::Overwrite)?;
        let params = self.params(accumulate)?;
        let scores = gpu.dispatch(
            &BACKWARD_SCORES,
            &[],
            &overwrite,
            &[q, a_src, a_dst, mask, alpha, d_out, d_score],
            self.grid(gpu, self.rows()),
        )?;
        let values = gpu.dispatch(
            &BACKWARD_VALUES,
            &[],
            &params,
            &[q, a_src, a_dst, alpha, d_out, d_score, d_q],
            self.grid(gpu, self.values()),
        )?;
        let vectors = gpu.dispatch(
            &BACKWARD_PARAMS,
            &[],
            &params,
            &[q, d_score, d_a],
            [self.channels as u32, 2, 1],
        )?;
        Ok([scores, values, vectors])
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::{GraphAttention, SLOPE};

    fn at(g: &GraphAttention, b: usize, n: usize, c: usize, t: usize) -> usize {
        ((b * g.nodes + n) * g.channels + c) * g.steps + t
    }

    fn row(g: &GraphAttention, b: usize, t: usize, h: usize, i: usize) -> usize {
        (((b * g.steps + t) * g.heads + h) * g.nodes + i) * g.nodes
    }

    /// a·q_n over head h's channels at (b, t).
    fn head_dot(
        g: &GraphAttention,
        a: &[f64],
        q: &[f64],
        b: usize,
        n: usize,
        h: usize,
        t: usize,
    ) -> f64 {
        let w = g.channels / g.heads;
        (h * w..(h + 1) * w)
            .map(|c| a[c] * q[at(g, b, n, c, t)])
            .sum()
    }

    /// The scores before the LeakyReLU, `[B, T, H, N, N]` (0 off the mask).
    fn scores(
        g: &GraphAttention,
        q: &[f64],
        a_src: &[f64],
        a_dst: &[f64],
        mask: &[f64],
    ) -> Vec<f64> {
        let n = g.nodes;
        let mut e = vec![0.0; g.weights()];
        for b in 0..g.batch {
            for t in 0..g.steps {
                for h in 0..g.heads {
                    for i in 0..n {
                        let s = head_dot(g, a_src, q, b, i, h, t);
                        for j in (0..n).filter(|&j| mask[i * n + j] > 0.5) {
                            e[row(g, b, t, h, i) + j] = s + head_dot(g, a_dst, q, b, j, h, t);
                        }
                    }
                }
            }
        }
        e
    }

    fn leaky(x: f64) -> f64 {
        if x > 0.0 {
            x
        } else {
            SLOPE as f64 * x
        }
    }

    /// (α `[B, T, H, N, N]`, out `[B, N, C, T]`).
    pub fn forward(
        g: &GraphAttention,
        q: &[f64],
        a_src: &[f64],
        a_dst: &[f64],
        mask: &[f64],
    ) -> (Vec<f64>, Vec<f64>) {
        let n = g.nodes;
        let e = scores(g, q, a_src, a_dst, mask);
        let mut alpha = vec![0.0; g.weights()];
        for (r, out) in alpha.chunks_mut(n).enumerate() {
            let i = r % n;
            let on: Vec<usize> = (0..n).filter(|&j| mask[i * n + j] > 0.5).collect();
            let m = on
                .iter()
                .map(|&j| leaky(e[r * n + j]))
                .fold(f64::NEG_INFINITY, f64::max);
            let z: f64 = on.iter().map(|&j| (leaky(e[r * n + j]) - m).exp()).sum();
            for &j in &on {
                out[j] = (leaky(e[r * n + j]) - m).exp() / z;
            }
        }
        let w = g.channels / g.heads;
        let mut out = vec![0.0; g.values()];
        for b in 0..g.batch {
            for i in 0..n {
                for c in 0..g.channels {
                    for t in 0..g.steps {
                        let r = row(g, b, t, c / w, i);
                        out[at(g, b, i, c, t)] =
                            (0..n).map(|j| alpha[r + j] * q[at(g, b, j, c, t)]).sum();
                    }
                }
            }
        }
        (alpha, out)
    }

    /// (∂ℒ/∂q, ∂ℒ/∂a_src, ∂ℒ/∂a_dst) from ∂ℒ/∂out.
    pub fn backward(
        g: &GraphAttention,
        q: &[f64],
        a_src: &[f64],
        a_dst: &[f64],
        mask: &[f64],
        d_out: &[f64],
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let n = g.nodes;
        let w = g.channels / g.heads;
        let (alpha, _) = forward(g, q, a_src, a_dst, mask);
        let e = scores(g, q, a_src, a_dst, mask);
        let mut dq = vec![0.0; g.values()];
        let (mut da_src, mut da_dst) = (vec![0.0; g.channels], vec![0.0; g.channels]);
        for b in 0..g.batch {
            for t in 0..g.steps {
                for h in 0..g.heads {
                    let chans = h * w..(h + 1) * w;
                    for i in 0..n {
                        let r = row(g, b, t, h, i);
                        // Values: out_i = Σ_j α_ij q_j.
                        let da: Vec<f64> = (0..n)
                            .map(|j| {
                                chans
                                    .clone()
                                    .map(|c| {
                                        dq[at(g, b, j, c, t)] +=
                                            alpha[r + j] * d_out[at(g, b, i, c, t)];
                                        d_out[at(g, b, i, c, t)] * q[at(g, b, j, c, t)]
                                    })
                                    .sum()
                            })
                            .collect();
                        // Softmax, LeakyReLU, then the two dot products of the score.
                        let dot: f64 = (0..n).map(|j| alpha[r + j] * da[j]).sum();
                        for j in (0..n).filter(|&j| mask[i * n + j] > 0.5) {
                            let de = alpha[r + j] * (da[j] - dot);
                            let ds = if e[r + j] > 0.0 {
                                de
                            } else {
                                SLOPE as f64 * de
                            };
                            for c in chans.clone() {
                                dq[at(g, b, i, c, t)] += ds * a_src[c];
                                dq[at(g, b, j, c, t)] += ds * a_dst[c];
                                da_src[c] += ds * q[at(g, b, i, c, t)];
                                da_dst[c] += ds * q[at(g, b, j, c, t)];
                            }
                        }
                    }
                }
            }
        }
        (dq, da_src, da_dst)
    }
}
