//! One test per step of the ST block across its three implementations: the same random
//! case goes through the f64 reference of the step's op, the native f32 step (this
//! module's parent) and the WGSL step (`model::block`, run alone on the device), forward
//! and backward, so that a wrong step in either implementation is named by the failing
//! assertion ("gated_dcc iastgcn block 1 (wgsl): d gate.weight: element 3 …"; "(native)"
//! for the native step). The references: `temporal_attention` and `spatial_attention`
//! against `model::reference::attention`, `graph_conv` against
//! `model::reference::graph_conv` (the node mixing (I + S')·X_t, which the reference does
//! in step 2 and both blocks in step 3, and at the taps the time mixing X·(I + E') are
//! written out here), `gated_dcc` against `ops::gated_dcc::cpu`, `residual_layer_norm`
//! and `layer_norm_dropout` (WGSL: `residual_layer_norm` and `dropout`) against
//! `ops::layer_norm::cpu` (the residual 1×1 convolution and the ReLUs around it are
//! written out here, a sum each). Each runs in a block with every output step and in a
//! last block, gated (`iastgcn`) and not (`iastgcn-t`); `graph_conv` in `iastgcn`,
//! `iastgcn-a` (no attention), `iastgcn-s` (the Chebyshev basis) and `st-gat` (its graph
//! attention, every step in both blocks). In the last block the native steps keep steps
//! 4–7 at T − 1 and X_t, M and Z at the taps; the WGSL block ([`Extent::LastStep`])
//! computes steps 4–7 at T − 1 and steps 1–3 on all T steps, and is compared there. Each
//! step reads its inputs from the reference's earlier steps (rounded to f32), not from
//! the implementation's own, so that a wrong earlier step does not fail it; where a WGSL
//! step's boundary differs from the native one (`model::block`'s step table), its input
//! or output is converted here (dG = dZ masked by Z > 0, the dropout of a batch of one).
//! Both f32 paths are held to the same tolerance.
#![cfg(test)]

use super::tape::{Cols, Masks, Tape, Work};
use super::{
    gated_dcc, graph_conv, layer_norm_dropout, residual_layer_norm, spatial_attention,
    temporal_attention, Block,
};
use crate::gpu::{DType, Gpu, GpuError, Recorder, Tensor};
use crate::graph::Graph;
use crate::model::block::{Block as Wgsl, Extent, ParamTable, Pass};
use crate::model::config::{ModelConfig, Variant};
use crate::model::native::slots::Slots;
use crate::model::params::{graph_basis, param_specs, ParamSpec, Parameters};
use crate::model::reference::{
    attention, graph_conv as reference_gc, BlockParams, Dims, Grads, Table,
};
use crate::model::schedule::{Scratch, Steps};
use crate::ops::dropout::keep;
use crate::ops::gated_dcc::{cpu as dcc, Unfold};
use crate::ops::layer_norm::{cpu as norm, LayerNorm};
use crate::ops::Accumulate::Overwrite;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;
use std::sync::OnceLock;

/// f32 steps against f64 sums of a few dozen terms of order 1: |a − e| ≤ ABS + REL·|e|.
/// (`crate::testing` has the same comparison, but `model` may not import it.)
const ABS: f64 = 2e-5;
const REL: f64 = 2e-4;

/// `n` values uniform in [lo, hi) from a generator seeded with `seed`.
fn uniform(seed: u64, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    let mut g = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| g.random_range(lo..hi)).collect()
}

/// A small network of `variant` (C 8, T 12, L 2: block 1 is the last) with its
/// parameters perturbed away from their initial values, and its memory.
struct Case {
    cfg: ModelConfig,
    slots: Slots,
    params: Vec<Vec<f32>>,
    tape: Tape,
    work: Work,
}

fn case(variant: Variant) -> Case {
    let cfg = ModelConfig {
        variant,
        channels: 8,
        window: 12,
        blocks: 2,
        ..ModelConfig::default()
    };
    let slots = Slots::new(&cfg, &param_specs(&cfg)).unwrap();
    let params = Parameters::init(&cfg, 1)
        .values
        .into_iter()
        .enumerate()
        .map(|(i, v)| {
            let noise = uniform(100 + i as u64, v.len(), -0.2, 0.2);
            v.iter().zip(noise).map(|(a, e)| a + e as f32).collect()
        })
        .collect();
    Case {
        tape: Tape::new(&cfg, &slots),
        work: Work::new(&cfg),
        cfg,
        slots,
        params,
    }
}

