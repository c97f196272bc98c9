//! The head: ŷ from the last time step of the last block's output, its backward, and the
//! per-output weights of the loss (eq. 39).

use super::{row, Grads, Loss};
use crate::model::ModelConfig;

/// ŷ[b,o] = head.bias[o] + Σ_{n,c} head.weight[o, n·C + c]·Y_L[b,n,c,T−1].
pub(super) fn head(
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
pub(super) fn head_backward(
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

/// The weight of output `m` in eq. 39: 1 for position (m < 3), P for attitude.
pub(super) fn output_weight(m: usize, loss: &Loss) -> f64 {
    if m < 3 {
        1.0
    } else {
        loss.attitude_penalty
    }
}
