//! What the step tests share. Each step's `tests.rs` implements [`StepTest`]: its cases,
//! random inputs and output gradients under its contract's names, its f64 reference
//! forward and backward at the implementations' boundaries, and one run of each f32
//! implementation (the native step on a case's memory, and the WGSL step on the device
//! block run one step at a time, [`Device`]). `every_step.rs` drives them all and names
//! the step, the case and the implementation that broke ("gated_dcc iastgcn block 1
//! (wgsl): d blocks.1.tcn.gate.weight: element 3 …").
//!
//! Each step runs in a block with every output step and in a last block. In the last
//! block the native steps keep steps 4–7 at T − 1 and X_t, M and Z at the taps step 4
//! reads, and are compared where they compute ([`StepTest::native_outputs`]); the WGSL
//! block ([`Extent::LastStep`]) computes steps 4–7 at T − 1 and steps 1–3 on all T steps,
//! and is compared there. Every step reads the same random inputs, not an earlier step's
//! outputs, so that a wrong earlier step does not fail it. Both f32 paths are held to
//! the same tolerance.
//!
//! This file holds the trait and its tensors ([`Tensors`], [`Where`], [`Run`]), the
//! random case ([`case`]), the comparison ([`check`]), the WGSL block run one step at a
//! time ([`Device`]) and the kept steps' layout ([`at_cols`], [`from_cols`]).
#![cfg(test)]

use crate::gpu::{DType, Gpu, GpuError, Recorder, Tensor};
use crate::model::block::slots::Slots;
use crate::model::block::tape::{Cols, Tape, Work};
use crate::model::block::wgsl::{Block as Wgsl, Extent, Table};
use crate::model::config::{ModelConfig, Variant};
use crate::model::exact::Grads;
use crate::model::params::{param_specs, ParamSpec, Parameters};
use crate::model::schedule::{Scratch, Steps};
use std::collections::BTreeMap;
use std::sync::OnceLock;

use crate::testing;

/// f32 steps against f64 sums of a few dozen terms of order 1: |a − e| ≤ ABS + REL·|e|.
pub(super) const ABS: f64 = 2e-5;
pub(super) const REL: f64 = 2e-4;

/// `n` values uniform in [lo, hi) from a generator seeded with `seed`.
pub(super) fn uniform(seed: u64, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    testing::uniform(&mut testing::rng(seed), n, lo, hi)
}

/// A small network of `variant` (C 8, T 12, L 2: block 1 is the last) with its
/// parameters perturbed away from their initial values, and its memory.
pub(super) struct Case {
    pub(super) cfg: ModelConfig,
    pub(super) slots: Slots,
    pub(super) params: Vec<Vec<f32>>,
    pub(super) tape: Tape,
    pub(super) work: Work,
}

