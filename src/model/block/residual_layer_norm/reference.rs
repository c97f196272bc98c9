//! Steps 5–6: the residual 1×1 convolution R and Y = LayerNorm_C(ReLU(H + R)) (the ReLU
//! itself is applied in `block.rs`).

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use crate::model::block::exact::Dims;
use crate::model::block::residual_layer_norm::layer_norm_kernel::{cpu, LayerNorm};
use crate::model::exact::{axpy, dot, row, row_mut};

// ---------------------------------------------------------------------------------------
// Step 5: residual 1×1 convolution.

/// R[b,n,o,t] = res.bias[o] + Σ_c res.weight[o,c]·X[b,n,c,t].
pub(crate) fn residual(d: &Dims, weight: &[f64], bias: &[f64], x: &[f64]) -> Vec<f64> {
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
pub(crate) fn residual_backward(
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
// Step 6: Y = LayerNorm_C(ReLU(H + R)), the op's f64 reference (`layer_norm_kernel::cpu`).

/// The LayerNorm over the channels of a block's `[B, N, C, T]` tensor, with ε held as
/// an f32 as the device and the native path hold it.
fn channel_norm(d: &Dims, eps: f64) -> LayerNorm {
    LayerNorm {
        eps: eps as f32,
        ..LayerNorm::new(d.b * d.n, d.c, d.t)
    }
}

/// LayerNorm over the channel axis for each (b,n,t), biased variance.
pub(crate) fn layer_norm(d: &Dims, a: &[f64], gamma: &[f64], beta: &[f64], eps: f64) -> Vec<f64> {
    cpu::forward(&channel_norm(d, eps), a, gamma, beta)
}

/// Backward of [`layer_norm`]: returns (dA, dγ, dβ).
pub(crate) fn layer_norm_backward(
    d: &Dims,
    a: &[f64],
    gamma: &[f64],
    eps: f64,
    dy: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    cpu::backward(&channel_norm(d, eps), a, gamma, dy)
}
