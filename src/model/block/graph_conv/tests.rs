//! Step 3, the graph convolution, and `st-gat`'s graph attention in its place, against
//! the step's reference on the reference's steps 1–2 and the graph's basis: Ψ
//! and Z from the native `graph_conv` (Z in the tape's layout, [`tape_layout`]) and the
//! WGSL `graph_conv_forward` (`graph_attention_forward` in `st-gat`), then back from a
//! random dZ (dG = dZ masked by Z > 0 for both) the parameter gradients and dS' and dX_t (dX without attention), in both
//! blocks of `iastgcn`, `iastgcn-a`, `iastgcn-s` and `st-gat`.
#![cfg(test)]

use crate::graph::Graph;
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::graph_attention::reference as reference_gat;
use crate::model::block::graph_conv::reference as reference_gc;
use crate::model::block::native::Block;
use crate::model::block::spatial_attention::reference::{self as spatial, SpatialParams};
use crate::model::block::tape::Cols;
use crate::model::block::temporal_attention::reference::{self as temporal, TemporalParams};
use crate::model::block::testing::{
    at_cols, case, check, check_grads, from_cols, gpu, narrow, node_mix_backward, random, uniform,
    wide, zero_grads, Case, Device,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::{graph_basis, param_specs};

/// `[N, ch, cols.len]` in the tape's layout of Z: `[N, cols.len, ch]` at the taps.
fn tape_layout(cols: &Cols, ch: usize, v: &[f64]) -> Vec<f64> {
    if !cols.taps {
        return v.to_vec();
    }
    let size = ch * cols.len;
    let mut out = vec![0.0; v.len()];
    for (s, o) in v.chunks(size).zip(out.chunks_mut(size)) {
        for c in 0..ch {
            for j in 0..cols.len {
                o[j * ch + c] = s[c * cols.len + j];
            }
        }
    }
    out
}

/// Step 3 forward and backward in block `l` of `variant` on the graph's basis, against
/// `reference::graph_conv` (`graph_kernel`, `graph_conv` and its backward; `st-gat`:
/// `graph_attention` and its backward), on the reference's steps 1–2 (X_t at the kept
/// steps and S' rounded to f32 on the tape, X_s = (I + S')·X_t for the reference; X
/// without attention). The native step's dS' and dX_t are the node mixing's
/// ([`node_mix_backward`]) of the reference's dX_s; without attention, dX is dX_s.
fn graph_conv_matches_its_reference(variant: Variant, l: usize) {
    let Case {
        cfg,
        slots,
        params,
        mut tape,
        mut work,
    } = case(variant);
    let s = &slots.blocks[l];
    let (n, t, c, ci) = (cfg.nodes, cfg.window, cfg.channels, s.c_in);
    let basis = graph_basis(&Graph::default_asset(), &cfg);
    let basis32 = narrow(&basis);
    let b = Block::new(&cfg, &basis32, s, 1);
    let bt = &mut tape.blocks[l];
    let cols = bt.cols;
    let what = |part: &str| format!("graph_conv {} block {l} (native): {part}", variant.name());
    let x = random(16, n * ci * t, -1.0, 1.0);
    let specs = param_specs(&cfg);
    let values: Vec<Vec<f64>> = params.iter().map(|v| wide(v)).collect();
    let table = Table::new(&specs, &values);
    let p = BlockParams::new(&table, &cfg, l);
    let d = Dims::new(&cfg, 1, l);
    let xf = wide(&x);
    let attended = cfg
        .variant
        .attention()
        .then(|| (TemporalParams::of(&p), SpatialParams::of(&p)))
        .map(|(tp, sp)| {
            let ta = temporal::temporal_attention(&d, &xf, &tp);
            let sa = spatial::spatial_attention(&d, &ta.output, &sp);
            (ta, sa)
        });
    if let Some((ta, sa)) = &attended {
        bt.xt
            .copy_from_slice(&narrow(&at_cols(&cols, &ta.output, t)));
        bt.s.copy_from_slice(&narrow(&sa.weights));
    }
    let xs = attended.as_ref().map_or(&xf[..], |(_, sa)| &sa.output[..]);
    if s.gat.is_some() {
        b.graph_attention_forward(&params, &x, bt);
    } else {
        b.graph_conv_forward(&params, &x, bt);
    }
    let psi = s
        .theta
        .map(|theta| reference_gc::graph_kernel(n, &basis, &values[theta]))
        .unwrap_or_default();
    let (q, z) = if s.theta.is_some() {
        check(&what("Ψ"), &wide(&bt.psi), &psi);
        reference_gc::graph_conv(&d, &psi, &values[s.w], xs)
    } else {
        reference_gat::graph_attention(&d, cfg.heads, &basis, &p, xs)
    };
    check(
        &what("Z"),
        &wide(&bt.z),
        &tape_layout(&cols, c, &at_cols(&cols, &z, t)),
    );
    // Backward from dZ at the kept steps (zero off them for the reference), handed to
    // the native step as step 4's backward does: dG, dZ masked by the tape's Z > 0.
    let dz = uniform(17, n * c * cols.len, -1.0, 1.0);
    let dz32 = narrow(&tape_layout(&cols, c, &dz));
    for ((g, d), &zv) in work.dz.iter_mut().zip(&dz32).zip(&bt.z) {
        *g = if zv > 0.0 { *d } else { 0.0 };
    }
    work.dsp.fill(0.0);
    work.dxt.fill(0.0);
    work.dx.fill(0.0);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    if s.gat.is_some() {
        b.graph_attention_backward(&params, &x, bt, true, &mut grads, &mut work);
    } else {
        b.graph_conv_backward(&params, &x, bt, true, &mut grads, &mut work);
    }
    let mut reference = zero_grads(&specs);
    let dz = from_cols(&cols, &dz, t);
    let dxs = if s.theta.is_some() {
        reference_gc::graph_conv_backward(&d, &basis, &p, &psi, &q, &z, xs, &dz, &mut reference)
    } else {
        reference_gat::graph_attention_backward(
            &d,
            cfg.heads,
            &basis,
            &p,
            &q,
            &z,
            xs,
            &dz,
            &mut reference,
        )
    };
    check_grads(&what, &grads, &reference);
    match &attended {
        Some((ta, sa)) => {
            let (dsp, dxt) = node_mix_backward(n, ci * t, &sa.weights, &ta.output, &dxs);
            check(&what("dS'"), &wide(&work.dsp), &dsp);
            check(
                &what("dX_t"),
                &wide(&work.dxt[..n * ci * cols.len]),
                &at_cols(&cols, &dxt, t),
            );
        }
        None => check(&what("dX"), &wide(&work.dx[..dxs.len()]), &dxs),
    }

    // The WGSL step (`graph_conv`, or `graph_attention` in `st-gat`) on the same inputs,
    // on all T steps, from the same dZ masked by Z > 0 (dG: like the native step, its
    // backward starts past Z's ReLU, which step 4's backward applies); with attention, dX_t is its term Qᵀ·dM,
    // which the WGSL block adds at the end of the spatial attention's backward.
    let what = |part: &str| format!("graph_conv {} block {l} (wgsl): {part}", variant.name());
    let dev = Device::new(&cfg, l, &params, &basis32, &x);
    if let Some((ta, sa)) = &attended {
        dev.write("X_t", &narrow(&ta.output));
        dev.write("S'", &narrow(&sa.weights));
    }
    let gat = s.theta.is_none();
    dev.run(|b, p, _, st| {
        if gat {
            b.graph_attention_forward(gpu(), p, st)
        } else {
            b.graph_conv_forward(gpu(), p, st)
        }
    });
    if !gat {
        check(&what("Ψ"), &dev.read_buffer("Psi"), &psi);
    }
    check(&what("Z"), &dev.read_buffer("Z"), &z);
    let dg: Vec<f32> = dz
        .iter()
        .zip(&z)
        .map(|(&d, &zv)| if zv > 0.0 { d as f32 } else { 0.0 })
        .collect();
    let dg = dev.upload("dG", &dg);
    let d_in = dev.upload("dX", &vec![0.0; n * ci * t]);
    let for_attention = dev.run(|b, p, sc, st| {
        if gat {
            b.graph_attention_backward(gpu(), p, sc, st, &dg, &d_in)?;
            return Ok(None);
        }
        b.graph_conv_backward(gpu(), p, sc, st, &dg, &d_in)
    });
    check_grads(&what, &dev.grads(), &reference);
    match (&attended, for_attention) {
        (Some((ta, sa)), Some(a)) => {
            let (dsp, dxt_ref) = node_mix_backward(n, ci * t, &sa.weights, &ta.output, &dxs);
            check(&what("dS'"), &dev.read(&a.dsp), &dsp);
            check(&what("dX_t"), &dev.read(&a.dxt), &dxt_ref);
        }
        (None, None) => check(&what("dX"), &dev.read(&d_in), &dxs),
        _ => panic!("{}", what("attention gradients only with attention")),
    }
}

#[test]
fn graph_conv_native_and_wgsl_every_step_and_in_the_last_block() {
    for variant in [
        Variant::Iastgcn,
        Variant::NoAttention,
        Variant::Chebyshev,
        Variant::StGat,
    ] {
        for l in [0, 1] {
            graph_conv_matches_its_reference(variant, l);
        }
    }
}
