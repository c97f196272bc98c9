//! Step 3 in f64: the graph convolution (eq. 29; Chebyshev basis in `iastgcn-s`),
//! forward and backward.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use crate::model::block::exact::{channel_mix, channel_mix_backward, BlockParams, Dims};
use crate::model::exact::{axpy, dot, row, row_mut, Grads};

/// Ψ[i,j] = Σ_k θ_k·basis[k,i,j].
pub(crate) fn graph_kernel(nn: usize, basis: &[f64], theta: &[f64]) -> Vec<f64> {
    let mut psi = vec![0.0; nn * nn];
    for (k, &th) in theta.iter().enumerate() {
        axpy(&mut psi, th, row(basis, k, nn * nn));
    }
    psi
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
