//! Steps 5–7 in the generic step test (`every_step.rs`): a random H (step 4's output), X
//! and dY through the step's reference (the residual, the LayerNorm and the dropout of
//! training step [`STEP`], whose mask both implementations draw from the same hash), the
//! native step and the WGSL step, in both blocks of `iastgcn` and `iastgcn-t`, with the
//! dropout and without. Without it the WGSL step is inference's forward (its training
//! step always has one), so only the forward is compared. Besides the contract's tensors
//! it checks A = ReLU(H + R + b), which both keep for the backward, and on the native
//! path the mask of the second window of a batch of two (the window's offset into the
//! batch's mask).
#![cfg(test)]

use super::reference::{layer_norm, layer_norm_backward, residual, residual_backward};
use crate::gpu::GpuError;
use crate::model::block::exact::Dims;
use crate::model::block::native::Block;
use crate::model::block::residual_layer_norm::dropout_kernel::keep;
use crate::model::block::tape::Masks;
use crate::model::block::testing::in_both_blocks;
use crate::model::block::testing::{
    check, gpu, narrow, out_steps, random, wide, Case, Device, Run, StepTest, Tensors, Where,
};
use crate::model::block::wgsl::MaskedStep;
use crate::model::config::{ModelConfig, Variant};
use crate::model::schedule::{Pass, Steps};
use crate::ops::Accumulate::Overwrite;

/// Steps 5–7's [`StepTest`].
pub(crate) struct ResidualLayerNorm;

/// The optimiser step whose dropout mask the case draws.
const STEP: u32 = 4;

/// The mask of window `item` of a batch of `batch` at block `l`'s output steps `[N, C,
/// steps]`, and the dropout's scale 1/(1 − p).
fn kept(cfg: &ModelConfig, l: usize, batch: usize, item: usize) -> (Vec<bool>, f64) {
    let masks = Masks {
        seed: Device::SEED,
        step: STEP,
        batch,
        item,
    };
    let ((d, offset), step) = (masks.block(cfg, l), masks.step);
    let (t0, steps) = out_steps(cfg, l);
    let t = cfg.window;
    let mask = (0..cfg.nodes * cfg.channels * steps)
        .map(|e| {
            let (io, tau) = (e / steps, e % steps);
            keep(&d, step, offset + io * t + t0 + tau)
        })
        .collect();
    (mask, 1.0 / (1.0 - cfg.dropout))
}

/// The block's shapes at its output steps (the LayerNorm's rows).
fn out_dims(cfg: &ModelConfig, l: usize) -> Dims {
    Dims {
        t: out_steps(cfg, l).1,
        ..Dims::new(cfg, 1, l)
    }
}

/// A = ReLU(H + R + b) `[N, C, steps]`.
fn activation(case: &Case, l: usize, params: &[Vec<f64>], inputs: &Tensors) -> Vec<f64> {
    let (cfg, s) = (&case.cfg, &case.slots.blocks[l]);
    let r = residual(
        &Dims::new(cfg, 1, l),
        &params[s.res.0],
        &params[s.res.1],
        &inputs["X"],
    );
    let (t0, steps) = out_steps(cfg, l);
    let r_out = r
        .chunks(cfg.window)
        .flat_map(|row| row[t0..t0 + steps].to_vec());
    inputs["H"]
        .iter()
        .zip(r_out)
        .map(|(h, r)| (h + r).max(0.0))
        .collect()
}

/// Y of the reference with the dropout `mask` (none: the evaluation forward).
fn output(
    case: &Case,
    l: usize,
    params: &[Vec<f64>],
    inputs: &Tensors,
    mask: Option<&(Vec<bool>, f64)>,
) -> Vec<f64> {
    let (cfg, s) = (&case.cfg, &case.slots.blocks[l]);
    let a = activation(case, l, params, inputs);
    let mut y = layer_norm(
        &out_dims(cfg, l),
        &a,
        &params[s.gamma],
        &params[s.beta],
        cfg.eps,
    );
    if let Some((kept, scale)) = mask {
        for (v, &k) in y.iter_mut().zip(kept) {
            *v = if k { *v * scale } else { 0.0 };
        }
    }
    y
}

