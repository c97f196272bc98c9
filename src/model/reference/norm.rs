//! Steps 5–6: the residual 1×1 convolution R and Y = LayerNorm_C(ReLU(H + R)) (the ReLU
//! itself is applied in `block.rs`).

use super::{axpy, dot, row, row_mut, Dims};

// ---------------------------------------------------------------------------------------
// Step 5: residual 1×1 convolution.

/// R[b,n,o,t] = res.bias[o] + Σ_c res.weight[o,c]·X[b,n,c,t].
pub(super) fn residual(d: &Dims, weight: &[f64], bias: &[f64], x: &[f64]) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut r = vec![0.0; nb * nn * nc * nt];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let rr = row_mut(&mut r, d.r(nc, b, n, o), nt);
                rr.fill(bias[o]);
                for c in 0..ci {
                    axpy(rr, weight[o * ci + c], row(x, d.r(ci, b, n, c), nt));
                }
            }
        }
    }
    r
}

/// Backward of step 5: adds dL/dX to `dx`, returns (dweight, dbias).
pub(super) fn residual_backward(
    d: &Dims,
    weight: &[f64],
    x: &[f64],
    dr: &[f64],
    dx: &mut [f64],
) -> (Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut dw = vec![0.0; nc * ci];
    let mut db = vec![0.0; nc];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let gr = row(dr, d.r(nc, b, n, o), nt);
                db[o] += gr.iter().sum::<f64>();
                for c in 0..ci {
                    let r = d.r(ci, b, n, c);
                    dw[o * ci + c] += dot(gr, row(x, r, nt));
                    axpy(row_mut(dx, r, nt), weight[o * ci + c], gr);
                }
            }
        }
    }
    (dw, db)
}

// ---------------------------------------------------------------------------------------
// Step 6: Y = LayerNorm_C(ReLU(H + R)).

/// LayerNorm over the channel axis for each (b,n,t), biased variance. Returns
/// (Y, mean, rstd) with mean and rstd `[B,N,T]`.
pub(super) fn layer_norm(
    d: &Dims,
    a: &[f64],
    gamma: &[f64],
    beta: &[f64],
    eps: f64,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let ct = nc * nt;
    let mut y = vec![0.0; a.len()];
    let mut mean = vec![0.0; nb * nn * nt];
    let mut rstd = vec![0.0; nb * nn * nt];
    for bn in 0..nb * nn {
        let am = row(a, bn, ct);
        let mu = row_mut(&mut mean, bn, nt);
        for ar in am.chunks_exact(nt) {
            axpy(mu, 1.0 / nc as f64, ar);
        }
        let mut var = vec![0.0; nt];
        for ar in am.chunks_exact(nt) {
            for ((v, x), m) in var.iter_mut().zip(ar).zip(mu.iter()) {
                *v += (x - m) * (x - m) / nc as f64;
            }
        }
        let rs = row_mut(&mut rstd, bn, nt);
        for (r, v) in rs.iter_mut().zip(&var) {
            *r = 1.0 / (v + eps).sqrt();
        }
        let mu = row(&mean, bn, nt);
        let rs = row(&rstd, bn, nt);
        let ym = row_mut(&mut y, bn, ct);
        for (c, (yr, ar)) in ym.chunks_exact_mut(nt).zip(am.chunks_exact(nt)).enumerate() {
            for (((y, x), m), r) in yr.iter_mut().zip(ar).zip(mu).zip(rs) {
                *y = gamma[c] * (x - m) * r + beta[c];
            }
        }
    }
    (y, mean, rstd)
}

/// Backward of [`layer_norm`]: returns (dA, dγ, dβ).
pub(super) fn layer_norm_backward(
    d: &Dims,
    a: &[f64],
    mean: &[f64],
    rstd: &[f64],
    gamma: &[f64],
    dy: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let ct = nc * nt;
    let inv_c = 1.0 / nc as f64;
    let mut da = vec![0.0; a.len()];
    let mut dgamma = vec![0.0; nc];
    let mut dbeta = vec![0.0; nc];
    let mut xhat = vec![0.0; ct];
    let mut dxhat = vec![0.0; ct];
    for bn in 0..nb * nn {
        let (am, gm) = (row(a, bn, ct), row(dy, bn, ct));
        let (mu, rs) = (row(mean, bn, nt), row(rstd, bn, nt));
        // Σ_c dx̂ and Σ_c dx̂·x̂ per t.
        let mut s1 = vec![0.0; nt];
        let mut s2 = vec![0.0; nt];
        for c in 0..nc {
            let (ar, gr) = (row(am, c, nt), row(gm, c, nt));
            let xr = row_mut(&mut xhat, c, nt);
            for (((xh, x), m), r) in xr.iter_mut().zip(ar).zip(mu).zip(rs) {
                *xh = (x - m) * r;
            }
            dgamma[c] += dot(gr, xr);
            dbeta[c] += gr.iter().sum::<f64>();
            let dr = row_mut(&mut dxhat, c, nt);
            for (dh, g) in dr.iter_mut().zip(gr) {
                *dh = g * gamma[c];
            }
            for (((s1, s2), dh), xh) in s1
                .iter_mut()
                .zip(s2.iter_mut())
                .zip(dr.iter())
                .zip(xr.iter())
            {
                *s1 += dh;
                *s2 += dh * xh;
            }
        }
        let dm = row_mut(&mut da, bn, ct);
        for c in 0..nc {
            let (xr, dr) = (row(&xhat, c, nt), row(&dxhat, c, nt));
            let out = row_mut(dm, c, nt);
            for t in 0..nt {
                out[t] = rs[t] * (dr[t] - s1[t] * inv_c - xr[t] * s2[t] * inv_c);
            }
        }
    }
    (da, dgamma, dbeta)
}
