//! Step 4 in the generic step test (`every_step.rs`): a random Z and dH through the
//! step's reference, the native step and the WGSL step, in both blocks of `iastgcn` and
//! `iastgcn-t`. Besides the contract's tensors (H forward; dG, dZ through step 3's ReLU,
//! and the four parameters' gradients backward) it checks what each implementation keeps
//! for its backward: tanh(G_f) and σ(G_g) on the native tape, G_f and G_g on the device.
#![cfg(test)]

use super::reference::{gated_dcc_backward, gated_dcc_conv, gated_dcc_output};
use crate::model::block::exact::{BlockParams, Dims};
use crate::model::block::native::Block;
use crate::model::block::testing::in_both_blocks;
use crate::model::block::testing::{
    check, gpu, narrow, out_steps, random, wide, zero_grads, Case, Device, Run, StepTest, Tensors,
    Where,
};
use crate::model::config::Variant;
use crate::model::exact::Table;
use crate::model::params::param_specs;
use crate::model::schedule::Pass;

/// Step 4's [`StepTest`].
pub(crate) struct GatedDcc;

/// G_f and G_g (gated variants) `[N, C, T]` of the reference on Z.
fn convolutions(
    case: &Case,
    l: usize,
    params: &[Vec<f64>],
    z: &[f64],
) -> (Vec<f64>, Option<Vec<f64>>) {
    let s = &case.slots.blocks[l];
    let d = Dims::new(&case.cfg, 1, l);
    let conv = |(w, b): (usize, usize)| gated_dcc_conv(&d, s.dilation, &params[w], &params[b], z);
    (conv(s.filter), s.gate.map(conv))
}

/// Rows of T `[.., T]` at the output steps `[.., steps]`.
fn at_out(v: &[f64], t: usize, (t0, steps): (usize, usize)) -> Vec<f64> {
    v.chunks(t)
        .flat_map(|r| r[t0..t0 + steps].to_vec())
        .collect()
}

/// `[C, N·steps]` (the native tape's layout) as `[N, C, steps]`.
fn per_node(v: &[f32], n: usize, c: usize, steps: usize) -> Vec<f64> {
    let mut out = vec![0.0; n * c * steps];
    for i in 0..n {
        for o in 0..c {
            for tau in 0..steps {
                out[(i * c + o) * steps + tau] = v[o * n * steps + i * steps + tau] as f64;
            }
        }
    }
    out
}

