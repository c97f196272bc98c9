//! Step 1 in the generic step test (`every_step.rs`): a random X and dX_t through the
//! step's reference, the native step and the WGSL step, in both blocks of `iastgcn` and
//! `iastgcn-t`. The native last block keeps X_t at the taps step 4 reads only, so it is
//! compared there ([`StepTest::native_outputs`]), and dX_t is zero off those steps for
//! every implementation. No dE' comes from step 2 here (the native last block's step 2,
//! which reads X and E' at the taps, hands one back: `spatial_attention/tests.rs` checks
//! it).
#![cfg(test)]

use super::native as temporal_attention;
use super::reference::{temporal_attention as reference_forward, TemporalAttention};
use super::reference::{temporal_attention_backward, TemporalParams};
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::native::Block;
use crate::model::block::tape::Cols;
use crate::model::block::testing::in_both_blocks;
use crate::model::block::testing::{
    added, at_cols, from_cols, gpu, narrow, random, wide, zero_grads, Case, Device, Run, StepTest,
    Tensors, Where, LEFT,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::param_specs;

/// Step 1's [`StepTest`].
pub(crate) struct TemporalAttention1;

/// The steps block `l` of `case` keeps X_t at natively (all T but in the last block).
fn kept(case: &Case, l: usize) -> Cols {
    case.tape.blocks[l].cols
}

/// The reference's step 1 of block `l` on X.
fn reference(case: &Case, l: usize, params: &[Vec<f64>], x: &[f64]) -> TemporalAttention {
    let specs = param_specs(&case.cfg);
    let table = Table::new(&specs, params);
    let p = BlockParams::new(&table, &case.cfg, l);
    reference_forward(&Dims::new(&case.cfg, 1, l), x, &TemporalParams::of(&p))
}

impl StepTest for TemporalAttention1 {
    fn name(&self) -> &'static str {
        "temporal_attention"
    }

    fn cases(&self) -> Vec<Where> {
        in_both_blocks(&[Variant::Iastgcn, Variant::PlainTemporal], &[false])
    }

    fn case_tensors(&self, case: &Case, at: Where) -> (Tensors, Tensors) {
        let cfg = &case.cfg;
        let (n, ci, t) = (cfg.nodes, cfg.block_input(at.block), cfg.window);
        let cols = kept(case, at.block);
        // Values an f32 holds exactly; dX_t zero off the kept steps.
        let x = wide(&random(12, n * ci * t, -1.0, 1.0));
        let dxt = wide(&random(13, n * ci * cols.len, -1.0, 1.0));
        (
            Tensors::from([("X", x)]),
            Tensors::from([("X_t", from_cols(&cols, &dxt, t))]),
        )
    }

    fn reference_forward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
    ) -> Tensors {
        let ta = reference(case, at.block, params, &inputs["X"]);
        Tensors::from([("E'", ta.weights), ("X_t", ta.output)])
    }

    fn reference_backward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
        d_outputs: &Tensors,
    ) -> (Tensors, Vec<Vec<f64>>) {
        let (cfg, l, x) = (&case.cfg, at.block, &inputs["X"]);
        let specs = param_specs(cfg);
        let table = Table::new(&specs, params);
        let p = BlockParams::new(&table, cfg, l);
        let (d, tp) = (Dims::new(cfg, 1, l), TemporalParams::of(&p));
        let ta = reference_forward(&d, x, &tp);
        let mut grads = zero_grads(&specs);
        let mut dx = vec![0.0; x.len()];
        let prefix = format!("blocks.{l}");
        let dxt = &d_outputs["X_t"];
        temporal_attention_backward(&d, x, &tp, &ta, dxt, &mut dx, &mut grads, &prefix);
        (Tensors::from([("X", dx)]), grads.values)
    }

    fn native_outputs(&self, case: &Case, at: Where, mut outputs: Tensors) -> Tensors {
        let cols = kept(case, at.block);
        // invariant: test support: the reference's outputs hold X_t.
        let xt = outputs.get_mut("X_t").unwrap();
        *xt = at_cols(&cols, xt, case.cfg.window);
        outputs
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
        let x = narrow(&inputs["X"]);
        temporal_attention::forward(&b, params, &x, bt);
        let outputs = Tensors::from([("E'", wide(&bt.e)), ("X_t", wide(&bt.xt))]);
        let dxt = narrow(&at_cols(&bt.cols, &d_outputs["X_t"], t));
        work.dxt[..dxt.len()].copy_from_slice(&dxt);
        work.de.fill(0.0);
        work.dx.fill(LEFT);
        let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
        temporal_attention::backward(&b, params, &x, bt, true, &mut grads, work);
        Run::computed(
            outputs,
            Tensors::from([("X", added(&work.dx[..x.len()]))]),
            &grads,
        )
    }

    fn wgsl(&self, case: &Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let x = narrow(&inputs["X"]);
        let dev = Device::new(&case.cfg, at.block, &case.params, &[], &x);
        dev.run(|b, p, _, st| b.temporal_attention_forward(gpu(), p, st));
        let outputs = Tensors::from([
            ("E'", dev.read_buffer("E'")),
            ("X_t", dev.read_buffer("X_t")),
        ]);
        let dxt = dev.upload("dX_t", &narrow(&d_outputs["X_t"]));
        let d_in = dev.upload("dX", &vec![LEFT; x.len()]);
        dev.run(|b, p, sc, st| b.temporal_attention_backward(gpu(), p, sc, st, &dxt, &d_in));
        Run::computed(
            outputs,
            Tensors::from([("X", added(&narrow(&dev.read(&d_in))))]),
            &dev.grads(),
        )
    }
}
