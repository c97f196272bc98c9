//! Step 1, the temporal attention, against its reference: on a random X,
//! E' and X_t from the native `temporal_attention` (X_t at the steps the block keeps)
//! and the WGSL `temporal_attention_forward` (on all T steps), then back from a random
//! dX_t the attention's parameter gradients and dX, in both blocks of `iastgcn` and
//! `iastgcn-t`.
#![cfg(test)]

use super::native as temporal_attention;
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::native::Block;
use crate::model::block::temporal_attention::reference::{self as temporal, TemporalParams};
use crate::model::block::testing::{
    at_cols, case, check, check_grads, from_cols, gpu, narrow, random, wide, zero_grads, Case,
    Device,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::param_specs;

/// Step 1 forward and backward in block `l` of `variant`, against
/// `temporal_attention` and its backward (the reference's dX_t zero
/// off the steps the block keeps, and no dE' from step 2: `w.de` zero).
fn temporal_attention_matches_its_reference(variant: Variant, l: usize) {
    let Case {
        cfg,
        slots,
        params,
        mut tape,
        mut work,
    } = case(variant);
    let s = &slots.blocks[l];
    let (n, t, ci) = (cfg.nodes, cfg.window, s.c_in);
    let b = Block::new(&cfg, &[], s, 1);
    let bt = &mut tape.blocks[l];
    let cols = bt.cols;
    let what = |part: &str| {
        format!(
            "temporal_attention {} block {l} (native): {part}",
            variant.name()
        )
    };
    let x = random(12, n * ci * t, -1.0, 1.0);
    temporal_attention::forward(&b, &params, &x, bt);
    let specs = param_specs(&cfg);
    let values: Vec<Vec<f64>> = params.iter().map(|v| wide(v)).collect();
    let table = Table::new(&specs, &values);
    let p = BlockParams::new(&table, &cfg, l);
    let tp = TemporalParams::of(&p);
    let d = Dims::new(&cfg, 1, l);
    let xf = wide(&x);
    let ta = temporal::temporal_attention(&d, &xf, &tp);
    check(&what("E'"), &wide(&bt.e), &ta.weights);
    check(&what("X_t"), &wide(&bt.xt), &at_cols(&cols, &ta.output, t));
    // Backward from dX_t at the kept steps.
    let dxt = random(13, n * ci * cols.len, -1.0, 1.0);
    work.dxt[..dxt.len()].copy_from_slice(&dxt);
    work.de.fill(0.0);
    work.dx.fill(0.0);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    temporal_attention::backward(&b, &params, &x, bt, true, &mut grads, &mut work);
    let mut reference = zero_grads(&specs);
    let mut dx = vec![0.0; xf.len()];
    temporal::temporal_attention_backward(
        &d,
        &xf,
        &tp,
        &ta,
        &from_cols(&cols, &wide(&dxt), t),
        &mut dx,
        &mut reference,
        &format!("blocks.{l}"),
    );
    check_grads(&what, &grads, &reference);
    check(&what("dX"), &wide(&work.dx[..dx.len()]), &dx);

    // The WGSL step on the same X, from the same dX_t (zero off the kept steps): E', and
    // X_t on all T steps.
    let what = |part: &str| {
        format!(
            "temporal_attention {} block {l} (wgsl): {part}",
            variant.name()
        )
    };
    let dev = Device::new(&cfg, l, &params, &[], &x);
    dev.run(|b, p, _, st| b.temporal_attention_forward(gpu(), p, st));
    check(&what("E'"), &dev.read_buffer("E'"), &ta.weights);
    check(&what("X_t"), &dev.read_buffer("X_t"), &ta.output);
    let dxt = dev.upload("dX_t", &narrow(&from_cols(&cols, &wide(&dxt), t)));
    let d_in = dev.upload("dX", &vec![0.0; n * ci * t]);
    dev.run(|b, p, sc, st| b.temporal_attention_backward(gpu(), p, sc, st, &dxt, &d_in));
    check_grads(&what, &dev.grads(), &reference);
    check(&what("dX"), &dev.read(&d_in), &dx);
}

#[test]
fn temporal_attention_native_and_wgsl_every_step_and_in_the_last_block() {
    for variant in [Variant::Iastgcn, Variant::PlainTemporal] {
        for l in [0, 1] {
            temporal_attention_matches_its_reference(variant, l);
        }
    }
}