pub(super) fn case(variant: Variant) -> Case {
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

pub(super) fn wide(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// What a test leaves in a gradient buffer that a step's backward adds to (dX, where the
/// residual's backward wrote first), so that a backward that overwrites it fails;
/// [`added`] takes it off again.
pub(super) const LEFT: f32 = 0.5;

/// A buffer's contents less [`LEFT`]: what the backward added.
pub(super) fn added(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| (x - LEFT) as f64).collect()
}

/// `n` random values in [lo, hi), already f32.
pub(super) fn random(seed: u64, n: usize, lo: f64, hi: f64) -> Vec<f32> {
    uniform(seed, n, lo, hi).iter().map(|&v| v as f32).collect()
}

/// Panics naming `what` and the worst element unless every element is within tolerance.
pub(super) fn check(what: &str, actual: &[f64], expected: &[f64]) {
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

/// The device every step test shares, opened once (`crate::testing::gpu()` opens one a
/// call): each test's pipelines are compiled once.
pub(super) fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    // invariant: test support: a test without a device fails with the reason.
    GPU.get_or_init(testing::gpu)
}

/// Block `l` of the WGSL path on one window (batch 1) of `cfg`, with `params` (in
/// `param_specs` order), the graph `basis` (`[terms, N, N]`, empty for none) and the
/// block input `x` `[N, C_in, T]` uploaded: [`Extent::LastStep`] for the last block, as
/// the network builds it (steps 4–7 at T − 1 only), [`Extent::Window`] otherwise; its
/// dropout seeded with [`Device::SEED`].
pub(super) struct Device {
    pub(super) specs: Vec<ParamSpec>,
    /// The parameters and their (zeroed) gradients, in `specs` order.
    pub(super) params: Vec<Tensor>,
    pub(super) grads: Vec<Tensor>,
    pub(super) basis: Option<Tensor>,
    pub(super) block: Wgsl,
}

impl Device {
    pub(super) const SEED: u32 = 3;

    pub(super) fn new(
        cfg: &ModelConfig,
        l: usize,
        params: &[Vec<f32>],
        basis: &[f32],
        x: &[f32],
    ) -> Device {
        let g = gpu();
        let specs = param_specs(cfg);
        let (params, grads) = specs
            .iter()
            .zip(params)
            .map(|(spec, v)| {
                let value = g.upload(&spec.name, &spec.shape, v).unwrap();
                let grad = g.zeros(&format!("grad {}", spec.name), &spec.shape, DType::F32);
                (value, grad.unwrap())
            })
            .unzip();
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
            params,
            grads,
            basis,
            block,
        }
    }

    /// The parameters by name, as the network's schedules look them up.
    pub(super) fn table(&self) -> Table<'_> {
        Table::new(&self.specs, &self.params, &self.grads, self.basis.as_ref())
    }

    /// Overwrites the block's buffer of `role` ([`Wgsl::buffer`]).
    pub(super) fn write(&self, role: &str, data: &[f32]) {
        gpu().write(self.block.buffer(role), data).unwrap();
    }

    /// A new device tensor holding `data`.
    pub(super) fn upload(&self, name: &str, data: &[f32]) -> Tensor {
        gpu().upload(name, &[data.len()], data).unwrap()
    }

    pub(super) fn read(&self, t: &Tensor) -> Vec<f64> {
        let mut v = gpu().read_f32(t).unwrap();
        v.truncate(t.numel());
        wide(&v)
    }

    pub(super) fn read_buffer(&self, role: &str) -> Vec<f64> {
        self.read(self.block.buffer(role))
    }

    /// Every parameter's gradient, in `param_specs` order.
    pub(super) fn grads(&self) -> Vec<Vec<f32>> {
        self.grads.iter().map(|t| narrow(&self.read(t))).collect()
    }

    /// Runs the dispatches `f` schedules (one step's methods) and waits for them;
    /// returns what `f` returned.
    pub(super) fn run<R>(
        &self,
        f: impl FnOnce(&Wgsl, &Table, &mut Scratch, &mut Steps) -> Result<R, GpuError>,
    ) -> R {
        let g = gpu();
        let mut scratch = Scratch::new(g);
        let mut steps = Steps::default();
        let r = f(&self.block, &self.table(), &mut scratch, &mut steps).unwrap();
        let mut rec = Recorder::new(g);
        steps.record(&mut rec).unwrap();
        rec.submit().unwrap();
        g.wait().unwrap();
        r
    }
}

// ---------------------------------------------------------------------------------------
// For steps 1–3, against the steps' f64 references.

pub(super) fn narrow(v: &[f64]) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}

/// Zero gradients of every parameter, for the reference to add to.
pub(super) fn zero_grads(specs: &[ParamSpec]) -> Grads<'_> {
    Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    }
}

/// Rows of T `[.., T]` at the kept steps, `[.., cols.len]`.
pub(super) fn at_cols(cols: &Cols, v: &[f64], t: usize) -> Vec<f64> {
    v.chunks(t)
        .flat_map(|r| (0..cols.len).map(move |j| r[cols.first + cols.stride * j]))
        .collect()
}

/// The adjoint of [`at_cols`]: rows of `cols.len` to rows of T, zero off the kept steps.
pub(super) fn from_cols(cols: &Cols, v: &[f64], t: usize) -> Vec<f64> {
    let mut out = vec![0.0; v.len() / cols.len * t];
    for (r, o) in v.chunks(cols.len).zip(out.chunks_mut(t)) {
        for (j, &x) in r.iter().enumerate() {
            o[cols.first + cols.stride * j] = x;
        }
    }
    out
}

// ---------------------------------------------------------------------------------------
// The generic step test's contract (`every_step.rs`).

/// Named tensors of one window in the reference's layout (`[N, C, T]` and the like; the
/// outputs of steps 4–7 at the block's output steps only, [`out_steps`]).
pub(super) type Tensors = BTreeMap<&'static str, Vec<f64>>;