fn wide(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// `n` random values in [lo, hi), already f32.
fn random(seed: u64, n: usize, lo: f64, hi: f64) -> Vec<f32> {
    uniform(seed, n, lo, hi).iter().map(|&v| v as f32).collect()
}

/// Panics naming `what` and the worst element unless every element is within tolerance.
fn check(what: &str, actual: &[f64], expected: &[f64]) {
    assert_eq!(actual.len(), expected.len(), "{what}: lengths");
    for (i, (a, e)) in actual.iter().zip(expected).enumerate() {
        assert!(
            (a - e).abs() <= ABS + REL * e.abs(),
            "{what}: element {i} is {a}, expected {e}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// The WGSL block (`model::block`), one step at a time.

/// The device every test shares (made as `crate::testing::gpu()` makes one; `model` may
/// not import `testing`): each test's pipelines are compiled once.
fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    // invariant: test support: a test without a device fails with the reason.
    GPU.get_or_init(|| Gpu::new().unwrap_or_else(|e| panic!("{e}")))
}

/// The parameters and their (zeroed) gradients on the device, by name, and the graph
/// basis.
struct DeviceParams {
    tensors: HashMap<String, (Tensor, Tensor)>,
    basis: Option<Tensor>,
}

impl ParamTable for DeviceParams {
    fn param(&self, name: &str) -> &Tensor {
        if name == "graph.basis" {
            return self.basis.as_ref().expect("the case has a graph basis");
        }
        &self.tensors[name].0
    }

    fn grad(&self, name: &str) -> &Tensor {
        &self.tensors[name].1
    }
}

/// Block `l` of the WGSL path on one window (batch 1) of `cfg`, with `params` (in
/// `param_specs` order), the graph `basis` (`[terms, N, N]`, empty for none) and the
/// block input `x` `[N, C_in, T]` uploaded: [`Extent::LastStep`] for the last block, as
/// the network builds it (steps 4–7 at T − 1 only), [`Extent::Window`] otherwise; its
/// dropout seeded with [`Device::SEED`].
struct Device {
    specs: Vec<ParamSpec>,
    table: DeviceParams,
    block: Wgsl,
}

impl Device {
    const SEED: u32 = 3;

    fn new(cfg: &ModelConfig, l: usize, params: &[Vec<f32>], basis: &[f32], x: &[f32]) -> Device {
        let g = gpu();
        let specs = param_specs(cfg);
        let tensors = specs
            .iter()
            .zip(params)
            .map(|(spec, v)| {
                let value = g.upload(&spec.name, &spec.shape, v).unwrap();
                let grad = g.zeros(&format!("grad {}", spec.name), &spec.shape, DType::F32);
                (spec.name.clone(), (value, grad.unwrap()))
            })
            .collect();
        let basis =
            (!basis.is_empty()).then(|| g.upload("graph.basis", &[basis.len()], basis).unwrap());
        let (n, t, ci) = (cfg.nodes, cfg.window, cfg.block_input(l));
        let input = g.upload("x", &[1, n, ci, t], x).unwrap();
        let extent = if l + 1 == cfg.blocks {
            Extent::LastStep
        } else {
            Extent::Window
        };
        let block = Wgsl::new(g, cfg, l, 1, &input, Device::SEED, extent).unwrap();
        Device {
            specs,
            table: DeviceParams { tensors, basis },
            block,
        }
    }

    /// Overwrites the block's buffer of `role` ([`Wgsl::buffer`]).
    fn write(&self, role: &str, data: &[f32]) {
        gpu().write(self.block.buffer(role), data).unwrap();
    }

    /// A new device tensor holding `data`.
    fn upload(&self, name: &str, data: &[f32]) -> Tensor {
        gpu().upload(name, &[data.len()], data).unwrap()
    }

    fn read(&self, t: &Tensor) -> Vec<f64> {
        let mut v = gpu().read_f32(t).unwrap();
        v.truncate(t.numel());
        wide(&v)
    }

    fn read_buffer(&self, role: &str) -> Vec<f64> {
        self.read(self.block.buffer(role))
    }

    /// Every parameter's gradient, in `param_specs` order.
    fn grads(&self) -> Vec<Vec<f32>> {
        self.specs
            .iter()
            .map(|s| narrow(&self.read(self.table.grad(&s.name))))
            .collect()
    }

    /// Runs the dispatches `f` schedules (one step's methods) and waits for them;
    /// returns what `f` returned.
    fn run<R>(
        &self,
        f: impl FnOnce(&Wgsl, &DeviceParams, &mut Scratch, &mut Steps) -> Result<R, GpuError>,
    ) -> R {
        let g = gpu();
        let mut scratch = Scratch::new(g);
        let mut steps = Steps::default();
        let r = f(&self.block, &self.table, &mut scratch, &mut steps).unwrap();
        let mut rec = Recorder::new(g);
        steps.record(&mut rec).unwrap();
        rec.submit().unwrap();
        g.wait().unwrap();
        r
    }
}

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
    // dZ before Z's ReLU (step 3's), from the tape's layout back to `[N, C, T]`.
    let native_dz: Vec<f64> = if cols.taps {
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
    check(&what("dZ"), &native_dz, &dz);

    // The WGSL step on the same Z and parameters, from the same dH: G_f, G_g and H =
    // tanh(G_f) ⊙ σ(G_g) (ReLU(G_f) in `iastgcn-t`) at the steps the block keeps, and dG
    // = dZ masked by Z > 0 (step 3's ReLU, which the unfolding's backward applies).
    let what = |part: &str| format!("gated_dcc {} block {l} (wgsl): {part}", variant.name());
    let dev = Device::new(&cfg, l, &params, &[], &vec![0.0; n * s.c_in * t]);
    dev.write("Z", &z);
    dev.run(|b, p, _, st| b.gated_dcc_forward(gpu(), p, st, Pass::Train));
    check(&what("G_f"), &dev.read_buffer("G_f"), &gf);
    let h: Vec<f64> = match &gg {
        Some(gg) => {
            check(&what("G_g"), &dev.read_buffer("G_g"), gg);
            gf.iter()
                .zip(gg)
                .map(|(f, g)| f.tanh() / (1.0 + (-g).exp()))
                .collect()
        }
        None => gf.iter().map(|f| f.max(0.0)).collect(),
    };
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
    let masked: Vec<f64> = dz
        .iter()
        .zip(&z)
        .map(|(&d, &zv)| if zv > 0.0 { d } else { 0.0 })
        .collect();
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
/// training step or without: the native `residual_layer_norm` then `layer_norm_dropout`,
/// and the WGSL `residual_layer_norm` then `dropout` (without dropout, the WGSL check
/// reads Y before the dropout and starts the backward from dY).
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
    // Step 4's output on the tape: [tanh(G_f); σ(G_g)] `[outs, N·steps]`, or G_f.
    let gated = s.gate.is_some();
    let half = c * n * steps;
    let f = random(9, half, -1.0, 1.0);
    let q = random(10, half, 0.0, 1.0);
    bt.g[..half].copy_from_slice(&f);
    if gated {
        bt.g[half..2 * half].copy_from_slice(&q);
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
    layer_norm_dropout::forward(&b, &params, bt, mask, last.then_some(&mut h[..]));
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
                hv[at(i, o, tau)] = if gated {
                    f[g] as f64 * q[g] as f64
                } else {
                    (f[g] as f64).max(0.0)
                };
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
    check(&what("native", "layer_norm_dropout: Y"), &native_y, &e.y);
    // Backward from dY.
    work.dy[..dy.len()].copy_from_slice(&dy);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    layer_norm_dropout::backward(&b, bt, drop, &mut grads, &mut work);
    residual_layer_norm::backward(&b, &params, &x, bt, true, &mut grads, &mut work);
    let checks = |path: &str, grads: &[Vec<f32>], da: &[f64], dx: &[f64], e: &NormReference| {
        let w = |part: &str| what(path, part);
        check(
            &w("layer_norm_dropout: dγ"),
            &wide(&grads[s.gamma]),
            &e.dgamma,
        );
        check(
            &w("layer_norm_dropout: dβ"),
            &wide(&grads[s.beta]),
            &e.dbeta,
        );
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
    dev.run(|b, p, _, st| b.residual_layer_norm_forward(gpu(), p, st, Pass::Train));
    let what_wgsl = |part: &str| what("wgsl", part);
    check(
        &what_wgsl("residual_layer_norm: A"),
        &dev.read_buffer("H"),
        &act,
    );
    let one = Masks {
        batch: 1,
        item: 0,
        ..masks
    };
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
    let d_out = dev.upload("d output", &dy);
    let d_in = dev.upload("dX", &vec![0.0; n * ci * t]);
    let ds = if drop {
        dev.run(|b, _, _, st| {
            let slot = b.dropout_forward(gpu(), st)?;
            let d = st.dispatch(slot).expect("the dropout is a dispatch");
            b.dropout().set_step(gpu(), d, one.step, Overwrite)?;
            Ok(slot)
        });
        check(&what_wgsl("dropout: Y"), &dev.read_buffer("output"), &e.y);
        dev.run(|b, p, sc, st| {
            let (dy, slot) = b.dropout_backward(gpu(), sc, st, &d_out)?;
            let d = st.dispatch(slot).expect("the dropout is a dispatch");
            b.dropout().set_step(gpu(), d, one.step, Overwrite)?;
            b.residual_layer_norm_backward(gpu(), p, sc, st, &dy, &d_in)
        })
    } else {
        check(
            &what_wgsl("residual_layer_norm: Y"),
            &dev.read_buffer("Y"),
            &e.y,
        );
        dev.run(|b, p, sc, st| b.residual_layer_norm_backward(gpu(), p, sc, st, &d_out, &d_in))
    };
    checks("wgsl", &dev.grads(), &dev.read(&ds), &dev.read(&d_in), &e);
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

// ---------------------------------------------------------------------------------------
// Steps 1–3 against `model::reference`'s f64 steps (`attention.rs`, `graph_conv.rs`).

fn narrow(v: &[f64]) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}

/// Zero gradients of every parameter, for the reference to add to.
fn zero_grads(specs: &[ParamSpec]) -> Grads<'_> {
    Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    }
}

/// Every parameter's gradient of the native step against the reference's: a step adds to
/// its own parameters and leaves every other one zero.
fn check_grads(what: &dyn Fn(&str) -> String, native: &[Vec<f32>], reference: &Grads) {
    for ((spec, a), e) in reference.specs.iter().zip(native).zip(&reference.values) {
        check(&what(&format!("d {}", spec.name)), &wide(a), e);
    }
}

/// Rows of T `[.., T]` at the kept steps, `[.., cols.len]`.
fn at_cols(cols: &Cols, v: &[f64], t: usize) -> Vec<f64> {
    v.chunks(t)
        .flat_map(|r| (0..cols.len).map(move |j| r[cols.first + cols.stride * j]))
        .collect()
}

/// The adjoint of [`at_cols`]: rows of `cols.len` to rows of T, zero off the kept steps.
fn from_cols(cols: &Cols, v: &[f64], t: usize) -> Vec<f64> {
    let mut out = vec![0.0; v.len() / cols.len * t];
    for (r, o) in v.chunks(cols.len).zip(out.chunks_mut(t)) {
        for (j, &x) in r.iter().enumerate() {
            o[cols.first + cols.stride * j] = x;
        }
    }
    out
}

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

/// The node mixing X_s = (I + S')·X_t (rows of `width` per node) backward from dX_s:
/// (dS' = dX_s·X_tᵀ, dX_t = (I + S')ᵀ·dX_s). The reference computes it first thing in
/// `spatial_attention_backward`, not as a function of its own, and the native block in
/// `graph_conv` (Q = Ψ·(I + S')): written out here, a sum each.
fn node_mix_backward(
    n: usize,
    width: usize,
    s: &[f64],
    xt: &[f64],
    dxs: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let mut ds = vec![0.0; n * n];
    let mut dxt = dxs.to_vec();
    for i in 0..n {
        let gi = &dxs[i * width..][..width];
        for j in 0..n {
            let xj = &xt[j * width..][..width];
            ds[i * n + j] = gi.iter().zip(xj).map(|(g, x)| g * x).sum();
            for (d, g) in dxt[j * width..][..width].iter_mut().zip(gi) {
                *d += s[i * n + j] * g;
            }
        }
    }
    (ds, dxt)
}

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

/// Step 1 forward and backward in block `l` of `variant`, against
/// `reference::attention::temporal_attention` and its backward (the reference's dX_t zero
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
    let tp = p.temporal.as_ref().expect("the variant attends");
    let d = Dims::new(&cfg, 1, l);
    let xf = wide(&x);
    let ta = attention::temporal_attention(&d, &xf, tp);
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
    attention::temporal_attention_backward(
        &d,
        &xf,
        tp,
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

/// Step 2 forward and backward in block `l` of `variant`, against
/// `reference::attention::spatial_attention` and its backward, on the reference's step 1
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
    let (tp, sp) = (
        p.temporal.as_ref().expect("the variant attends"),
        p.spatial.as_ref().expect("the variant attends"),
    );
    let d = Dims::new(&cfg, 1, l);
    let xf = wide(&x);
    let ta = attention::temporal_attention(&d, &xf, tp);
    let sa = attention::spatial_attention(&d, &ta.output, sp);
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
    let dxt = attention::spatial_attention_backward(
        &d,
        &ta.output,
        sp,
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

    // The WGSL step on the same X_t, from the same dS' and no dM (the Qᵀ·dM that it adds
    // to dX_t last is step 3's, checked there): S', and the attention's part of dX_t on
    // all T steps.
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
    let dm = dev.upload("dM", &vec![0.0; n * ci * t]);
    let dxt_dev = dev.run(|b, p, sc, st| b.spatial_attention_backward(gpu(), p, sc, st, &dsp, &dm));
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
    let attended = p.temporal.as_ref().zip(p.spatial.as_ref()).map(|(tp, sp)| {
        let ta = attention::temporal_attention(&d, &xf, tp);
        let sa = attention::spatial_attention(&d, &ta.output, sp);
        (ta, sa)
    });
    if let Some((ta, sa)) = &attended {
        bt.xt
            .copy_from_slice(&narrow(&at_cols(&cols, &ta.output, t)));
        bt.s.copy_from_slice(&narrow(&sa.weights));
    }
    let xs = attended.as_ref().map_or(&xf[..], |(_, sa)| &sa.output[..]);
    graph_conv::forward(&b, &params, &x, bt);
    let psi = s
        .theta
        .map(|theta| reference_gc::graph_kernel(n, &basis, &values[theta]))
        .unwrap_or_default();
    let (q, z) = if s.theta.is_some() {
        check(&what("Ψ"), &wide(&bt.psi), &psi);
        reference_gc::graph_conv(&d, &psi, &values[s.w], xs)
    } else {
        reference_gc::graph_attention(&d, cfg.heads, &basis, &p, xs)
    };
    check(
        &what("Z"),
        &wide(&bt.z),
        &tape_layout(&cols, c, &at_cols(&cols, &z, t)),
    );
    // Backward from dZ at the kept steps (zero off them for the reference).
    let dz = uniform(17, n * c * cols.len, -1.0, 1.0);
    let dz32 = narrow(&tape_layout(&cols, c, &dz));
    work.dz[..dz32.len()].copy_from_slice(&dz32);
    work.dsp.fill(0.0);
    work.dxt.fill(0.0);
    work.dx.fill(0.0);
    let mut grads: Vec<Vec<f32>> = params.iter().map(|p| vec![0.0; p.len()]).collect();
    graph_conv::backward(&b, &params, &x, bt, true, &mut grads, &mut work);
    let mut reference = zero_grads(&specs);
    let dz = from_cols(&cols, &dz, t);
    let dxs = if s.theta.is_some() {
        reference_gc::graph_conv_backward(&d, &basis, &p, &psi, &q, &z, xs, &dz, &mut reference)
    } else {
        reference_gc::graph_attention_backward(
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
    // on all T steps, from the same dZ masked by Z > 0 (its backward starts past Z's
    // ReLU, which step 4's unfolding applies); with attention, dX_t is its term Qᵀ·dM,
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
    let dxt = dev.upload("dX_t", &vec![0.0; n * ci * t]);
    let for_attention = dev.run(|b, p, sc, st| {
        if gat {
            b.graph_attention_backward(gpu(), p, sc, st, &dg, &d_in)?;
            return Ok(None);
        }
        let a = b.graph_conv_backward(gpu(), p, sc, st, &dg, &d_in)?;
        if let Some(a) = &a {
            b.graph_conv_backward_into_xt(gpu(), st, &a.dm, &dxt)?;
        }
        Ok(a)
    });
    check_grads(&what, &dev.grads(), &reference);
    match (&attended, for_attention) {
        (Some((ta, sa)), Some(a)) => {
            let (dsp, dxt_ref) = node_mix_backward(n, ci * t, &sa.weights, &ta.output, &dxs);
            check(&what("dS'"), &dev.read(&a.dsp), &dsp);
            check(&what("dX_t"), &dev.read(&dxt), &dxt_ref);
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
