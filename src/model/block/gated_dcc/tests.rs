//! Step 4, the gated dilated causal convolution, against `ops::gated_dcc::cpu`: on a
//! random Z, the native and the WGSL step give the same outputs, H = tanh(G_f) ⊙ σ(G_g)
//! (ReLU(G_f) in `iastgcn-t`), with what each keeps for its backward (tanh(G_f) and
//! σ(G_g) on the native tape, G_f and G_g on the device); then back from a random dH the
//! filter's and the gate's gradients and dG (dZ masked by Z > 0, step 3's ReLU), in both
//! blocks of `iastgcn` and `iastgcn-t`.
#![cfg(test)]

use super::native as gated_dcc;
use crate::model::block::native::Block;
use crate::model::block::testing::{case, check, gpu, narrow, random, wide, Case, Device};
use crate::model::config::Variant;
use crate::model::schedule::Pass;
use crate::ops::gated_dcc::{cpu as dcc, Unfold};

/// Step 4 forward and backward in block `l` of `variant`.
fn gated_dcc_matches_its_reference(variant: Variant, l: usize) {
    let Case {
        cfg,
        slots,
        params,
        mut tape,
        mut work,
    } = case(variant);
    let s = &slots.blocks[l];
    let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
    let b = Block::new(&cfg, &[], s, 1);
    let bt = &mut tape.blocks[l];
    let (cols, steps) = (bt.cols, bt.steps);
    let what = |part: &str| format!("gated_dcc {} block {l} (native): {part}", variant.name());
    // Z `[N, C, T]`, in the tape's layout (at the taps `[N, taps, C]`).
    let z = random(6, n * c * t, -1.0, 1.0);
    if cols.taps {
        for i in 0..n {
            for j in 0..cols.len {
                for ch in 0..c {
                    bt.z[(i * cols.len + j) * c + ch] =
                        z[(i * c + ch) * t + cols.first + cols.stride * j];
                }
            }
        }
    } else {
        bt.z.copy_from_slice(&z);
    }
    gated_dcc::forward(&b, &params, bt);
    let u = Unfold {
        rows: n,
        channels: c,
        kernel: k,
        steps: t,
        dilation: s.dilation,
        outputs: steps,
    };
    let zf = wide(&z);
    let conv =
        |(w, bias): (usize, usize)| dcc::conv(&u, c, &wide(&params[w]), &wide(&params[bias]), &zf);
    let gf = conv(s.filter);
    let gg = s.gate.map(conv);
    // bt.g is `[outs, N·steps]`; the reference `[N, C, steps]`.
    let per_node = |half: usize| -> Vec<f64> {
        let mut out = vec![0.0; n * c * steps];
        for i in 0..n {
            for o in 0..c {
                for tau in 0..steps {
                    out[(i * c + o) * steps + tau] =
                        bt.g[(half * c + o) * n * steps + i * steps + tau] as f64;
                }
            }
        }
        out
    };
    match &gg {
        Some(gg) => {
            let tanh: Vec<f64> = gf.iter().map(|v| v.tanh()).collect();
            let sigma: Vec<f64> = gg.iter().map(|v| 1.0 / (1.0 + (-v).exp())).collect();
            check(&what("tanh(G_f)"), &per_node(0), &tanh);
            check(&what("σ(G_g)"), &per_node(1), &sigma);
        }
        None => check(&what("G_f"), &per_node(0), &gf),
    }
    // H = tanh(G_f) ⊙ σ(G_g), ReLU(G_f) in `iastgcn-t`: the step's output, `[C, N·steps]`.
    let h: Vec<f64> = match &gg {
        Some(gg) => gf
            .iter()
            .zip(gg)
            .map(|(f, g)| f.tanh() / (1.0 + (-g).exp()))
            .collect(),
        None => gf.iter().map(|f| f.max(0.0)).collect(),
    };
    let native_h: Vec<f64> = {
        let mut out = vec![0.0; n * c * steps];
        for i in 0..n {
            for o in 0..c {
                for tau in 0..steps {
                    out[(i * c + o) * steps + tau] =
                        bt.hidden[o * n * steps + i * steps + tau] as f64;
                }
            }
        }
        out
    };
    check(&what("H"), &native_h, &h);
    // Backward from dH.
    let dh = random(7, n * c * steps, -1.0, 1.0);
    work.da[..dh.len()].copy_from_slice(&dh);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    gated_dcc::backward(&b, &params, bt, &mut grads, &mut work);
    let dh = wide(&dh);
    let (df, dg) = match &gg {
        Some(gg) => {
            let (df, dg) = dcc::gate_backward(&gf, gg, &dh);
            (df, Some(dg))
        }
        // `iastgcn-t`: H = ReLU(G_f).
        None => (
            dh.iter()
                .zip(&gf)
                .map(|(d, f)| if *f > 0.0 { *d } else { 0.0 })
                .collect(),
            None,
        ),
    };
    let (mut dz, dwf, dbf) = dcc::conv_backward(&u, c, &wide(&params[s.filter.0]), &zf, &df);
    check(&what("d filter.weight"), &wide(&grads[s.filter.0]), &dwf);
    check(&what("d filter.bias"), &wide(&grads[s.filter.1]), &dbf);
    let gate_grads = s.gate.zip(dg).map(|((w, bias), dg)| {
        let (dzg, dwg, dbg) = dcc::conv_backward(&u, c, &wide(&params[w]), &zf, &dg);
        check(&what("d gate.weight"), &wide(&grads[w]), &dwg);
        check(&what("d gate.bias"), &wide(&grads[bias]), &dbg);
        for (a, g) in dz.iter_mut().zip(dzg) {
            *a += g;
        }
        (w, bias, dwg, dbg)
    });
    // dG = dZ through Z's ReLU (step 3's, whose backward step 4's applies): from the
    // tape's layout back to `[N, C, T]`.
    let masked: Vec<f64> = dz
        .iter()
        .zip(&z)
        .map(|(&d, &zv)| if zv > 0.0 { d } else { 0.0 })
        .collect();
    let native_dg: Vec<f64> = if cols.taps {
        let mut out = vec![0.0; n * c * t];
        for i in 0..n {
            for j in 0..cols.len {
                for ch in 0..c {
                    out[(i * c + ch) * t + cols.first + cols.stride * j] =
                        work.dz[(i * cols.len + j) * c + ch] as f64;
                }
            }
        }
        out
    } else {
        wide(&work.dz[..n * c * t])
    };
    check(&what("dG"), &native_dg, &masked);

    // The WGSL step on the same Z and parameters, from the same dH: G_f, G_g and H =
    // tanh(G_f) ⊙ σ(G_g) (ReLU(G_f) in `iastgcn-t`) at the steps the block keeps, and dG
    // = dZ masked by Z > 0 (step 3's ReLU, which the unfolding's backward applies).
    let what = |part: &str| format!("gated_dcc {} block {l} (wgsl): {part}", variant.name());
    let dev = Device::new(&cfg, l, &params, &[], &vec![0.0; n * s.c_in * t]);
    dev.write("Z", &z);
    dev.run(|b, p, _, st| b.gated_dcc_forward(gpu(), p, st, Pass::Train));
    check(&what("G_f"), &dev.read_buffer("G_f"), &gf);
    if let Some(gg) = &gg {
        check(&what("G_g"), &dev.read_buffer("G_g"), gg);
    }
    check(&what("H"), &dev.read_buffer("H"), &h);
    let dh = dev.upload("dH", &narrow(&dh));
    let dg = dev.run(|b, p, sc, st| b.gated_dcc_backward(gpu(), p, sc, st, &dh));
    let grads = dev.grads();
    check(&what("d filter.weight"), &wide(&grads[s.filter.0]), &dwf);
    check(&what("d filter.bias"), &wide(&grads[s.filter.1]), &dbf);
    if let Some((w, bias, dwg, dbg)) = &gate_grads {
        check(&what("d gate.weight"), &wide(&grads[*w]), dwg);
        check(&what("d gate.bias"), &wide(&grads[*bias]), dbg);
    }
    check(&what("dG"), &dev.read(&dg), &masked);
}

#[test]
fn gated_dcc_native_and_wgsl_every_step_and_in_the_last_block() {
    for variant in [Variant::Iastgcn, Variant::PlainTemporal] {
        for l in [0, 1] {
            gated_dcc_matches_its_reference(variant, l);
        }
    }
}
