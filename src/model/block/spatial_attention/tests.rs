//! Step 2, the spatial attention, against its reference on the
//! reference's step 1: S' from the native `spatial_attention` and the WGSL
//! `spatial_attention_forward`, then back from the dS' of a random dX_s the attention's
//! parameter gradients and its part of dX_t; at the taps, where the native step reads X
//! and E' instead of X_t, that dX_t goes on through the time mixing X·(I + E') written
//! out here ([`time_mix_backward`]) to dE' and dX. In both blocks of `iastgcn` and
//! `iastgcn-t`.
#![cfg(test)]

use super::native as spatial_attention;
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::native::Block;
use crate::model::block::spatial_attention::reference::{self as spatial, SpatialParams};
use crate::model::block::temporal_attention::reference::{self as temporal, TemporalParams};
use crate::model::block::testing::{
    case, check, check_grads, gpu, narrow, node_mix_backward, random, uniform, wide, zero_grads,
    Case, Device,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::param_specs;

/// The time mixing X_t = X·(I + E') (rows of T) backward from dX_t: (dE' = Xᵀ·dX_t,
/// dX = dX_t·(I + E')ᵀ). The reference computes it first thing in
/// `temporal_attention_backward`, which goes on to the attention's parameters: written
/// out here for the spatial attention at the taps, which reads X and E' instead of X_t.
fn time_mix_backward(t: usize, e: &[f64], x: &[f64], dxt: &[f64]) -> (Vec<f64>, Vec<f64>) {
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
    (de, dx)
}

/// Step 2 forward and backward in block `l` of `variant`, against
/// `spatial_attention` and its backward, on the reference's step 1
/// (E' and X_t, rounded to f32 on the tape). The reference's step 2 ends with the node
/// mixing X_s = (I + S')·X_t, which the native block does in `graph_conv`: the native
/// step's input dS' is that mixing's (from a random dX_s, [`node_mix_backward`]), and its
/// dX_t the reference's less the mixing's (I + S')ᵀ·dX_s; at the taps, where the native
/// step reads X and E', that dX_t through [`time_mix_backward`] gives its dE' and dX.
fn spatial_attention_matches_its_reference(variant: Variant, l: usize) {
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
            "spatial_attention {} block {l} (native): {part}",
            variant.name()
        )
    };
    let x = random(14, n * ci * t, -1.0, 1.0);
    let specs = param_specs(&cfg);
    let values: Vec<Vec<f64>> = params.iter().map(|v| wide(v)).collect();
    let table = Table::new(&specs, &values);
    let p = BlockParams::new(&table, &cfg, l);
    let (tp, sp) = (TemporalParams::of(&p), SpatialParams::of(&p));
    let d = Dims::new(&cfg, 1, l);
    let xf = wide(&x);
    let ta = temporal::temporal_attention(&d, &xf, &tp);
    let sa = spatial::spatial_attention(&d, &ta.output, &sp);
    bt.e.copy_from_slice(&narrow(&ta.weights));
    if !cols.taps {
        bt.xt.copy_from_slice(&narrow(&ta.output));
    }
    spatial_attention::forward(&b, &params, &x, bt);
    check(&what("S'"), &wide(&bt.s), &sa.weights);
    // Backward from dX_s.
    let dxs = uniform(15, n * ci * t, -1.0, 1.0);
    let (dsp, mixed) = node_mix_backward(n, ci * t, &sa.weights, &ta.output, &dxs);
    work.dsp.copy_from_slice(&narrow(&dsp));
    work.dxt.fill(0.0);
    work.de.fill(0.0);
    work.dx.fill(0.0);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    spatial_attention::backward(&b, &params, &x, bt, true, &mut grads, &mut work);
    let mut reference = zero_grads(&specs);
    let dxt = spatial::spatial_attention_backward(
        &d,
        &ta.output,
        &sp,
        &sa,
        &dxs,
        &mut reference,
        &format!("blocks.{l}"),
    );
    check_grads(&what, &grads, &reference);
    // The attention's part of dX_t.
    let dxt: Vec<f64> = dxt.iter().zip(&mixed).map(|(a, m)| a - m).collect();
    if cols.taps {
        let (de, dx) = time_mix_backward(t, &ta.weights, &xf, &dxt);
        check(&what("dE'"), &wide(&work.de[..t * t]), &de);
        check(&what("dX"), &wide(&work.dx[..dx.len()]), &dx);
    } else {
        check(&what("dX_t"), &wide(&work.dxt[..dxt.len()]), &dxt);
        check(&what("dE'"), &wide(&work.de[..t * t]), &vec![0.0; t * t]);
    }

    // The WGSL step on the same X_t, from the same dS' and a zero dX_t (step 3's term,
    // Qᵀ·dM, is checked there): S', and the attention's part of dX_t on all T steps.
    let what = |part: &str| {
        format!(
            "spatial_attention {} block {l} (wgsl): {part}",
            variant.name()
        )
    };
    let dev = Device::new(&cfg, l, &params, &[], &x);
    dev.write("X_t", &narrow(&ta.output));
    dev.run(|b, p, _, st| b.spatial_attention_forward(gpu(), p, st));
    check(&what("S'"), &dev.read_buffer("S'"), &sa.weights);
    let dsp = dev.upload("dS'", &narrow(&dsp));
    let dxt_dev = dev.upload("dX_t", &vec![0.0; n * ci * t]);
    dev.run(|b, p, sc, st| b.spatial_attention_backward(gpu(), p, sc, st, &dsp, &dxt_dev));
    check_grads(&what, &dev.grads(), &reference);
    check(&what("dX_t"), &dev.read(&dxt_dev), &dxt);
}

#[test]
fn spatial_attention_native_and_wgsl_every_step_and_in_the_last_block() {
    for variant in [Variant::Iastgcn, Variant::PlainTemporal] {
        for l in [0, 1] {
            spatial_attention_matches_its_reference(variant, l);
        }
    }
}
