//! Step 1 in f64: the temporal attention (eq. 35–37), forward and backward, with the
//! softmax over the first time index that only it uses.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use crate::model::block::exact::{BlockParams, Dims};
use crate::model::exact::{axpy, dot, row, row_mut, score_gate_backward, sigmoid, Grads};

/// The temporal attention's parameters of one block (U1, U2, U3, be, Ve).
pub(crate) struct TemporalParams<'a> {
    pub(crate) u1: &'a [f64],
    pub(crate) u2: &'a [f64],
    pub(crate) u3: &'a [f64],
    pub(crate) be: &'a [f64],
    pub(crate) ve: &'a [f64],
}

impl<'a> TemporalParams<'a> {
    /// Block `p`'s temporal-attention parameters.
    pub(crate) fn of(p: &BlockParams<'a>) -> TemporalParams<'a> {
        TemporalParams {
            u1: p.get("tat.U1"),
            u2: p.get("tat.U2"),
            u3: p.get("tat.U3"),
            be: p.get("tat.be"),
            ve: p.get("tat.Ve"),
        }
    }
}

/// Step 1 intermediates (eq. 35–37).
#[derive(Clone, Debug)]
pub struct TemporalAttention {
    /// `Σ_n X[b,n,c,t]·U1[n]`, stored `[B,C_in,T]`.
    pub xu1: Vec<f64>,
    /// lhs `[B,T,N]`.
    pub lhs: Vec<f64>,
    /// rhs `[B,N,T]`.
    pub rhs: Vec<f64>,
    /// σ(P + be) `[B,T,T]`.
    pub sig: Vec<f64>,
    /// E = Ve·σ(P + be) `[B,T,T]`.
    pub scores: Vec<f64>,
    /// E' = softmax of E over its first time index `[B,T,T]`.
    pub weights: Vec<f64>,
    /// X_t `[B,N,C_in,T]`.
    pub output: Vec<f64>,
}

/// Softmax over the first index of each `[T,T]` matrix (columns sum to one, step 1).
fn softmax_columns(e: &[f64], nb: usize, nt: usize) -> Vec<f64> {
    let mut w = e.to_vec();
    for m in w.chunks_exact_mut(nt * nt).take(nb) {
        let mut max = vec![f64::NEG_INFINITY; nt];
        for r in m.chunks_exact(nt) {
            for (mx, &v) in max.iter_mut().zip(r) {
                *mx = mx.max(v);
            }
        }
        let mut sum = vec![0.0; nt];
        for r in m.chunks_exact_mut(nt) {
            for ((v, mx), s) in r.iter_mut().zip(&max).zip(sum.iter_mut()) {
                *v = (*v - mx).exp();
                *s += *v;
            }
        }
        for r in m.chunks_exact_mut(nt) {
            for (v, s) in r.iter_mut().zip(&sum) {
                *v /= s;
            }
        }
    }
    w
}

/// Backward of [`softmax_columns`]: dE = E' ⊙ (dE' − Σ_u E'[u,·]·dE'[u,·]).
fn softmax_columns_backward(w: &[f64], dw: &[f64], nb: usize, nt: usize) -> Vec<f64> {
    let mut de = vec![0.0; w.len()];
    for b in 0..nb {
        let (wm, gm) = (row(w, b, nt * nt), row(dw, b, nt * nt));
        let mut s = vec![0.0; nt];
        for (wr, gr) in wm.chunks_exact(nt).zip(gm.chunks_exact(nt)) {
            for ((s, w), g) in s.iter_mut().zip(wr).zip(gr) {
                *s += w * g;
            }
        }
        let dm = row_mut(&mut de, b, nt * nt);
        for ((dr, wr), gr) in dm
            .chunks_exact_mut(nt)
            .zip(wm.chunks_exact(nt))
            .zip(gm.chunks_exact(nt))
        {
            for (((d, w), g), s) in dr.iter_mut().zip(wr).zip(gr).zip(&s) {
                *d = w * (g - s);
            }
        }
    }
    de
}

// ---------------------------------------------------------------------------------------
// Step 1: temporal attention (eq. 35–37).

/// lhs = (X·U1)·U2, rhs = U3·X, P = lhs·rhs, E = Ve·σ(P + be), E' = softmax over the first
/// time index, X_t = X·(E' + I).
pub(crate) fn temporal_attention(d: &Dims, x: &[f64], p: &TemporalParams) -> TemporalAttention {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let mut xu1 = vec![0.0; nb * ci * nt];
    let mut rhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let xr = row(x, d.r(ci, b, n, c), nt);
                axpy(row_mut(&mut xu1, b * ci + c, nt), p.u1[n], xr);
                axpy(row_mut(&mut rhs, b * nn + n, nt), p.u3[c], xr);
            }
        }
    }
    let mut lhs = vec![0.0; nb * nt * nn];
    for b in 0..nb {
        for t in 0..nt {
            let lr = row_mut(&mut lhs, b * nt + t, nn);
            for c in 0..ci {
                axpy(lr, xu1[(b * ci + c) * nt + t], row(p.u2, c, nn));
            }
        }
    }
    let mut sig = vec![0.0; nb * nt * nt];
    for b in 0..nb {
        for t in 0..nt {
            let sr = row_mut(&mut sig, b * nt + t, nt);
            for n in 0..nn {
                axpy(sr, lhs[(b * nt + t) * nn + n], row(&rhs, b * nn + n, nt));
            }
            for (s, be) in sr.iter_mut().zip(row(p.be, t, nt)) {
                *s = sigmoid(*s + be);
            }
        }
    }
    let mut scores = vec![0.0; nb * nt * nt];
    for b in 0..nb {
        for t in 0..nt {
            for k in 0..nt {
                let v = p.ve[t * nt + k];
                let src = row(&sig, b * nt + k, nt);
                axpy(row_mut(&mut scores, b * nt + t, nt), v, src);
            }
        }
    }
    let weights = softmax_columns(&scores, nb, nt);
    let mut output = x.to_vec();
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let (xr, or) = (row(x, r, nt), row_mut(&mut output, r, nt));
                for (t, &xv) in xr.iter().enumerate() {
                    axpy(or, xv, row(&weights, b * nt + t, nt));
                }
            }
        }
    }
    TemporalAttention {
        xu1,
        lhs,
        rhs,
        sig,
        scores,
        weights,
        output,
    }
}

