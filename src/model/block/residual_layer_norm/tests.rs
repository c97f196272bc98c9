//! Steps 5–7, the residual connection, the LayerNorm and the dropout, against
//! `ops::layer_norm::cpu` with the residual 1×1 convolution and the ReLUs around it
//! written out here ([`norm_reference`]): on a random X and step 4's output H, the native
//! and the WGSL step (each with the dropout fused in its own way) give A = ReLU(H + R + b) and Y, then back from
//! a random dY dγ, dβ, dA, the residual's gradients and dX, in both blocks of `iastgcn`
//! and `iastgcn-t`, with the dropout of a training step and without (the WGSL step
//! without dropout is inference's forward: its training step always has one).
#![cfg(test)]

use super::native as residual_layer_norm;
use crate::gpu::GpuError;
use crate::model::block::native::Block;
use crate::model::block::tape::Masks;
use crate::model::block::testing::{case, check, gpu, narrow, random, wide, Case, Device};
use crate::model::block::wgsl::MaskedStep;
use crate::model::config::Variant;
use crate::model::schedule::Pass;
use crate::model::schedule::Steps;
use crate::ops::dropout::keep;
use crate::ops::layer_norm::{cpu as norm, LayerNorm};
use crate::ops::Accumulate::Overwrite;

/// The f64 reference of steps 5–7 on A `[N, C, steps]`, with dropout where `kept` is
/// given: Y, then from dY dA (masked by A > 0), dγ, dβ, d res.weight, d res.bias and dX
/// `[N, C_in, T]` (zero off the steps the block keeps, from `t0`).
struct NormReference {
    y: Vec<f64>,
    da: Vec<f64>,
    dgamma: Vec<f64>,
    dbeta: Vec<f64>,
    dw: Vec<f64>,
    db: Vec<f64>,
    dx: Vec<f64>,
}

#[allow(clippy::too_many_arguments)]
fn norm_reference(
    (n, c, ci, t, t0, steps): (usize, usize, usize, usize, usize, usize),
    act: &[f64],
    (gamma, beta): (&[f64], &[f64]),
    res_w: &[f64],
    xf: &[f64],
    kept: Option<(&[bool], f64)>,
    dy: &[f32],
) -> NormReference {
    let ln = LayerNorm::new(n, c, steps);
    let mut y = norm::forward(&ln, act, gamma, beta);
    if let Some((kept, scale)) = kept {
        for (v, &k) in y.iter_mut().zip(kept) {
            *v = if k { *v * scale } else { 0.0 };
        }
    }
    let dy: Vec<f64> = match kept {
        None => wide(dy),
        Some((kept, scale)) => dy
            .iter()
            .zip(kept)
            .map(|(&g, &k)| if k { g as f64 * scale } else { 0.0 })
            .collect(),
    };
    let (mut da, dgamma, dbeta) = norm::backward(&ln, act, gamma, &dy);
    for (d, &a) in da.iter_mut().zip(act) {
        if a <= 0.0 {
            *d = 0.0;
        }
    }
    let mut dw = vec![0.0; c * ci];
    let mut db = vec![0.0; c];
    let mut dx = vec![0.0; n * ci * t];
    for i in 0..n {
        for o in 0..c {
            for tau in 0..steps {
                let g = da[(i * c + o) * steps + tau];
                db[o] += g;
                for ch in 0..ci {
                    let xi = (i * ci + ch) * t + t0 + tau;
                    dw[o * ci + ch] += g * xf[xi];
                    dx[xi] += g * res_w[o * ci + ch];
                }
            }
        }
    }
    NormReference {
        y,
        da,
        dgamma,
        dbeta,
        dw,
        db,
        dx,
    }
}

