//! Step 3: the graph convolution (eq. 29; Chebyshev basis in `iastgcn-s`), or the
//! multi-head graph attention of `st-gat` (`ops::graph_attention::cpu`).

use super::{axpy, dot, row, row_mut, BlockParams, Dims, Grads};
use crate::ops::graph_attention::{cpu as gat, GraphAttention};

/// Ψ[i,j] = Σ_k θ_k·basis[k,i,j].
pub(crate) fn graph_kernel(nn: usize, basis: &[f64], theta: &[f64]) -> Vec<f64> {
    let mut psi = vec![0.0; nn * nn];
    for (k, &th) in theta.iter().enumerate() {
        axpy(&mut psi, th, row(basis, k, nn * nn));
    }
    psi
}

/// Q = X_s·W over channels: `Q[b,j,o,t] = Σ_c X_s[b,j,c,t]·W[c,o]`.
fn channel_mix(d: &Dims, w: &[f64], xs: &[f64]) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut q = vec![0.0; nb * nn * nc * nt];
    for b in 0..nb {
        for j in 0..nn {
            for o in 0..nc {
                let qr = row_mut(&mut q, d.r(nc, b, j, o), nt);
                for c in 0..ci {
                    axpy(qr, w[c * nc + o], row(xs, d.r(ci, b, j, c), nt));
                }
            }
        }
    }
    q
}

/// Backward of [`channel_mix`] from dQ: returns dL/dX_s and adds dW to `grads`.
fn channel_mix_backward(
    d: &Dims,
    p: &BlockParams,
    xs: &[f64],
    dq: &[f64],
    grads: &mut Grads,
    name: &str,
) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut dw = vec![0.0; ci * nc];
    let mut dxs = vec![0.0; xs.len()];
    for b in 0..nb {
        for j in 0..nn {
            for o in 0..nc {
                let gr = row(dq, d.r(nc, b, j, o), nt);
                for c in 0..ci {
                    let r = d.r(ci, b, j, c);
                    dw[c * nc + o] += dot(row(xs, r, nt), gr);
                    axpy(row_mut(&mut dxs, r, nt), p.w[c * nc + o], gr);
                }
            }
        }
    }
    grads.add(&p.name(name), &dw);
    dxs
}

/// Q = X_s·W (channels), Z = ReLU(Ψ·Q) (nodes). Returns (Q, Z).
pub(crate) fn graph_conv(d: &Dims, psi: &[f64], w: &[f64], xs: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let (nb, nn, ct) = (d.b, d.n, d.c * d.t);
    let q = channel_mix(d, w, xs);
    let mut z = vec![0.0; nb * nn * ct];
    for b in 0..nb {
        for i in 0..nn {
            let zr = row_mut(&mut z, b * nn + i, ct);
            for j in 0..nn {
                axpy(zr, psi[i * nn + j], row(&q, b * nn + j, ct));
            }
            for v in zr.iter_mut() {
                *v = v.max(0.0);
            }
        }
    }
    (q, z)
}

/// The graph attention of `st-gat` on `heads` heads.
fn attention_shape(d: &Dims, heads: usize) -> GraphAttention {
    GraphAttention {
        batch: d.b,
        nodes: d.n,
        channels: d.c,
        steps: d.t,
        heads,
    }
}

/// `st-gat`'s step 3: Q = X_s·W (channels), Z = ReLU(GAT(Q)) with the neighbour `mask`
/// `[N,N]`. Returns (Q, Z).
pub(crate) fn graph_attention(
    d: &Dims,
    heads: usize,
    mask: &[f64],
    p: &BlockParams,
    xs: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    // invariant: called only for the st-gat variant, whose parameters include them.
    let (a_src, a_dst) = p.attention_vectors.expect("st-gat has attention vectors");
    let q = channel_mix(d, p.w, xs);
    let (_, g) = gat::forward(&attention_shape(d, heads), &q, a_src, a_dst, mask);
    (q, g.into_iter().map(|v| v.max(0.0)).collect())
}

/// Backward of [`graph_attention`]: returns dL/dX_s and adds dW, da_src, da_dst.
#[allow(clippy::too_many_arguments)]
pub(crate) fn graph_attention_backward(
    d: &Dims,
    heads: usize,
    mask: &[f64],
    p: &BlockParams,
    q: &[f64],
    z: &[f64],
    xs: &[f64],
    dz: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    // invariant: called only for the st-gat variant, whose parameters include them.
    let (a_src, a_dst) = p.attention_vectors.expect("st-gat has attention vectors");
    let dg: Vec<f64> = dz
        .iter()
        .zip(z)
        .map(|(&g, &z)| if z > 0.0 { g } else { 0.0 })
        .collect();
    let (dq, da_src, da_dst) =
        gat::backward(&attention_shape(d, heads), q, a_src, a_dst, mask, &dg);
    grads.add(&p.name("gat.a_src"), &da_src);
    grads.add(&p.name("gat.a_dst"), &da_dst);
    channel_mix_backward(d, p, xs, &dq, grads, "gat.W")
}

/// Backward of step 3: returns dL/dX_s and adds dθ, dW to `grads`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn graph_conv_backward(
    d: &Dims,
    basis: &[f64],
    p: &BlockParams,
    psi: &[f64],
    q: &[f64],
    z: &[f64],
    xs: &[f64],
    dz: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    let (nb, nn, ct) = (d.b, d.n, d.c * d.t);
    // ReLU.
    let dg: Vec<f64> = dz
        .iter()
        .zip(z)
        .map(|(&g, &z)| if z > 0.0 { g } else { 0.0 })
        .collect();
    // G = Ψ·Q over nodes; Ψ = Σ_k θ_k basis_k.
    let mut dpsi = vec![0.0; nn * nn];
    let mut dq = vec![0.0; q.len()];
    for b in 0..nb {
        for i in 0..nn {
            let gi = row(&dg, b * nn + i, ct);
            for j in 0..nn {
                dpsi[i * nn + j] += dot(gi, row(q, b * nn + j, ct));
                axpy(row_mut(&mut dq, b * nn + j, ct), psi[i * nn + j], gi);
            }
        }
    }
    let dtheta: Vec<f64> = (0..p.theta.len())
        .map(|k| dot(&dpsi, row(basis, k, nn * nn)))
        .collect();
    grads.add(&p.name("gwc.theta"), &dtheta);
    // Q = X_s·W over channels.
    channel_mix_backward(d, p, xs, &dq, grads, "gwc.W")
}
