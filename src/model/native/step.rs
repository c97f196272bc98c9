//! Training steps of the IASTGCN variants on the CPU in f32: the training forward of
//! every window of a batch with its dropout (`block/`), the loss of eq. 39 (plain or
//! over ensembles), the backward pass (`block/`, its steps in reverse) and Adam, with
//! the windows split over threads. It is the device schedule's arithmetic (same masks, same loss, same
//! update as `shaders/adam.wgsl`); summation orders differ, so the two agree to rounding
//! (tests/native_train.rs).

use crate::model::block::native::{backward, forward};
use crate::model::block::slots::Slots;
use crate::model::block::tape::{Masks, Tape, Work};
use crate::model::conv_lstm::native::{ConvLstmNet, ConvLstmTape};
use crate::model::cpu::{flushing_subnormals, with_products, Products};
use crate::model::dense::native::{DenseNet, DenseTape};
use crate::model::recurrent::native::{RecurrentNet, RecurrentTape};

use super::cores;

use crate::graph::Graph;
use crate::model::config::{Family, ModelConfig};
use crate::model::error::ModelError;
use crate::model::params::{graph_basis, param_specs, ParamSpec, Parameters};
use crate::ops::adam::hyper_values;
use crate::ops::loss::PoseLoss;

/// Adam's constants (docs/model.md "Optimiser and schedule"); λ acts on the tensors
/// whose spec has `decay`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NativeAdam {
    /// β1.
    pub beta1: f64,
    /// β2.
    pub beta2: f64,
    /// ε.
    pub eps: f64,
    /// λ, the weight decay of eq. 39 (applied in the update, as on the device).
    pub weight_decay: f64,
}

/// The shape of one training stage's steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NativeStepShape {
    /// Windows per step.
    pub batch: usize,
    /// Windows per ensemble of the loss (1 for the plain loss); divides `batch`.
    pub group: usize,
    /// The dropout masks' base seed (block l uses seed + l).
    pub seed: u32,
    /// The attitude penalty P of eq. 39.
    pub penalty: f64,
    /// Shares the batch's ensembles are split over (at least 1), one thread each unless
    /// a [`super::cores::Cores`] budget allows fewer. The gradient sums in a fixed order
    /// for a given count, so a run is reproducible with the same count, whatever the
    /// threads that ran it.
    pub threads: usize,
}

/// One worker's tapes (one per window of an ensemble), working memory and gradient sums.
struct Worker {
    tapes: Tapes,
    grads: Vec<Vec<f32>>,
    loss: f64,
}

/// What the network is built from: the ST blocks (the graph basis and every tensor's
/// slot), dense layers or a graph-convolutional GRU.
enum Body {
    Blocks { basis: Vec<f32>, slots: Slots },
    Dense(DenseNet),
    Recurrent(RecurrentNet),
    ConvLstm(ConvLstmNet),
}

/// A worker's tapes for its body, one per window of an ensemble; the recurrent
/// baselines' one tape runs up to [`RECURRENT_WINDOWS`] windows together.
enum Tapes {
    Blocks { tapes: Vec<Tape>, work: Box<Work> },
    Dense(Vec<DenseTape>),
    Recurrent(Box<RecurrentTape>),
    ConvLstm(Vec<ConvLstmTape>),
}

/// Windows the recurrent baselines run together (rounded to whole ensembles): their
/// per-step products have N·B rows instead of N, which amortises each call and each
/// packing of the weights; 32 keeps a worker's tape near 30 MB at T = 48, H = 64.
const RECURRENT_WINDOWS: usize = 32;

/// Parameters, Adam moments and working memory of one model's training on the CPU.
pub struct NativeTraining {
    config: ModelConfig,
    specs: Vec<ParamSpec>,
    body: Body,
    shape: NativeStepShape,
    adam: NativeAdam,
    params: Vec<Vec<f32>>,
    grads: Vec<Vec<f32>>,
    m: Vec<Vec<f32>>,
    v: Vec<Vec<f32>>,
    workers: Vec<Worker>,
}