/// Where a step runs: the variant, the block (of [`case`]'s two; block 1 is the last),
/// and whether with the dropout of a training step (steps 5–7 only).
#[derive(Clone, Copy, Debug)]
pub(super) struct Where {
    pub(super) variant: Variant,
    pub(super) block: usize,
    pub(super) dropout: bool,
}

impl std::fmt::Display for Where {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "{} block {}", self.variant.name(), self.block)?;
        if self.dropout {
            write!(f, " with dropout")?;
        }
        Ok(())
    }
}

/// What an implementation of a step computed from its inputs and its outputs' gradients.
pub(super) struct Run {
    /// What the step hands the next one, by name.
    pub(super) outputs: Tensors,
    /// Its backward (none where the implementation has no backward for the case: the
    /// WGSL steps 5–7 without dropout are inference's).
    pub(super) backward: Option<Backward>,
}

impl Run {
    /// An f32 implementation's run: its outputs, the gradients its backward handed back and
    /// every parameter's gradient (in `param_specs` order).
    pub(super) fn computed(outputs: Tensors, d_inputs: Tensors, d_params: &[Vec<f32>]) -> Run {
        Run {
            outputs,
            backward: Some(Backward {
                d_inputs,
                d_params: d_params.iter().map(|v| wide(v)).collect(),
            }),
        }
    }
}

/// Blocks 0 and 1 (the last, of the test's two) of each of `variants`, with or without
/// dropout as `dropout` lists.
pub(super) fn in_both_blocks(variants: &[Variant], dropout: &[bool]) -> Vec<Where> {
    let mut cases = Vec::new();
    for &variant in variants {
        for block in [0, 1] {
            for &dropout in dropout {
                cases.push(Where {
                    variant,
                    block,
                    dropout,
                });
            }
        }
    }
    cases
}

/// What a step's backward computed.
#[derive(Clone)]
pub(super) struct Backward {
    /// What it hands the earlier step, by the name of the input it belongs to.
    pub(super) d_inputs: Tensors,
    /// Every parameter's gradient, in `param_specs` order (zero for other steps').
    pub(super) d_params: Vec<Vec<f64>>,
}

/// One step as the generic test drives it: its cases, its f64 reference and its two f32
/// implementations, all with the same inputs, outputs and gradients (the step's contract,
/// its folder's `mod.rs`).
pub(super) trait StepTest {
    /// The step's folder name.
    fn name(&self) -> &'static str;
    /// The variants and blocks it runs in.
    fn cases(&self) -> Vec<Where>;
    /// Random inputs and output gradients (values an f32 holds exactly).
    fn case_tensors(&self, case: &Case, at: Where) -> (Tensors, Tensors);
    /// The reference's outputs from `inputs` and `params` (in `param_specs` order).
    fn reference_forward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
    ) -> Tensors;
    /// The reference's gradients of Σ d_out·out: for every input, and every parameter.
    fn reference_backward(
        &self,
        case: &Case,
        at: Where,
        params: &[Vec<f64>],
        inputs: &Tensors,
        d_outputs: &Tensors,
    ) -> (Tensors, Vec<Vec<f64>>);
    /// What the step's backward hands back from the gradients of its inputs, when that
    /// is not the gradients themselves (step 4: dG, dZ through step 3's ReLU).
    fn handed_back(&self, _inputs: &Tensors, d_inputs: Tensors) -> Tensors {
        d_inputs
    }
    /// The reference's outputs where the native step computes them, in its layout, when
    /// that is not everywhere (the native last block keeps X_t, M and Z at the taps step
    /// 4 reads only).
    fn native_outputs(&self, _case: &Case, _at: Where, outputs: Tensors) -> Tensors {
        outputs
    }
    /// The native step on `case`'s memory.
    fn native(&self, case: &mut Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run;
    /// The WGSL step on the device, alone.
    fn wgsl(&self, case: &Case, at: Where, inputs: &Tensors, d_outputs: &Tensors) -> Run;
}

/// The first output step and how many the block computes steps 4–7 at: (0, T), or
/// (T − 1, 1) in the last block.
pub(super) fn out_steps(cfg: &ModelConfig, l: usize) -> (usize, usize) {
    if l + 1 == cfg.blocks {
        (cfg.window - 1, 1)
    } else {
        (0, cfg.window)
    }
}
