//! Step 2 in the generic step test (`every_step.rs`): in both blocks of `iastgcn` and
//! `iastgcn-t`, a random X and E' (step 1's outputs: the native last block, which keeps
//! X_t at the taps only, reads them instead of X_t) and a random dS' through the step's
//! reference, the native step and the WGSL step. The step's output is S'; backward, the
//! gradients it hands back are taken on to X and E' through the time mixing
//! X_t = X·(I + E') ([`time_mix`], [`time_mix_backward`], written out here) where an
//! implementation hands back dX_t (the device, and the native step in a block that keeps
//! X_t everywhere).
#![cfg(test)]

use super::native as spatial_attention;
use super::reference::{spatial_attention as reference_forward, weights_backward, SpatialParams};
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::native::Block;
use crate::model::block::testing::in_both_blocks;
use crate::model::block::testing::{
    gpu, narrow, random, wide, zero_grads, Case, Device, Run, StepTest, Tensors, Where,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::param_specs;

/// Step 2's [`StepTest`].
pub(crate) struct SpatialAttention2;

/// The time mixing X_t = X·(I + E') on rows of T.
fn time_mix(t: usize, e: &[f64], x: &[f64]) -> Vec<f64> {
    let mut xt = x.to_vec();
    for (xr, or) in x.chunks(t).zip(xt.chunks_mut(t)) {
        for u in 0..t {
            for v in 0..t {
                or[v] += xr[u] * e[u * t + v];
            }
        }
    }
    xt
}

/// [`time_mix`] backward from dX_t: the gradients of X and E'.
fn time_mix_backward(t: usize, e: &[f64], x: &[f64], dxt: &[f64]) -> Tensors {
    let mut de = vec![0.0; t * t];
    let mut dx = dxt.to_vec();
    for ((xr, gr), dr) in x.chunks(t).zip(dxt.chunks(t)).zip(dx.chunks_mut(t)) {
        for u in 0..t {
            for v in 0..t {
                de[u * t + v] += xr[u] * gr[v];
                dr[u] += e[u * t + v] * gr[v];
            }
        }
    }
    Tensors::from([("X", dx), ("E'", de)])
}

impl StepTest for SpatialAttention2 {
    fn name(&self) -> &'static str {
        "spatial_attention"
    }

    fn cases(&self) -> Vec<Where> {
        in_both_blocks(&[Variant::Iastgcn, Variant::PlainTemporal], &[false])
    }

    fn case_tensors(&self, case: &Case, at: Where) -> (Tensors, Tensors) {
        let cfg = &case.cfg;
        let (n, ci, t) = (cfg.nodes, cfg.block_input(at.block), cfg.window);
        // Values an f32 holds exactly; E' small, as a softmax's columns over T steps are.
        let f32s = |seed, len, scale: f64| wide(&random(seed, len, -scale, scale));
        (
            Tensors::from([
                ("X", f32s(14, n * ci * t, 1.0)),
                ("E'", f32s(15, t * t, 0.2)),
            ]),
            Tensors::from([("S'", f32s(16, n * n, 1.0))]),
        )
    }

    fn reference_forward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
    ) -> Tensors {
        let cfg = &case.cfg;
        let specs = param_specs(cfg);
        let table = Table::new(&specs, params);
        let p = BlockParams::new(&table, cfg, at.block);
        let xt = time_mix(cfg.window, &inputs["E'"], &inputs["X"]);
        let d = Dims::new(cfg, 1, at.block);
        let sa = reference_forward(&d, &xt, &SpatialParams::of(&p));
        Tensors::from([("S'", sa.weights)])
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
        let specs = param_specs(cfg);
        let table = Table::new(&specs, params);
        let p = BlockParams::new(&table, cfg, l);
        let (e, x) = (&inputs["E'"], &inputs["X"]);
        let xt = time_mix(cfg.window, e, x);
        let (d, sp) = (Dims::new(cfg, 1, l), SpatialParams::of(&p));
        let sa = reference_forward(&d, &xt, &sp);
        let mut grads = zero_grads(&specs);
        let mut dxt = vec![0.0; xt.len()];
        let prefix = format!("blocks.{l}");
        weights_backward(
            &d,
            &xt,
            &sp,
            &sa,
            &d_outputs["S'"],
            &mut dxt,
            &mut grads,
            &prefix,
        );
        (time_mix_backward(cfg.window, e, x, &dxt), grads.values)
    }

    fn native(&self, case: &mut Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let Case {
            cfg,
            slots,
            params,
            tape,
            work,
        } = case;
        let t = cfg.window;
        let b = Block::new(cfg, &[], &slots.blocks[l], 1);
        let bt = &mut tape.blocks[l];
        let (x, e) = (&inputs["X"], &inputs["E'"]);
        bt.e.copy_from_slice(&narrow(e));
        let taps = bt.cols.taps;
        if !taps {
            bt.xt.copy_from_slice(&narrow(&time_mix(t, e, x)));
        }
        let x32 = narrow(x);
        spatial_attention::forward(&b, params, &x32, bt);
        let outputs = Tensors::from([("S'", wide(&bt.s))]);
        work.dsp.copy_from_slice(&narrow(&d_outputs["S'"]));
        work.dxt.fill(0.0);
        work.de.fill(0.0);
        work.dx.fill(0.0);
        let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
        spatial_attention::backward(&b, params, &x32, bt, true, &mut grads, work);
        // At the taps it hands back dE' and dX; elsewhere dX_t, which X_t's mixing takes on.
        let d_inputs = if taps {
            Tensors::from([
                ("X", wide(&work.dx[..x.len()])),
                ("E'", wide(&work.de[..t * t])),
            ])
        } else {
            time_mix_backward(t, e, x, &wide(&work.dxt[..x.len()]))
        };
        Run::computed(outputs, d_inputs, &grads)
    }

    fn wgsl(&self, case: &Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let t = case.cfg.window;
        let (x, e) = (&inputs["X"], &inputs["E'"]);
        let dev = Device::new(&case.cfg, at.block, &case.params, &[], &narrow(x));
        dev.write("X_t", &narrow(&time_mix(t, e, x)));
        dev.run(|b, p, _, st| b.spatial_attention_forward(gpu(), p, st));
        let outputs = Tensors::from([("S'", dev.read_buffer("S'"))]);
        // From dS' and a zero dX_t (step 3's term, Qᵀ·dM, is step 3's test's).
        let dsp = dev.upload("dS'", &narrow(&d_outputs["S'"]));
        let dxt = dev.upload("dX_t", &vec![0.0; x.len()]);
        dev.run(|b, p, sc, st| b.spatial_attention_backward(gpu(), p, sc, st, &dsp, &dxt));
        Run::computed(
            outputs,
            time_mix_backward(t, e, x, &dev.read(&dxt)),
            &dev.grads(),
        )
    }
}