impl NativeTraining {
    /// Zero parameters and moments for `config`'s variant at `shape`; load weights with
    /// [`NativeTraining::load_parameters`].
    pub fn new(
        config: &ModelConfig,
        graph: &Graph,
        shape: NativeStepShape,
        adam: NativeAdam,
    ) -> Result<NativeTraining, ModelError> {
        config.validate().map_err(ModelError::Config)?;
        if shape.batch == 0 || shape.group == 0 || !shape.batch.is_multiple_of(shape.group) {
            return Err(ModelError::Config(format!(
                "native training: batch {} is not a positive multiple of the ensemble size {}",
                shape.batch, shape.group
            )));
        }
        let specs = param_specs(config);
        let body = if config.variant.family() == Family::Dense {
            Body::Dense(DenseNet::new(config, graph, &specs)?)
        } else if config.variant.family() == Family::Recurrent {
            Body::Recurrent(RecurrentNet::new(config, graph, &specs)?)
        } else if config.variant.family() == Family::ConvRecurrent {
            Body::ConvLstm(ConvLstmNet::new(config, &specs)?)
        } else {
            Body::Blocks {
                basis: graph_basis(graph, config)
                    .iter()
                    .map(|&v| v as f32)
                    .collect(),
                slots: Slots::new(config, &specs)?,
            }
        };
        let zeros = || {
            specs
                .iter()
                .map(|s| vec![0f32; s.numel()])
                .collect::<Vec<_>>()
        };
        let groups = shape.batch / shape.group;
        let threads = shape.threads.clamp(1, groups);
        let workers = (0..threads)
            .map(|_| Worker {
                tapes: match &body {
                    Body::Blocks { slots, .. } => Tapes::Blocks {
                        tapes: (0..shape.group).map(|_| Tape::new(config, slots)).collect(),
                        work: Box::new(Work::new(config)),
                    },
                    Body::Dense(net) => {
                        Tapes::Dense((0..shape.group).map(|_| net.tape()).collect())
                    }
                    Body::Recurrent(net) => {
                        let per_worker = groups.div_ceil(threads) * shape.group;
                        let chunk = recurrent_chunk(shape.group) * shape.group;
                        Tapes::Recurrent(Box::new(net.tape(per_worker.min(chunk))))
                    }
                    Body::ConvLstm(net) => {
                        Tapes::ConvLstm((0..shape.group).map(|_| net.tape()).collect())
                    }
                },
                grads: zeros(),
                loss: 0.0,
            })
            .collect();
        Ok(NativeTraining {
            body,
            params: zeros(),
            grads: zeros(),
            m: zeros(),
            v: zeros(),
            config: config.clone(),
            specs,
            shape: NativeStepShape { threads, ..shape },
            adam,
            workers,
        })
    }

    /// The network's shapes and variant.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// The stage's step shape (with the thread count actually used).
    pub fn shape(&self) -> NativeStepShape {
        self.shape
    }

    /// Name and shape of every tensor, in `param_specs` order.
    pub fn specs(&self) -> &[ParamSpec] {
        &self.specs
    }

    /// Replaces the weights; an error names a tensor whose name or size differs.
    pub fn load_parameters(&mut self, p: &Parameters) -> Result<(), ModelError> {
        check(&self.specs, &p.specs, &p.values)?;
        self.params.clone_from(&p.values);
        Ok(())
    }

    /// A copy of the weights.
    pub fn parameters(&self) -> Parameters {
        Parameters {
            specs: self.specs.clone(),
            values: self.params.clone(),
        }
    }

