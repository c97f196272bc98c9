//! The head in f64: ŷ from the last time step of the last block's output ([`head`]), or
//! from a flat input, the recurrent baselines' last state or context ([`flat_head`]), and
//! their backward.

use crate::model::exact::{axpy, dot, row, row_mut, Grads};
use crate::model::ModelConfig;

/// ŷ[b,o] = head.bias[o] + Σ_{n,c} head.weight[o, n·C + c]·Y_L[b,n,c,T−1].
pub(crate) fn head(
    config: &ModelConfig,
    batch: usize,
    w: &[f64],
    bias: &[f64],
    y: &[f64],
) -> Vec<f64> {
    let (nn, nc, nt, no) = (config.nodes, config.channels, config.window, config.outputs);
    let mut out = vec![0.0; batch * no];
    for b in 0..batch {
        for o in 0..no {
            let wr = row(w, o, nn * nc);
            out[b * no + o] = bias[o]
                + (0..nn * nc)
                    .map(|nc_| wr[nc_] * y[(b * nn * nc + nc_) * nt + nt - 1])
                    .sum::<f64>();
        }
    }
    out
}

/// Backward of [`head`] from dL/dŷ `[B,O]`: returns dL/dY_L, adds the head's gradients.
pub(crate) fn head_backward(
    config: &ModelConfig,
    batch: usize,
    w: &[f64],
    y: &[f64],
    dout: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    let (nn, nc, nt, no) = (config.nodes, config.channels, config.window, config.outputs);
    let mut dhw = vec![0.0; w.len()];
    let mut dhb = vec![0.0; no];
    let mut dy = vec![0.0; y.len()];
    for b in 0..batch {
        for o in 0..no {
            let g = dout[b * no + o];
            dhb[o] += g;
            for k in 0..nn * nc {
                let i = (b * nn * nc + k) * nt + nt - 1;
                dhw[o * nn * nc + k] += g * y[i];
                dy[i] += g * w[o * nn * nc + k];
            }
        }
    }
    grads.add("head.weight", &dhw);
    grads.add("head.bias", &dhb);
    dy
}

/// The head of the recurrent baselines on a flat input `h` `[B, width]` (their last state or
/// context): ŷ[b,o] = bias[o] + Σ_k w[o, k]·h[b, k].
pub(crate) fn flat_head(w: &[f64], bias: &[f64], h: &[f64], batch: usize) -> Vec<f64> {
    let (no, width) = (bias.len(), h.len() / batch);
    (0..batch * no)
        .map(|i| {
            let (b, o) = (i / no, i % no);
            bias[o] + dot(row(w, o, width), row(h, b, width))
        })
        .collect()
}

/// Backward of [`flat_head`] from dL/dŷ `[B,O]`: returns dL/dh, adds the head's gradients.
pub(crate) fn flat_head_backward(
    w: &[f64],
    h: &[f64],
    dout: &[f64],
    batch: usize,
    grads: &mut Grads,
) -> Vec<f64> {
    let (no, width) = (dout.len() / batch, h.len() / batch);
    let (mut dw, mut db) = (vec![0.0; w.len()], vec![0.0; no]);
    let mut dh = vec![0.0; h.len()];
    for b in 0..batch {
        for o in 0..no {
            let g = dout[b * no + o];
            db[o] += g;
            axpy(row_mut(&mut dw, o, width), g, row(h, b, width));
            axpy(row_mut(&mut dh, b, width), g, row(w, o, width));
        }
    }
    grads.add("head.weight", &dw);
    grads.add("head.bias", &db);
    dh
}
