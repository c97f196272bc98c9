//! Step 4: the gated dilated causal convolution (eq. 30–31), also the plain one of
//! `iastgcn-t`, on the whole window: the op's f64 reference (`gated_dcc::kernel::cpu`) on
//! the block's `[B, N, C, T]` tensors.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::gated_dcc::kernel::{cpu, Unfold};
use crate::model::exact::Grads;

/// The unfolding of a block's `[B, N, C, T]` input with dilation `dil` and `kernel` taps,
/// every step kept.
fn unfolding(d: &Dims, dil: usize, kernel: usize) -> Unfold {
    Unfold {
        rows: d.b * d.n,
        channels: d.c,
        kernel,
        steps: d.t,
        dilation: dil,
        outputs: d.t,
    }
}

/// Taps of a `[C, C, K]` weight.
fn taps(d: &Dims, weight: &[f64]) -> usize {
    weight.len() / (d.c * d.c)
}

/// G[b,n,o,t] = bias[o] + Σ_c Σ_k weight[o,c,k]·Z[b,n,c,t − dil·k] (zero before t = 0).
pub(crate) fn gated_dcc_conv(
    d: &Dims,
    dil: usize,
    weight: &[f64],
    bias: &[f64],
    z: &[f64],
) -> Vec<f64> {
    cpu::conv(&unfolding(d, dil, taps(d, weight)), d.c, weight, bias, z)
}

/// H = tanh(G_f) ⊙ σ(G_g) (gated, eq. 31) or ReLU(G_f) (`iastgcn-t`).
pub(crate) fn gated_dcc_output(filter: &[f64], gate: Option<&[f64]>) -> Vec<f64> {
    match gate {
        Some(gate) => cpu::gate(filter, gate),
        None => filter.iter().map(|&f| f.max(0.0)).collect(),
    }
}

/// Backward of step 4 from dL/dH: returns dL/dZ, adds the convolution gradients.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gated_dcc_backward(
    d: &Dims,
    dil: usize,
    p: &BlockParams,
    z: &[f64],
    filter: &[f64],
    gate: Option<&[f64]>,
    dh: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    let u = unfolding(d, dil, taps(d, p.filter_weight));
    let mut dz = vec![0.0; z.len()];
    let mut conv = |name: &str, weight: &[f64], dg: &[f64], grads: &mut Grads| {
        let (dx, dw, db) = cpu::conv_backward(&u, d.c, weight, z, dg);
        for (a, b) in dz.iter_mut().zip(&dx) {
            *a += b;
        }
        grads.add(&p.name(&format!("tcn.{name}.weight")), &dw);
        grads.add(&p.name(&format!("tcn.{name}.bias")), &db);
    };
    match (gate, p.gate) {
        (Some(gate), Some((gate_weight, _))) => {
            let (df, dgate) = cpu::gate_backward(filter, gate, dh);
            conv("filter", p.filter_weight, &df, grads);
            conv("gate", gate_weight, &dgate, grads);
        }
        (None, None) => {
            let df: Vec<f64> = dh
                .iter()
                .zip(filter)
                .map(|(&g, &f)| if f > 0.0 { g } else { 0.0 })
                .collect();
            conv("filter", p.filter_weight, &df, grads);
        }
        // invariant: the forward pass fills the tape for exactly the parameters it has.
        _ => unreachable!("gate tape and gate parameters come together"),
    }
    dz
}