    /// Copies of Adam's first and second moments.
    pub fn moments(&self) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        (self.m.clone(), self.v.clone())
    }

    /// Replaces Adam's moments (a resumed run); sizes must match the parameters.
    pub fn load_moments(&mut self, m: &[Vec<f32>], v: &[Vec<f32>]) -> Result<(), ModelError> {
        check(&self.specs, &self.specs, m)?;
        check(&self.specs, &self.specs, v)?;
        self.m = m.to_vec();
        self.v = v.to_vec();
        Ok(())
    }

    /// ∂ℒ/∂parameter of the last [`NativeTraining::gradients`] (without the decay term,
    /// which the update adds), in `param_specs` order.
    pub fn last_gradients(&self) -> &[Vec<f32>] {
        &self.grads
    }

    /// ℒ of eq. 39 (no decay term) for the batch `x` `[B, N, F, T]`, `y` `[B, O]` with the
    /// dropout of optimiser step `step`, and its gradient (kept for the update).
    pub fn gradients(&mut self, x: &[f32], y: &[f32], step: u32) -> Result<f64, ModelError> {
        let cfg = &self.config;
        let (b, o) = (self.shape.batch, cfg.outputs);
        let per = cfg.nodes * cfg.features * cfg.window;
        if x.len() != b * per || y.len() != b * o {
            return Err(ModelError::Config(format!(
                "native training: x has {} floats and y {}; a batch of {b} needs {} and {}",
                x.len(),
                y.len(),
                b * per,
                b * o
            )));
        }
        let m = self.shape.group;
        let groups = b / m;
        let threads = self.workers.len();
        let ctx = Context {
            cfg,
            body: &self.body,
            params: &self.params,
            x,
            y,
            step,
            shape: self.shape,
            groups,
        };
        let share = |w: usize| (w * groups / threads)..((w + 1) * groups / threads);
        // Each worker's share on some thread (a run of consecutive workers per thread
        // the budget allows, see `cores`): the sums below, in worker order, are the
        // same whichever thread ran which share.
        let run = |first: usize, workers: &mut [Worker]| {
            with_products(Products::Packed, || {
                flushing_subnormals(|| {
                    for (i, worker) in workers.iter_mut().enumerate() {
                        ctx.run(share(first + i), worker);
                    }
                })
            })
        };
        let lease = cores::lease(threads);
        if lease.threads() == 1 {
            run(0, &mut self.workers);
        } else {
            std::thread::scope(|scope| {
                let mut rest = &mut self.workers[..];
                for part in cores::runs(threads, lease.threads()) {
                    let (mine, tail) = std::mem::take(&mut rest).split_at_mut(part.len());
                    rest = tail;
                    let run = &run;
                    scope.spawn(move || run(part.start, mine));
                }
            });
        }
        drop(lease);
        let mut loss = 0.0;
        for (w, worker) in self.workers.iter().enumerate() {
            for (total, part) in self.grads.iter_mut().zip(&worker.grads) {
                if w == 0 {
                    total.copy_from_slice(part);
                } else {
                    for (a, b) in total.iter_mut().zip(part) {
                        *a += b;
                    }
                }
            }
            loss += worker.loss;
        }
        Ok(loss)
    }

    /// Adam update number `t` (1-based) at learning rate `lr` from the last gradients,
    /// the arithmetic of `shaders/adam.wgsl` in f32.
    pub fn update(&mut self, lr: f64, t: u64) {
        flushing_subnormals(|| self.adam_update(lr, t))
    }

    /// [`NativeTraining::update`]'s arithmetic.
    fn adam_update(&mut self, lr: f64, t: u64) {
        let a = self.adam;
        let [lr, bc1, bc2, _] = hyper_values(lr, a.beta1, a.beta2, t);
        let (b1, b2, eps) = (a.beta1 as f32, a.beta2 as f32, a.eps as f32);
        let (c1, c2) = ((1.0 - a.beta1) as f32, (1.0 - a.beta2) as f32);
        for (i, spec) in self.specs.iter().enumerate() {
            let decay = if spec.decay {
                a.weight_decay as f32
            } else {
                0.0
            };
            let (p, g) = (&mut self.params[i], &self.grads[i]);
            let (m, v) = (&mut self.m[i], &mut self.v[i]);
            for (((w, g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
                let g = g + 2.0 * decay * *w;
                *m = b1 * *m + c1 * g;
                *v = b2 * *v + c2 * g * g;
                *w -= lr * (*m / bc1) / ((*v / bc2).sqrt() + eps);
            }
        }
    }

    /// One optimiser step: [`NativeTraining::gradients`], then [`NativeTraining::update`]
    /// number `step + 1`. Returns the loss.
    pub fn step(&mut self, x: &[f32], y: &[f32], step: u64, lr: f64) -> Result<f64, ModelError> {
        let loss = self.gradients(x, y, step as u32)?;
        self.update(lr, step + 1);
        Ok(loss)
    }
}

/// What every worker of one step reads.
struct Context<'a> {
    cfg: &'a ModelConfig,
    body: &'a Body,
    params: &'a [Vec<f32>],
    x: &'a [f32],
    y: &'a [f32],
    step: u32,
    shape: NativeStepShape,
    groups: usize,
}

