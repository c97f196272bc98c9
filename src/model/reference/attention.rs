//! Steps 1–2: the temporal attention (eq. 35–37) and the spatial attention (eq. 32–34),
//! with the softmaxes and the score gate their backward passes share.

use super::{axpy, dot, row, row_mut, sigmoid, Dims, Grads, SpatialAttention, TemporalAttention};

/// The temporal attention's parameters of one block (U1, U2, U3, be, Ve).
pub(crate) struct TemporalParams<'a> {
    pub(super) u1: &'a [f64],
    pub(super) u2: &'a [f64],
    pub(super) u3: &'a [f64],
    pub(super) be: &'a [f64],
    pub(super) ve: &'a [f64],
}

/// The spatial attention's parameters of one block (W1, W2, W3, bs, Vs).
pub(crate) struct SpatialParams<'a> {
    pub(super) w1: &'a [f64],
    pub(super) w2: &'a [f64],
    pub(super) w3: &'a [f64],
    pub(super) bs: &'a [f64],
    pub(super) vs: &'a [f64],
}

// ---------------------------------------------------------------------------------------
// Softmaxes of the attention steps.

/// Backward of the attention scores `S[b] = V · σ(P[b] + bias)` (`[len, len]` per batch
/// item, both attentions): returns (dV, dP, dbias) from dS and the saved σ.
fn score_gate_backward(
    v: &[f64],
    sig: &[f64],
    dscores: &[f64],
    nb: usize,
    len: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut dv = vec![0.0; len * len];
    let mut dpre = vec![0.0; nb * len * len];
    for b in 0..nb {
        for i in 0..len {
            let dr = row(dscores, b * len + i, len);
            for k in 0..len {
                dv[i * len + k] += dot(dr, row(sig, b * len + k, len));
                axpy(row_mut(&mut dpre, b * len + k, len), v[i * len + k], dr);
            }
        }
    }
    let mut dbias = vec![0.0; len * len];
    for (dm, sm) in dpre
        .chunks_exact_mut(len * len)
        .zip(sig.chunks_exact(len * len))
    {
        for ((g, s), db) in dm.iter_mut().zip(sm).zip(dbias.iter_mut()) {
            *g *= s * (1.0 - s);
            *db += *g;
        }
    }
    (dv, dpre, dbias)
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

/// Backward of step 2: returns dL/dX_t and adds the parameter gradients to `grads`.
pub(crate) fn spatial_attention_backward(
    d: &Dims,
    xt: &[f64],
    p: &SpatialParams,
    a: &SpatialAttention,
    dxs: &[f64],
    grads: &mut Grads,
    prefix: &str,
) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let cs = ci * nt;
    // X_s = (S' + I)·X_t: dX_t = (S' + I)ᵀ·dX_s, dS'[b,i,j] = Σ_{c,t} dX_s[i]·X_t[j].
    let mut dxt = dxs.to_vec();
    let mut dw = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for i in 0..nn {
            let gi = row(dxs, b * nn + i, cs);
            for j in 0..nn {
                dw[(b * nn + i) * nn + j] = dot(gi, row(xt, b * nn + j, cs));
                axpy(
                    row_mut(&mut dxt, b * nn + j, cs),
                    a.weights[(b * nn + i) * nn + j],
                    gi,
                );
            }
        }
    }
    let ds = softmax_rows_backward(&a.weights, &dw, nn);
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
                let dxr = row_mut(&mut dxt, r, nt);
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
    dxt
}
