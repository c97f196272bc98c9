//! Step 2 in f64: the spatial attention (eq. 32–34), forward and backward, with the
//! softmax over nodes that only it uses.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use crate::model::block::exact::{BlockParams, Dims};
use crate::model::exact::{axpy, dot, row, row_mut, score_gate_backward, sigmoid, Grads};

/// The spatial attention's parameters of one block (W1, W2, W3, bs, Vs).
pub(crate) struct SpatialParams<'a> {
    pub(crate) w1: &'a [f64],
    pub(crate) w2: &'a [f64],
    pub(crate) w3: &'a [f64],
    pub(crate) bs: &'a [f64],
    pub(crate) vs: &'a [f64],
}

impl<'a> SpatialParams<'a> {
    /// Block `p`'s spatial-attention parameters.
    pub(crate) fn of(p: &BlockParams<'a>) -> SpatialParams<'a> {
        SpatialParams {
            w1: p.get("sat.W1"),
            w2: p.get("sat.W2"),
            w3: p.get("sat.W3"),
            bs: p.get("sat.bs"),
            vs: p.get("sat.Vs"),
        }
    }
}

/// Step 2 intermediates (eq. 32–34).
#[derive(Clone, Debug)]
pub struct SpatialAttention {
    /// `Σ_u X_t[b,n,c,u]·W1[u]` `[B,N,C_in]`.
    pub xw1: Vec<f64>,
    /// lhs `[B,N,T]`.
    pub lhs: Vec<f64>,
    /// rhs, stored transposed as `[B,N,T]` (`rhs[b,t,m]` of docs/model.md at `[b,m,t]`).
    pub rhs: Vec<f64>,
    /// σ(P + bs) `[B,N,N]`.
    pub sig: Vec<f64>,
    /// S = Vs·σ(P + bs) `[B,N,N]`.
    pub scores: Vec<f64>,
    /// S' = softmax of S over j `[B,N,N]`.
    pub weights: Vec<f64>,
    /// X_s `[B,N,C_in,T]`.
    pub output: Vec<f64>,
}

/// Softmax over the last index of each row of length `len` (step 2).
fn softmax_rows(s: &[f64], len: usize) -> Vec<f64> {
    let mut w = s.to_vec();
    for r in w.chunks_exact_mut(len) {
        let max = r.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut sum = 0.0;
        for v in r.iter_mut() {
            *v = (*v - max).exp();
            sum += *v;
        }
        for v in r.iter_mut() {
            *v /= sum;
        }
    }
    w
}

/// Backward of [`softmax_rows`]: dS = S' ⊙ (dS' − Σ_k S'[·,k]·dS'[·,k]).
fn softmax_rows_backward(w: &[f64], dw: &[f64], len: usize) -> Vec<f64> {
    let mut ds = vec![0.0; w.len()];
    for ((dr, wr), gr) in ds
        .chunks_exact_mut(len)
        .zip(w.chunks_exact(len))
        .zip(dw.chunks_exact(len))
    {
        let s = dot(wr, gr);
        for ((d, w), g) in dr.iter_mut().zip(wr).zip(gr) {
            *d = w * (g - s);
        }
    }
    ds
}

// ---------------------------------------------------------------------------------------
// Step 2: spatial attention (eq. 32–34).

/// lhs = (X_t·W1)·W2, rhs = W3·X_t, P = lhs·rhs, S = Vs·σ(P + bs), S' = softmax over j,
/// X_s = (S' + I)·X_t.
pub(crate) fn spatial_attention(d: &Dims, xt: &[f64], p: &SpatialParams) -> SpatialAttention {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let mut xw1 = vec![0.0; nb * nn * ci];
    let mut lhs = vec![0.0; nb * nn * nt];
    let mut rhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let xr = row(xt, d.r(ci, b, n, c), nt);
                let v = dot(xr, p.w1);
                xw1[(b * nn + n) * ci + c] = v;
                axpy(row_mut(&mut lhs, b * nn + n, nt), v, row(p.w2, c, nt));
                axpy(row_mut(&mut rhs, b * nn + n, nt), p.w3[c], xr);
            }
        }
    }
    let mut sig = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for k in 0..nn {
            for j in 0..nn {
                let pv = dot(row(&lhs, b * nn + k, nt), row(&rhs, b * nn + j, nt));
                sig[(b * nn + k) * nn + j] = sigmoid(pv + p.bs[k * nn + j]);
            }
        }
    }
    let mut scores = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for i in 0..nn {
            for k in 0..nn {
                let v = p.vs[i * nn + k];
                let src = row(&sig, b * nn + k, nn);
                axpy(row_mut(&mut scores, b * nn + i, nn), v, src);
            }
        }
    }
    let weights = softmax_rows(&scores, nn);
    let cs = ci * nt;
    let mut output = xt.to_vec();
    for b in 0..nb {
        for i in 0..nn {
            let or = row_mut(&mut output, b * nn + i, cs);
            for j in 0..nn {
                axpy(or, weights[(b * nn + i) * nn + j], row(xt, b * nn + j, cs));
            }
        }
    }
    SpatialAttention {
        xw1,
        lhs,
        rhs,
        sig,
        scores,
        weights,
        output,
    }
}