impl Context<'_> {
    /// Ensemble `g`'s share of the loss for its predictions `pred` `[M, O]`, and its share
    /// of ∂ℒ/∂ŷ into `dout`: L_g / G and its gradient / G.
    fn group_loss(&self, one: &PoseLoss, g: usize, pred: &[f64], dout: &mut [f32]) -> f64 {
        let len = pred.len();
        let target: Vec<f64> = self.y[g * len..][..len].iter().map(|&v| v as f64).collect();
        let scale = self.groups as f64;
        for (d, v) in dout.iter_mut().zip(one.gradient(pred, &target)) {
            *d = (v / scale) as f32;
        }
        one.value(pred, &target) / scale
    }

    /// Forward and backward of the ensembles in `range` into the worker's sums. The
    /// loss is the mean over ensembles of each ensemble's own loss (for M = 1 the mean
    /// over windows), so ensemble g adds L_g / G and its gradient / G.
    fn run(&self, range: std::ops::Range<usize>, w: &mut Worker) {
        let cfg = self.cfg;
        let (m, o) = (self.shape.group, cfg.outputs);
        let per = cfg.nodes * cfg.features * cfg.window;
        for g in w.grads.iter_mut() {
            g.fill(0.0);
        }
        w.loss = 0.0;
        let one = PoseLoss {
            batch: m,
            outputs: o,
            penalty: self.shape.penalty,
            group: m,
        };
        let mut pred = vec![0f64; m * o];
        if let (Body::Recurrent(net), Tapes::Recurrent(tape)) = (self.body, &mut w.tapes) {
            let chunk = recurrent_chunk(m);
            let mut dout = vec![0f32; chunk.min(range.len()) * m * o];
            for first in range.clone().step_by(chunk) {
                let groups = first..(first + chunk).min(range.end);
                let x = &self.x[groups.start * m * per..groups.end * m * per];
                net.forward(self.params, x, tape);
                let dout = &mut dout[..groups.len() * m * o];
                let outs = tape.output().chunks_exact(m * o);
                for ((g, out), d) in groups.zip(outs).zip(dout.chunks_exact_mut(m * o)) {
                    for (p, &v) in pred.iter_mut().zip(out) {
                        *p = v as f64;
                    }
                    w.loss += self.group_loss(&one, g, &pred, d);
                }
                net.backward(self.params, tape, dout, &mut w.grads);
            }
            return;
        }
        for g in range {
            let masks = |k: usize| Masks {
                seed: self.shape.seed,
                step: self.step,
                batch: self.shape.batch,
                item: g * m + k,
            };
            let x = |k: usize| &self.x[(g * m + k) * per..][..per];
            for k in 0..m {
                let out = match (self.body, &mut w.tapes) {
                    (Body::Blocks { basis, slots }, Tapes::Blocks { tapes, .. }) => {
                        let tape = &mut tapes[k];
                        forward(cfg, basis, slots, self.params, x(k), Some(masks(k)), tape);
                        &tape.out[..]
                    }
                    (Body::Dense(net), Tapes::Dense(tapes)) => {
                        net.forward(self.params, x(k), &mut tapes[k]);
                        tapes[k].output()
                    }
                    (Body::ConvLstm(net), Tapes::ConvLstm(tapes)) => {
                        net.forward(self.params, x(k), &mut tapes[k]);
                        tapes[k].output()
                    }
                    // invariant: a worker's tapes are built for the body (NativeTraining::new).
                    _ => unreachable!("a worker's tapes match the body"),
                };
                for (p, &v) in pred[k * o..][..o].iter_mut().zip(out) {
                    *p = v as f64;
                }
            }
            let mut dout = vec![0f32; m * o];
            w.loss += self.group_loss(&one, g, &pred, &mut dout);
            for k in 0..m {
                let dout = &dout[k * o..][..o];
                match (self.body, &mut w.tapes) {
                    (Body::Blocks { basis, slots }, Tapes::Blocks { tapes, work }) => backward(
                        cfg,
                        basis,
                        slots,
                        self.params,
                        x(k),
                        &tapes[k],
                        dout,
                        &mut w.grads,
                        work,
                    ),
                    (Body::Dense(net), Tapes::Dense(tapes)) => {
                        net.backward(self.params, &mut tapes[k], dout, &mut w.grads)
                    }
                    (Body::ConvLstm(net), Tapes::ConvLstm(tapes)) => {
                        net.backward(self.params, &mut tapes[k], dout, &mut w.grads)
                    }
                    // invariant: a worker's tapes are built for the body (NativeTraining::new).
                    _ => unreachable!("a worker's tapes match the body"),
                }
            }
        }
    }
}

/// Ensembles of `group` windows the recurrent baselines run together.
fn recurrent_chunk(group: usize) -> usize {
    (RECURRENT_WINDOWS / group).max(1)
}

/// Every tensor of `values` has the size of its spec (and `given` names match `specs`).
fn check(specs: &[ParamSpec], given: &[ParamSpec], values: &[Vec<f32>]) -> Result<(), ModelError> {
    if given.len() != specs.len() || values.len() != specs.len() {
        return Err(ModelError::Config(format!(
            "native training: {} tensors given, the model has {}",
            values.len(),
            specs.len()
        )));
    }
    for ((s, g), v) in specs.iter().zip(given).zip(values) {
        if s.name != g.name || v.len() != s.numel() {
            return Err(ModelError::Parameter {
                name: g.name.clone(),
                message: format!(
                    "expected {} {:?} ({} values), got {} {:?} ({} values)",
                    s.name,
                    s.shape,
                    s.numel(),
                    g.name,
                    g.shape,
                    v.len()
                ),
            });
        }
    }
    Ok(())
}