impl StepTest for GatedDcc {
    fn name(&self) -> &'static str {
        "gated_dcc"
    }

    fn cases(&self) -> Vec<Where> {
        in_both_blocks(&[Variant::Iastgcn, Variant::PlainTemporal], &[false])
    }

    fn case_tensors(&self, case: &Case, at: Where) -> (Tensors, Tensors) {
        let cfg = &case.cfg;
        let (n, c, t) = (cfg.nodes, cfg.channels, cfg.window);
        let steps = out_steps(cfg, at.block).1;
        // Values an f32 holds exactly, so that every implementation starts from the same.
        let f32s = |seed, len| wide(&random(seed, len, -1.0, 1.0));
        (
            Tensors::from([("Z", f32s(6, n * c * t))]),
            Tensors::from([("H", f32s(7, n * c * steps))]),
        )
    }

    fn reference_forward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
    ) -> Tensors {
        let (f, g) = convolutions(case, at.block, params, &inputs["Z"]);
        let h = gated_dcc_output(&f, g.as_deref());
        let out = out_steps(&case.cfg, at.block);
        Tensors::from([("H", at_out(&h, case.cfg.window, out))])
    }

    fn reference_backward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
        d_outputs: &Tensors,
    ) -> (Tensors, Vec<Vec<f64>>) {
        let (cfg, l, z) = (&case.cfg, at.block, &inputs["Z"]);
        let (f, g) = convolutions(case, l, params, z);
        // dH at the output steps, zero at the others.
        let (t0, steps) = out_steps(cfg, l);
        let t = cfg.window;
        let mut dh = vec![0.0; z.len()];
        for (row, d) in dh.chunks_mut(t).zip(d_outputs["H"].chunks(steps)) {
            row[t0..t0 + steps].copy_from_slice(d);
        }
        let specs = param_specs(cfg);
        let table = Table::new(&specs, params);
        let p = BlockParams::new(&table, cfg, l);
        let mut grads = zero_grads(&specs);
        let d = Dims::new(cfg, 1, l);
        let dil = case.slots.blocks[l].dilation;
        let dz = gated_dcc_backward(&d, dil, &p, z, &f, g.as_deref(), &dh, &mut grads);
        (Tensors::from([("Z", dz)]), grads.values)
    }

    fn handed_back(&self, inputs: &Tensors, mut d_inputs: Tensors) -> Tensors {
        // dG: dZ through step 3's ReLU, Z = ReLU(G) > 0.
        // invariant: test support: both tensors exist, the contract's.
        let dz = d_inputs.get_mut("Z").unwrap();
        for (g, &z) in dz.iter_mut().zip(&inputs["Z"]) {
            if z <= 0.0 {
                *g = 0.0;
            }
        }
        d_inputs
    }

    fn native(&self, case: &mut Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let what = |part: &str| format!("gated_dcc {at} (native): {part}");
        let params: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
        let (f, g) = convolutions(case, l, &params, &inputs["Z"]);
        let Case {
            cfg,
            slots,
            params,
            tape,
            work,
        } = case;
        let s = &slots.blocks[l];
        let (n, t, c) = (cfg.nodes, cfg.window, cfg.channels);
        let b = Block::new(cfg, &[], s, 1);
        let bt = &mut tape.blocks[l];
        let (cols, steps) = (bt.cols, bt.steps);
        let out = out_steps(cfg, l);
        // Z in the tape's layout (at the taps `[N, taps, C]`).
        let z = narrow(&inputs["Z"]);
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
        b.gated_dcc_forward(params, bt);
        // What the tape keeps: tanh(G_f) and σ(G_g) (G_f in `iastgcn-t`), `[outs, N·steps]`.
        let half = n * c * steps;
        match &g {
            Some(g) => {
                let tanh: Vec<f64> = f.iter().map(|v| v.tanh()).collect();
                let sigma: Vec<f64> = g.iter().map(|v| 1.0 / (1.0 + (-v).exp())).collect();
                check(
                    &what("tanh(G_f)"),
                    &per_node(&bt.g[..half], n, c, steps),
                    &at_out(&tanh, t, out),
                );
                check(
                    &what("σ(G_g)"),
                    &per_node(&bt.g[half..2 * half], n, c, steps),
                    &at_out(&sigma, t, out),
                );
            }
            None => check(
                &what("G_f"),
                &per_node(&bt.g[..half], n, c, steps),
                &at_out(&f, t, out),
            ),
        }
        let outputs = Tensors::from([("H", per_node(&bt.hidden, n, c, steps))]);
        work.da[..half].copy_from_slice(&narrow(&d_outputs["H"]));
        let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
        b.gated_dcc_backward(params, bt, &mut grads, work);
        // dG from the tape's layout back to `[N, C, T]`, zero off the kept steps.
        let dg: Vec<f64> = if cols.taps {
            let mut full = vec![0.0; n * c * t];
            for i in 0..n {
                for j in 0..cols.len {
                    for ch in 0..c {
                        full[(i * c + ch) * t + cols.first + cols.stride * j] =
                            work.dz[(i * cols.len + j) * c + ch] as f64;
                    }
                }
            }
            full
        } else {
            work.dz[..n * c * t].iter().map(|&v| v as f64).collect()
        };
        Run::computed(outputs, Tensors::from([("Z", dg)]), &grads)
    }

    fn wgsl(&self, case: &Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run {
        let l = at.block;
        let what = |part: &str| format!("gated_dcc {at} (wgsl): {part}");
        let cfg = &case.cfg;
        let (n, t, ci) = (cfg.nodes, cfg.window, cfg.block_input(l));
        let params: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
        let (f, g) = convolutions(case, l, &params, &inputs["Z"]);
        let out = out_steps(cfg, l);
        let dev = Device::new(cfg, l, &case.params, &[], &vec![0.0; n * ci * t]);
        dev.write("Z", &narrow(&inputs["Z"]));
        dev.run(|b, p, _, st| b.gated_dcc_forward(gpu(), p, st, Pass::Train));
        // What the device keeps: G_f and G_g at the output steps.
        check(&what("G_f"), &dev.read_buffer("G_f"), &at_out(&f, t, out));
        if let Some(g) = &g {
            check(&what("G_g"), &dev.read_buffer("G_g"), &at_out(g, t, out));
        }
        let outputs = Tensors::from([("H", dev.read_buffer("H"))]);
        let dh = dev.upload("dH", &narrow(&d_outputs["H"]));
        let dg = dev.run(|b, p, sc, st| b.gated_dcc_backward(gpu(), p, sc, st, &dh));
        Run::computed(outputs, Tensors::from([("Z", dev.read(&dg))]), &dev.grads())
    }
}
