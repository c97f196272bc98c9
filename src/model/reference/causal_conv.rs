//! Step 4: the gated dilated causal convolution (eq. 30–31), also the plain one of
//! `iastgcn-t`.

use super::{axpy, dot, row, row_mut, sigmoid, BlockParams, Dims, Grads};

/// G[b,n,o,t] = bias[o] + Σ_c Σ_k weight[o,c,k]·Z[b,n,c,t − dil·k] (zero before t = 0).
pub(super) fn causal_conv(
    d: &Dims,
    dil: usize,
    weight: &[f64],
    bias: &[f64],
    z: &[f64],
) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let nk = weight.len() / (nc * nc);
    let mut g = vec![0.0; z.len()];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let gr = row_mut(&mut g, d.r(nc, b, n, o), nt);
                gr.fill(bias[o]);
                for c in 0..nc {
                    let zr = row(z, d.r(nc, b, n, c), nt);
                    for k in 0..nk {
                        let s = dil * k;
                        if s < nt {
                            axpy(&mut gr[s..], weight[(o * nc + c) * nk + k], &zr[..nt - s]);
                        }
                    }
                }
            }
        }
    }
    g
}

/// Backward of [`causal_conv`]: adds dL/dZ to `dz`, returns (dweight, dbias).
fn causal_conv_backward(
    d: &Dims,
    dil: usize,
    weight: &[f64],
    z: &[f64],
    dg: &[f64],
    dz: &mut [f64],
) -> (Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let nk = weight.len() / (nc * nc);
    let mut dw = vec![0.0; weight.len()];
    let mut db = vec![0.0; nc];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let gr = row(dg, d.r(nc, b, n, o), nt);
                db[o] += gr.iter().sum::<f64>();
                for c in 0..nc {
                    let r = d.r(nc, b, n, c);
                    for k in 0..nk {
                        let s = dil * k;
                        if s < nt {
                            let i = (o * nc + c) * nk + k;
                            dw[i] += dot(&gr[s..], &row(z, r, nt)[..nt - s]);
                            axpy(&mut row_mut(dz, r, nt)[..nt - s], weight[i], &gr[s..]);
                        }
                    }
                }
            }
        }
    }
    (dw, db)
}

/// H = tanh(G_f) ⊙ σ(G_g) (gated, eq. 31) or ReLU(G_f) (`iastgcn-t`).
pub(super) fn temporal_output(filter: &[f64], gate: Option<&[f64]>) -> Vec<f64> {
    match gate {
        Some(gate) => filter
            .iter()
            .zip(gate)
            .map(|(&f, &g)| f.tanh() * sigmoid(g))
            .collect(),
        None => filter.iter().map(|&f| f.max(0.0)).collect(),
    }
}

/// Backward of step 4 from dL/dH: returns dL/dZ, adds the convolution gradients.
#[allow(clippy::too_many_arguments)]
pub(super) fn temporal_conv_backward(
    d: &Dims,
    dil: usize,
    p: &BlockParams,
    z: &[f64],
    filter: &[f64],
    gate: Option<&[f64]>,
    dh: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    let mut dz = vec![0.0; z.len()];
    match (gate, p.gate) {
        (Some(gate), Some((gate_weight, _))) => {
            let mut df = vec![0.0; dh.len()];
            let mut dgate = vec![0.0; dh.len()];
            for i in 0..dh.len() {
                let (th, sg) = (filter[i].tanh(), sigmoid(gate[i]));
                df[i] = dh[i] * sg * (1.0 - th * th);
                dgate[i] = dh[i] * th * sg * (1.0 - sg);
            }
            let (dw, db) = causal_conv_backward(d, dil, p.filter_weight, z, &df, &mut dz);
            grads.add(&p.name("tcn.filter.weight"), &dw);
            grads.add(&p.name("tcn.filter.bias"), &db);
            let (dw, db) = causal_conv_backward(d, dil, gate_weight, z, &dgate, &mut dz);
            grads.add(&p.name("tcn.gate.weight"), &dw);
            grads.add(&p.name("tcn.gate.bias"), &db);
        }
        (None, None) => {
            let df: Vec<f64> = dh
                .iter()
                .zip(filter)
                .map(|(&g, &f)| if f > 0.0 { g } else { 0.0 })
                .collect();
            let (dw, db) = causal_conv_backward(d, dil, p.filter_weight, z, &df, &mut dz);
            grads.add(&p.name("tcn.filter.weight"), &dw);
            grads.add(&p.name("tcn.filter.bias"), &db);
        }
        // invariant: the forward pass fills the tape for exactly the parameters it has.
        _ => unreachable!("gate tape and gate parameters come together"),
    }
    dz
}