/// Backward of step 2: returns dL/dX_t and adds the parameter gradients to `grads`: the
/// node mixing's ([`node_mix_backward`]), then the attention's from dS'
/// ([`weights_backward`]).
pub(crate) fn spatial_attention_backward(
    d: &Dims,
    xt: &[f64],
    p: &SpatialParams,
    a: &SpatialAttention,
    dxs: &[f64],
    grads: &mut Grads,
    prefix: &str,
) -> Vec<f64> {
    let (dw, mut dxt) = node_mix_backward(d, xt, &a.weights, dxs);
    weights_backward(d, xt, p, a, &dw, &mut dxt, grads, prefix);
    dxt
}

/// The node mixing X_s = (S' + I)·X_t backward from dX_s: (dS', dX_t), with
/// dX_t = (S' + I)ᵀ·dX_s and dS'[b,i,j] = Σ_{c,t} dX_s[i]·X_t[j]. (The implementations do
/// it in step 3, whose Q = Ψ·(I + S') holds the mixing.)
pub(crate) fn node_mix_backward(
    d: &Dims,
    xt: &[f64],
    weights: &[f64],
    dxs: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let cs = ci * nt;
    let mut dxt = dxs.to_vec();
    let mut dw = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for i in 0..nn {
            let gi = row(dxs, b * nn + i, cs);
            for j in 0..nn {
                dw[(b * nn + i) * nn + j] = dot(gi, row(xt, b * nn + j, cs));
                axpy(
                    row_mut(&mut dxt, b * nn + j, cs),
                    weights[(b * nn + i) * nn + j],
                    gi,
                );
            }
        }
    }
    (dw, dxt)
}

/// The attention's backward from dS' (`dw`), step 2 as the implementations cut it: adds
/// the five parameters' gradients to `grads` and the attention's two terms of dX_t to
/// `dxt`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn weights_backward(
    d: &Dims,
    xt: &[f64],
    p: &SpatialParams,
    a: &SpatialAttention,
    dw: &[f64],
    dxt: &mut [f64],
    grads: &mut Grads,
    prefix: &str,
) {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let ds = softmax_rows_backward(&a.weights, dw, nn);
    // S = Vs·σ(P + bs).
    let (dvs, dpre, dbs) = score_gate_backward(p.vs, &a.sig, &ds, nb, nn);
    // P[b,n,m] = Σ_t lhs[b,n,t]·rhs[b,m,t] (dpre is now dP).
    let mut dlhs = vec![0.0; nb * nn * nt];
    let mut drhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for n in 0..nn {
            for m in 0..nn {
                let g = dpre[(b * nn + n) * nn + m];
                axpy(
                    row_mut(&mut dlhs, b * nn + n, nt),
                    g,
                    row(&a.rhs, b * nn + m, nt),
                );
                axpy(
                    row_mut(&mut drhs, b * nn + m, nt),
                    g,
                    row(&a.lhs, b * nn + n, nt),
                );
            }
        }
    }
    // lhs = Σ_c xw1[c]·W2[c], xw1 = X_t·W1, rhs = Σ_c W3[c]·X_t[c].
    let mut dw1 = vec![0.0; nt];
    let mut dw2 = vec![0.0; ci * nt];
    let mut dw3 = vec![0.0; ci];
    for b in 0..nb {
        for n in 0..nn {
            let (gl, gr) = (row(&dlhs, b * nn + n, nt), row(&drhs, b * nn + n, nt));
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let xr = row(xt, r, nt);
                dw3[c] += dot(gr, xr);
                axpy(row_mut(&mut dw2, c, nt), a.xw1[(b * nn + n) * ci + c], gl);
                let g = dot(row(p.w2, c, nt), gl);
                axpy(&mut dw1, g, xr);
                let dxr = row_mut(dxt, r, nt);
                axpy(dxr, p.w3[c], gr);
                axpy(dxr, g, p.w1);
            }
        }
    }
    grads.add(&format!("{prefix}.sat.W1"), &dw1);
    grads.add(&format!("{prefix}.sat.W2"), &dw2);
    grads.add(&format!("{prefix}.sat.W3"), &dw3);
    grads.add(&format!("{prefix}.sat.bs"), &dbs);
    grads.add(&format!("{prefix}.sat.Vs"), &dvs);
}
