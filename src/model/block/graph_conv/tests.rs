//! Step 3 in the generic step test (`every_step.rs`), the graph convolution and, in
//! `st-gat`, the graph attention in its place, on the graph's basis, in both blocks of
//! `iastgcn`, `iastgcn-a`, `iastgcn-s` and `st-gat`: random inputs (X_t and S' with the
//! attention, X without) and a random dZ through the step's reference (X_s = (I + S')·X_t
//! and the reference's convolution or attention; backward, the node mixing's backward,
//! the reference's `node_mix_backward`, to dS' and dX_t), the native step and the WGSL
//! step. Both implementations start their backward from dG, dZ masked by their own
//! Z > 0 (step 4's backward applies Z's ReLU). The native last block keeps X_t and Z at
//! the taps step 4 reads only (Z in the tape's layout, [`tape_layout`]): compared there,
//! and dZ is zero off those steps for every implementation. Each implementation's Ψ,
//! which it keeps for its backward, is checked too.
#![cfg(test)]

use crate::graph::Graph;
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::graph_attention::reference as reference_gat;
use crate::model::block::graph_conv::reference as reference_gc;
use crate::model::block::native::Block;
use crate::model::block::spatial_attention::reference::node_mix_backward;
use crate::model::block::tape::Cols;
use crate::model::block::testing::in_both_blocks;
use crate::model::block::testing::{
    added, at_cols, check, from_cols, gpu, narrow, random, wide, zero_grads, Case, Device, Run,
    StepTest, Tensors, Where, LEFT,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::{graph_basis, param_specs};

/// Step 3's [`StepTest`]: the graph convolution, or with `gat` `st-gat`'s graph attention
/// (the `graph_attention` folder's step, tested here beside the convolution it replaces).
pub(crate) struct GraphConv3 {
    pub(crate) gat: bool,
}

/// Each block of `a · b` values of `v`, `[a, b]`, as `[b, a]`.
fn transposed_blocks(v: &[f64], a: usize, b: usize) -> Vec<f64> {
    let mut out = vec![0.0; v.len()];
    for (s, o) in v.chunks(a * b).zip(out.chunks_mut(a * b)) {
        for i in 0..a {
            for j in 0..b {
                o[j * a + i] = s[i * b + j];
            }
        }
    }
    out
}

/// `[N, ch, cols.len]` in the tape's layout of Z: `[N, cols.len, ch]` at the taps.
fn tape_layout(cols: &Cols, ch: usize, v: &[f64]) -> Vec<f64> {
    if cols.taps {
        transposed_blocks(v, ch, cols.len)
    } else {
        v.to_vec()
    }
}

/// The inverse of [`tape_layout`].
fn from_tape_layout(cols: &Cols, ch: usize, v: &[f64]) -> Vec<f64> {
    if cols.taps {
        transposed_blocks(v, cols.len, ch)
    } else {
        v.to_vec()
    }
}

/// The node mixing X_s = (I + S')·X_t of one window (rows of `width` per node).
fn node_mix(n: usize, width: usize, s: &[f64], xt: &[f64]) -> Vec<f64> {
    let mut xs = xt.to_vec();
    for i in 0..n {
        for j in 0..n {
            let w = s[i * n + j];
            for k in 0..width {
                xs[i * width + k] += w * xt[j * width + k];
            }
        }
    }
    xs
}

/// The graph's basis `[terms, N, N]` for `case`'s configuration.
fn basis(case: &Case) -> Vec<f64> {
    graph_basis(&Graph::default_asset(), &case.cfg)
}

/// The reference's step 3 of block `l` on `inputs`: (Ψ, (Q, Z), X_s).
#[allow(clippy::type_complexity)]
fn reference(
    case: &Case,
    l: usize,
    params: &[Vec<f64>],
    inputs: &Tensors,
) -> (Vec<f64>, (Vec<f64>, Vec<f64>), Vec<f64>) {
    let cfg = &case.cfg;
    let specs = param_specs(cfg);
    let table = Table::new(&specs, params);
    let p = BlockParams::new(&table, cfg, l);
    let d = Dims::new(cfg, 1, l);
    let (n, width) = (cfg.nodes, cfg.block_input(l) * cfg.window);
    let xs = match inputs.get("S'") {
        Some(s) => node_mix(n, width, s, &inputs["X_t"]),
        None => inputs["X"].clone(),
    };
    let basis = basis(case);
    if cfg.variant.graph_attention() {
        let qz = reference_gat::graph_attention(&d, cfg.heads, &basis, &p, &xs);
        return (Vec::new(), qz, xs);
    }
    // invariant: test support: a graph convolution has its θ.
    let theta = case.slots.blocks[l].theta.expect("the convolution's θ");
    let psi = reference_gc::graph_kernel(n, &basis, &params[theta]);
    let qz = reference_gc::graph_conv(&d, &psi, p.w, &xs);
    (psi, qz, xs)
}

/// dG: `dz` where `z` > 0, else 0.
fn past_relu(dz: &[f64], z: &[f64]) -> Vec<f32> {
    dz.iter()
        .zip(z)
        .map(|(&d, &zv)| if zv > 0.0 { d as f32 } else { 0.0 })
        .collect()
}

impl StepTest for GraphConv3 {
    fn name(&self) -> &'static str {
        if self.gat {
            "graph_attention"
        } else {
            "graph_conv"
        }
    }

    fn cases(&self) -> Vec<Where> {
        let variants = if self.gat {
            vec![Variant::StGat]
        } else {
            vec![Variant::Iastgcn, Variant::NoAttention, Variant::Chebyshev]
        };
        in_both_blocks(&variants, &[false])
    }

    fn case_tensors(&self, case: &Case, at: Where) -> (Tensors, Tensors) {
        let cfg = &case.cfg;
        let (n, ci, c, t) = (
            cfg.nodes,
            cfg.block_input(at.block),
            cfg.channels,
            cfg.window,
        );
        let cols = case.tape.blocks[at.block].cols;
        // Values an f32 holds exactly; S' small, as a softmax's rows over N nodes are;
        // dZ zero off the steps the native block keeps.
        let f32s = |seed, len, scale: f64| wide(&random(seed, len, -scale, scale));
        let inputs = if cfg.variant.attention() {
            Tensors::from([
                ("X_t", f32s(16, n * ci * t, 1.0)),
                ("S'", f32s(17, n * n, 0.2)),
            ])
        } else {
            Tensors::from([("X", f32s(16, n * ci * t, 1.0))])
        };
        let dz = from_cols(&cols, &f32s(18, n * c * cols.len, 1.0), t);
        (inputs, Tensors::from([("Z", dz)]))
    }

    fn reference_forward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
    ) -> Tensors {
        let (_, (_, z), _) = reference(case, at.block, params, inputs);
        Tensors::from([("Z", z)])
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
        let (psi, (q, z), xs) = reference(case, l, params, inputs);
        let specs = param_specs(cfg);
        let table = Table::new(&specs, params);
        let p = BlockParams::new(&table, cfg, l);
        let d = Dims::new(cfg, 1, l);
        let basis = basis(case);
        let mut grads = zero_grads(&specs);
        let dz = &d_outputs["Z"];
        let dxs = if cfg.variant.graph_attention() {
            let h = cfg.heads;
            reference_gat::graph_attention_backward(&d, h, &basis, &p, &q, &z, &xs, dz, &mut grads)
        } else {
            reference_gc::graph_conv_backward(&d, &basis, &p, &psi, &q, &z, &xs, dz, &mut grads)
        };
        let d_inputs = match inputs.get("S'") {
            Some(s) => {
                let (dsp, dxt) = node_mix_backward(&d, &inputs["X_t"], s, &dxs);
                Tensors::from([("S'", dsp), ("X_t", dxt)])
            }
            None => Tensors::from([("X", dxs)]),
        };
        (d_inputs, grads.values)
    }

    fn native_outputs(&self, case: &Case, at: Where, mut outputs: Tensors) -> Tensors {
        let cols = case.tape.blocks[at.block].cols;
        // invariant: test support: the reference's outputs hold Z.
        let z = outputs.get_mut("Z").unwrap();
        *z = at_cols(&cols, z, case.cfg.window);
        outputs
    }

    fn native(&self, case: &mut Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let what = |part: &str| format!("{} {at} (native): {part}", self.name());
        let params64: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
        let (psi, _, _) = reference(case, l, &params64, inputs);
        let basis32 = narrow(&basis(case));
        let Case {
            cfg,
            slots,
            params,
            tape,
            work,
        } = case;
        let s = &slots.blocks[l];
        let (n, t, c, ci) = (cfg.nodes, cfg.window, cfg.channels, s.c_in);
        let b = Block::new(cfg, &basis32, s, 1);
        let bt = &mut tape.blocks[l];
        let cols = bt.cols;
        let x = match (inputs.get("X_t"), inputs.get("S'")) {
            (Some(xt), Some(sp)) => {
                bt.xt.copy_from_slice(&narrow(&at_cols(&cols, xt, t)));
                bt.s.copy_from_slice(&narrow(sp));
                narrow(xt)
            }
            _ => narrow(&inputs["X"]),
        };
        if s.gat.is_some() {
            b.graph_attention_forward(params, &x, bt);
        } else {
            b.graph_conv_forward(params, &x, bt);
            check(&what("Ψ"), &wide(&bt.psi), &psi);
        }
        let z = from_tape_layout(&cols, c, &wide(&bt.z));
        let dz = tape_layout(&cols, c, &at_cols(&cols, &d_outputs["Z"], t));
        let dg = past_relu(&dz, &wide(&bt.z));
        work.dz[..dg.len()].copy_from_slice(&dg);
        work.dsp.fill(0.0);
        work.dxt.fill(0.0);
        work.dx.fill(LEFT);
        let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
        if s.gat.is_some() {
            b.graph_attention_backward(params, &x, bt, true, &mut grads, work);
        } else {
            b.graph_conv_backward(params, &x, bt, true, &mut grads, work);
        }
        let d_inputs = if inputs.contains_key("S'") {
            let dxt = wide(&work.dxt[..n * ci * cols.len]);
            Tensors::from([
                ("S'", wide(&work.dsp[..n * n])),
                ("X_t", from_cols(&cols, &dxt, t)),
            ])
        } else {
            Tensors::from([("X", added(&work.dx[..n * ci * t]))])
        };
        Run::computed(Tensors::from([("Z", z)]), d_inputs, &grads)
    }

    fn wgsl(&self, case: &Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let what = |part: &str| format!("{} {at} (wgsl): {part}", self.name());
        let cfg = &case.cfg;
        let (n, t, ci) = (cfg.nodes, cfg.window, cfg.block_input(l));
        let params64: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
        let (psi, _, _) = reference(case, l, &params64, inputs);
        let basis32 = narrow(&basis(case));
        let x = inputs.get("X").map_or(vec![0.0; n * ci * t], |x| narrow(x));
        let dev = Device::new(cfg, l, &case.params, &basis32, &x);
        if let (Some(xt), Some(sp)) = (inputs.get("X_t"), inputs.get("S'")) {
            dev.write("X_t", &narrow(xt));
            dev.write("S'", &narrow(sp));
        }
        let gat = cfg.variant.graph_attention();
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
        let z = dev.read_buffer("Z");
        let dg = dev.upload("dG", &past_relu(&d_outputs["Z"], &z));
        let d_in = dev.upload("dX", &vec![LEFT; n * ci * t]);
        let for_attention = dev.run(|b, p, sc, st| {
            if gat {
                b.graph_attention_backward(gpu(), p, sc, st, &dg, &d_in)?;
                return Ok(None);
            }
            b.graph_conv_backward(gpu(), p, sc, st, &dg, &d_in)
        });
        let d_inputs = match for_attention {
            Some(a) => Tensors::from([("S'", dev.read(&a.dsp)), ("X_t", dev.read(&a.dxt))]),
            None => Tensors::from([("X", added(&narrow(&dev.read(&d_in))))]),
        };
        Run::computed(Tensors::from([("Z", z)]), d_inputs, &dev.grads())
    }
}