/// Steps 5–7 forward and backward in block `l` of `variant`, with the dropout of a
/// training step or without: the native step (its two passes),
/// and the WGSL `residual_layer_norm` (without dropout, its inference forward alone).
fn residual_layer_norm_dropout_match_their_reference(variant: Variant, l: usize, drop: bool) {
    let Case {
        cfg,
        slots,
        params,
        mut tape,
        mut work,
    } = case(variant);
    let s = &slots.blocks[l];
    let (n, t, c, ci) = (cfg.nodes, cfg.window, cfg.channels, s.c_in);
    let x = random(8, n * ci * t, -1.0, 1.0);
    let b = Block::new(&cfg, &[], s, 1);
    let bt = &mut tape.blocks[l];
    let (t0, steps) = (bt.t0, bt.steps);
    let last = l + 1 == cfg.blocks;
    // "residual_layer_norm: dA" reads "residual_layer_norm iastgcn block 0 (wgsl): dA".
    let what = |path: &str, part: &str| {
        let (step, part) = part.split_once(": ").unwrap_or(("", part));
        format!(
            "{step} {} block {l}{} ({path}): {part}",
            variant.name(),
            if drop { " with dropout" } else { "" }
        )
    };
    // Step 4's output H on the tape `[C, N·steps]`: tanh(G_f) ⊙ σ(G_g) of a random
    // tanh(G_f) and σ(G_g), or ReLU(G_f).
    let gated = s.gate.is_some();
    let half = c * n * steps;
    let f = random(9, half, -1.0, 1.0);
    let q = random(10, half, 0.0, 1.0);
    for ((h, f), q) in bt.hidden.iter_mut().zip(&f).zip(&q) {
        *h = if gated { f * q } else { f.max(0.0) };
    }
    let masks = Masks {
        seed: Device::SEED,
        step: 4,
        batch: 2,
        item: 1,
    };
    let mask = drop.then(|| (masks.block(&cfg, l), masks.step));
    let mut h = vec![0f32; n * c];
    residual_layer_norm::forward(&b, &params, &x, bt);
    residual_layer_norm::affine_dropout_forward(&b, &params, bt, mask, last.then_some(&mut h[..]));
    // The reference, `[N, C, steps]`.
    let (res_w, res_b) = (wide(&params[s.res.0]), wide(&params[s.res.1]));
    let xf = wide(&x);
    let at = |i: usize, o: usize, tau: usize| (i * c + o) * steps + tau;
    // H `[N, C, steps]` and A = ReLU(H + R + b).
    let mut hv = vec![0.0; n * c * steps];
    let mut act = vec![0.0; n * c * steps];
    for i in 0..n {
        for o in 0..c {
            for tau in 0..steps {
                let r: f64 = (0..ci)
                    .map(|ch| res_w[o * ci + ch] * xf[(i * ci + ch) * t + t0 + tau])
                    .sum();
                let g = o * n * steps + i * steps + tau;
                hv[at(i, o, tau)] = bt.hidden[g] as f64;
                act[at(i, o, tau)] = (res_b[o] + r + hv[at(i, o, tau)]).max(0.0);
            }
        }
    }
    check(
        &what("native", "residual_layer_norm: A"),
        &wide(&bt.act),
        &act,
    );
    let (gamma, beta) = (wide(&params[s.gamma]), wide(&params[s.beta]));
    // Step 7: element (i, o, t0 + τ) of the block's whole `[N, C, T]` output keeps its
    // bit of the mask of the window's item in the batch.
    let scale = 1.0 / (1.0 - cfg.dropout);
    let kept_in = |masks: &Masks| -> Vec<bool> {
        let ((d, offset), step) = (masks.block(&cfg, l), masks.step);
        (0..n * c * steps)
            .map(|e| {
                let (io, tau) = (e / steps, e % steps);
                keep(&d, step, offset + io * t + t0 + tau)
            })
            .collect()
    };
    let dims = (n, c, ci, t, t0, steps);
    let dy = random(11, n * c * steps, -1.0, 1.0);
    let kept = kept_in(&masks);
    let e = norm_reference(
        dims,
        &act,
        (&gamma, &beta),
        &res_w,
        &xf,
        drop.then_some((&kept[..], scale)),
        &dy,
    );
    let native_y = if last { wide(&h) } else { wide(&bt.y) };
    check(&what("native", "affine_dropout: Y"), &native_y, &e.y);
    // Backward from dY.
    work.dy[..dy.len()].copy_from_slice(&dy);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    residual_layer_norm::affine_dropout_backward(&b, bt, drop, &mut grads, &mut work);
    residual_layer_norm::backward(&b, &params, &x, bt, true, &mut grads, &mut work);
    let checks = |path: &str, grads: &[Vec<f32>], da: &[f64], dx: &[f64], e: &NormReference| {
        let w = |part: &str| what(path, part);
        check(&w("affine_dropout: dγ"), &wide(&grads[s.gamma]), &e.dgamma);
        check(&w("affine_dropout: dβ"), &wide(&grads[s.beta]), &e.dbeta);
        check(&w("residual_layer_norm: dA"), da, &e.da);
        check(
            &w("residual_layer_norm: d res.weight"),
            &wide(&grads[s.res.0]),
            &e.dw,
        );
        check(
            &w("residual_layer_norm: d res.bias"),
            &wide(&grads[s.res.1]),
            &e.db,
        );
        check(&w("residual_layer_norm: dX"), dx, &e.dx);
    };
    let (da, dx) = (wide(&work.da[..e.da.len()]), wide(&work.dx[..e.dx.len()]));
    checks("native", &grads, &da, &dx, &e);

    // The WGSL steps on the same X, H and parameters, from the same dY; the dropout is
    // that of a batch of one window (the native mask above is the second window's of
    // two), and the block's own steps are at T − 1 in the last block as in the native.
    let dev = Device::new(&cfg, l, &params, &[], &x);
    dev.write("H", &narrow(&hv));
    let what_wgsl = |part: &str| what("wgsl", part);
    let one = Masks {
        batch: 1,
        item: 0,
        ..masks
    };
    // Every dispatch that reads the mask, at the step of the batch of one.
    let at_step = |st: &Steps, m: MaskedStep| -> Result<(), GpuError> {
        let d = st.dispatch(m.index).expect("a masked step is a dispatch");
        m.layer_norm.set_step(gpu(), d, one.step, Overwrite)
    };
    // Steps 5–7 of a training step, the dropout fused into LayerNorm's kernels; without
    // dropout the WGSL step is inference's (its training step always has one), and the
    // check stops after the forward.
    let pass = if drop { Pass::Train } else { Pass::Inference };
    dev.run(
        |b, p, _, st| match b.residual_layer_norm_forward(gpu(), p, st, pass)? {
            Some(masked) => at_step(st, masked),
            None => Ok(()),
        },
    );
    check(
        &what_wgsl("residual_layer_norm: A"),
        &dev.read_buffer("H"),
        &act,
    );
    let kept = kept_in(&one);
    let e = norm_reference(
        dims,
        &act,
        (&gamma, &beta),
        &res_w,
        &xf,
        drop.then_some((&kept[..], scale)),
        &dy,
    );
    check(
        &what_wgsl("residual_layer_norm: Y"),
        &dev.read_buffer("output"),
        &e.y,
    );
    if drop {
        let d_out = dev.upload("d output", &dy);
        let d_in = dev.upload("dX", &vec![0.0; n * ci * t]);
        let ds = dev.run(|b, p, sc, st| {
            let (ds, masked) = b.residual_layer_norm_backward(gpu(), p, sc, st, &d_out, &d_in)?;
            masked.into_iter().try_for_each(|m| at_step(st, m))?;
            Ok(ds)
        });
        checks("wgsl", &dev.grads(), &dev.read(&ds), &dev.read(&d_in), &e);
    }
}

#[test]
fn residual_layer_norm_and_dropout_native_and_wgsl_every_step_and_in_the_last_block() {
    for variant in [Variant::Iastgcn, Variant::PlainTemporal] {
        for l in [0, 1] {
            for drop in [false, true] {
                residual_layer_norm_dropout_match_their_reference(variant, l, drop);
            }
        }
    }
}