/// `[N, C, steps]` as the native tape's `[C, N·steps]`.
fn tape_layout(v: &[f64], n: usize, c: usize, steps: usize) -> Vec<f32> {
    let mut out = vec![0f32; n * c * steps];
    for i in 0..n {
        for o in 0..c {
            for tau in 0..steps {
                out[o * n * steps + i * steps + tau] = v[(i * c + o) * steps + tau] as f32;
            }
        }
    }
    out
}

impl StepTest for ResidualLayerNorm {
    fn name(&self) -> &'static str {
        "residual_layer_norm"
    }

    fn cases(&self) -> Vec<Where> {
        in_both_blocks(&[Variant::Iastgcn, Variant::PlainTemporal], &[false, true])
    }

    fn case_tensors(&self, case: &Case, at: Where) -> (Tensors, Tensors) {
        let cfg = &case.cfg;
        let (n, c, t, ci) = (
            cfg.nodes,
            cfg.channels,
            cfg.window,
            cfg.block_input(at.block),
        );
        let steps = out_steps(cfg, at.block).1;
        // Values an f32 holds exactly, so that every implementation starts from the same.
        let f32s = |seed, len| wide(&random(seed, len, -1.0, 1.0));
        (
            Tensors::from([("H", f32s(9, n * c * steps)), ("X", f32s(8, n * ci * t))]),
            Tensors::from([("Y", f32s(11, n * c * steps))]),
        )
    }

    fn reference_forward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
    ) -> Tensors {
        let mask = at.dropout.then(|| kept(&case.cfg, at.block, 1, 0));
        let y = output(case, at.block, params, inputs, mask.as_ref());
        Tensors::from([("Y", y)])
    }

    fn reference_backward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
        d_outputs: &Tensors,
    ) -> (Tensors, Vec<Vec<f64>>) {
        let (cfg, l) = (&case.cfg, at.block);
        let s = &case.slots.blocks[l];
        let a = activation(case, l, params, inputs);
        let dy: Vec<f64> = match at.dropout.then(|| kept(cfg, l, 1, 0)) {
            Some((kept, scale)) => d_outputs["Y"]
                .iter()
                .zip(&kept)
                .map(|(&g, &k)| if k { g * scale } else { 0.0 })
                .collect(),
            None => d_outputs["Y"].clone(),
        };
        let (mut da, dgamma, dbeta) =
            layer_norm_backward(&out_dims(cfg, l), &a, &params[s.gamma], cfg.eps, &dy);
        // A's ReLU: dH = dR = dA where A > 0.
        for (g, &v) in da.iter_mut().zip(&a) {
            if v <= 0.0 {
                *g = 0.0;
            }
        }
        // dR on every step (zero off the output steps), for the residual's backward.
        let (t0, steps) = out_steps(cfg, l);
        let x = &inputs["X"];
        let mut dr = vec![0.0; cfg.nodes * cfg.channels * cfg.window];
        for (row, d) in dr.chunks_mut(cfg.window).zip(da.chunks(steps)) {
            row[t0..t0 + steps].copy_from_slice(d);
        }
        let mut dx = vec![0.0; x.len()];
        let (dw, db) = residual_backward(&Dims::new(cfg, 1, l), &params[s.res.0], x, &dr, &mut dx);
        let mut d_params: Vec<Vec<f64>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
        d_params[s.gamma] = dgamma;
        d_params[s.beta] = dbeta;
        d_params[s.res.0] = dw;
        d_params[s.res.1] = db;
        (Tensors::from([("H", da), ("X", dx)]), d_params)
    }

    fn native(&self, case: &mut Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let what = |part: &str| format!("residual_layer_norm {at} (native): {part}");
        let params64: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
        let a = activation(case, l, &params64, inputs);
        // The second window of a batch of two: its mask starts one window in.
        let second = at.dropout.then(|| {
            let mask = kept(&case.cfg, l, 2, 1);
            output(case, l, &params64, inputs, Some(&mask))
        });
        let Case {
            cfg,
            slots,
            params,
            tape,
            work,
        } = case;
        let s = &slots.blocks[l];
        let (n, c, t, ci) = (cfg.nodes, cfg.channels, cfg.window, s.c_in);
        let b = Block::new(cfg, &[], s, 1);
        let bt = &mut tape.blocks[l];
        let steps = bt.steps;
        let last = l + 1 == cfg.blocks;
        let x = narrow(&inputs["X"]);
        bt.hidden
            .copy_from_slice(&tape_layout(&inputs["H"], n, c, steps));
        let masks = |batch, item| Masks {
            seed: Device::SEED,
            step: STEP,
            batch,
            item,
        };
        let mut h = vec![0f32; n * c];
        let forward = |bt: &mut _, batch, item, h: &mut [f32]| {
            let m: Masks = masks(batch, item);
            let mask = at.dropout.then(|| (m.block(cfg, l), m.step));
            b.residual_layer_norm_forward(params, &x, bt, mask, last.then_some(h));
        };
        if let Some(e) = &second {
            forward(bt, 2, 1, &mut h);
            let y = if last { wide(&h) } else { wide(&bt.y) };
            check(&what("Y of window 2 of 2"), &y, e);
        }
        forward(bt, 1, 0, &mut h);
        check(&what("A"), &wide(&bt.act), &a);
        let y = if last { wide(&h) } else { wide(&bt.y) };
        work.dy[..n * c * steps].copy_from_slice(&narrow(&d_outputs["Y"]));
        let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
        b.residual_layer_norm_backward(params, &x, bt, at.dropout, true, &mut grads, work);
        Run::computed(
            Tensors::from([("Y", y)]),
            Tensors::from([
                ("H", wide(&work.da[..n * c * steps])),
                ("X", wide(&work.dx[..n * ci * t])),
            ]),
            &grads,
        )
    }

    fn wgsl(&self, case: &Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let what = |part: &str| format!("residual_layer_norm {at} (wgsl): {part}");
        let params64: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
        let a = activation(case, l, &params64, inputs);
        let cfg = &case.cfg;
        let (n, t, ci) = (cfg.nodes, cfg.window, cfg.block_input(l));
        let dev = Device::new(cfg, l, &case.params, &[], &narrow(&inputs["X"]));
        dev.write("H", &narrow(&inputs["H"]));
        // Every dispatch that reads the mask, at the step the case draws.
        let at_step = |st: &Steps, m: MaskedStep| -> Result<(), GpuError> {
            // invariant: test support: the block hands back dispatches it scheduled.
            let d = st.dispatch(m.index).expect("a masked step is a dispatch");
            m.layer_norm.set_step(gpu(), d, STEP, Overwrite)
        };
        let pass = if at.dropout {
            Pass::Train
        } else {
            Pass::Inference
        };
        dev.run(
            |b, p, _, st| match b.residual_layer_norm_forward(gpu(), p, st, pass)? {
                Some(masked) => at_step(st, masked),
                None => Ok(()),
            },
        );
        // The residual product accumulates A onto H's buffer.
        check(&what("A"), &dev.read_buffer("H"), &a);
        let outputs = Tensors::from([("Y", dev.read_buffer("output"))]);
        if !at.dropout {
            return Run {
                outputs,
                backward: None,
            };
        }
        let d_out = dev.upload("d output", &narrow(&d_outputs["Y"]));
        let d_in = dev.upload("dX", &vec![0.0; n * ci * t]);
        let dh = dev.run(|b, p, sc, st| {
            let (dh, masked) = b.residual_layer_norm_backward(gpu(), p, sc, st, &d_out, &d_in)?;
            masked.into_iter().try_for_each(|m| at_step(st, m))?;
            Ok(dh)
        });
        Run::computed(
            outputs,
            Tensors::from([("H", dev.read(&dh)), ("X", dev.read(&d_in))]),
            &dev.grads(),
        )
    }
}