/// Backward of step 1: adds dL/dX to `dx` and the parameter gradients to `grads`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn temporal_attention_backward(
    d: &Dims,
    x: &[f64],
    p: &TemporalParams,
    a: &TemporalAttention,
    dxt: &[f64],
    dx: &mut [f64],
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
    // X_t = X·(E' + I): dX = dX_t·(E' + I)ᵀ, dE'[b,t,t'] = Σ_{n,c} X[t]·dX_t[t'].
    let mut dw = vec![0.0; nb * nt * nt];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let (xr, gr) = (row(x, r, nt), row(dxt, r, nt));
                let dxr = row_mut(dx, r, nt);
                for t in 0..nt {
                    dxr[t] += gr[t] + dot(gr, row(&a.weights, b * nt + t, nt));
                    axpy(row_mut(&mut dw, b * nt + t, nt), xr[t], gr);
                }
            }
        }
    }
    let de = softmax_columns_backward(&a.weights, &dw, nb, nt);
    // E = Ve·σ(P + be).
    let (dve, dpre, dbe) = score_gate_backward(p.ve, &a.sig, &de, nb, nt);
    // P = lhs·rhs (dpre is now dP).
    let mut dlhs = vec![0.0; nb * nt * nn];
    let mut drhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for t in 0..nt {
            let pr = row(&dpre, b * nt + t, nt);
            for n in 0..nn {
                dlhs[(b * nt + t) * nn + n] = dot(pr, row(&a.rhs, b * nn + n, nt));
                axpy(
                    row_mut(&mut drhs, b * nn + n, nt),
                    a.lhs[(b * nt + t) * nn + n],
                    pr,
                );
            }
        }
    }
    // lhs[b,t,m] = Σ_c xu1[b,c,t]·U2[c,m].
    let mut du2 = vec![0.0; ci * nn];
    let mut dxu1 = vec![0.0; nb * ci * nt];
    for b in 0..nb {
        for t in 0..nt {
            let lr = row(&dlhs, b * nt + t, nn);
            for c in 0..ci {
                axpy(row_mut(&mut du2, c, nn), a.xu1[(b * ci + c) * nt + t], lr);
                dxu1[(b * ci + c) * nt + t] = dot(row(p.u2, c, nn), lr);
            }
        }
    }
    // xu1 = Σ_n U1[n]·X[n], rhs = Σ_c U3[c]·X[c].
    let mut du1 = vec![0.0; nn];
    let mut du3 = vec![0.0; ci];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let (gu, gr) = (row(&dxu1, b * ci + c, nt), row(&drhs, b * nn + n, nt));
                du1[n] += dot(gu, row(x, r, nt));
                du3[c] += dot(gr, row(x, r, nt));
                let dxr = row_mut(dx, r, nt);
                axpy(dxr, p.u1[n], gu);
                axpy(dxr, p.u3[c], gr);
            }
        }
    }
    grads.add(&format!("{prefix}.tat.U1"), &du1);
    grads.add(&format!("{prefix}.tat.U2"), &du2);
    grads.add(&format!("{prefix}.tat.U3"), &du3);
    grads.add(&format!("{prefix}.tat.be"), &dbe);
    grads.add(&format!("{prefix}.tat.Ve"), &dve);
}
