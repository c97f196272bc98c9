//! One training stage: seeded shuffled mini-batches (single windows, or ensembles of
//! consecutive windows for refinement), each step forward + loss + backward + Adam on the
//! stage's engine (`engine.rs`: on the device, one submit per step with no readback and
//! the step losses read once per epoch; or on the native CPU path), validation, early
//! stopping with the best weights kept, and a divergence guard that replays the failing
//! epoch step by step to say which step and which tensor went bad.

use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

use super::config::TrainConfig;
use super::engine::Engine;
pub use super::error::TrainError;
use super::metrics::ensemble_loss;
use super::optimizer::learning_rate;
use crate::data::{Dataset, OUTPUTS};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{ModelConfig, Network, Parameters};

/// One stage's schedule.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stage {
    /// `core`, or `refine-m10` … (names the stage in logs and states).
    pub name: String,
    /// Windows per ensemble: 1 for the core stage.
    pub group: usize,
    /// lr0 of the stage's inverse-time decay.
    pub lr0: f64,
    /// Epochs at most.
    pub max_epochs: usize,
    /// Epochs without a better validation loss before the stage stops.
    pub patience: usize,
}

/// One finished epoch.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    /// The stage's name (`core`, `refine-m10`, ...).
    pub stage: String,
    /// 1-based.
    pub epoch: usize,
    /// Optimiser steps taken so far in this stage.
    pub step: u64,
    /// Mean of the step losses (eq. 39 without the λ term; the ensemble loss when
    /// refining), standardised label space.
    pub train_loss: f64,
    /// The same loss on the validation split.
    pub val_loss: f64,
    /// Learning rate of the epoch's last step.
    pub lr: f64,
    /// Wall time of the training steps (validation excluded), s.
    pub seconds: f64,
    /// Training throughput: windows per second of `seconds`.
    pub windows_per_s: f64,
    /// Wall time of the validation pass, s.
    #[serde(default)]
    pub validation_seconds: f64,
    /// Wall time of the rest of the epoch: parameter and optimiser-state readbacks and the
    /// snapshot kept for a replay, s. (Files written after the epoch are timed by the
    /// caller: [`super::fit::run_stage`].)
    #[serde(default)]
    pub readback_seconds: f64,
    /// Where the steps ran: the adapter's name, or `native CPU (n threads)`.
    #[serde(default)]
    pub trained_on: String,
}

/// Where a stage stands; saved with the training state so a run can resume.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    /// Epochs completed.
    pub epoch: usize,
    /// Optimiser steps taken in the stage.
    pub step: u64,
    /// The best validation loss so far (infinite before the first epoch).
    pub best_val: f64,
    /// The epoch of `best_val`; 0 until an epoch has finished.
    pub best_epoch: usize,
    /// Epochs in a row without improvement.
    pub bad_epochs: usize,
    /// One record per finished epoch.
    pub history: Vec<EpochRecord>,
    /// The loss of the stage's first step, before any update: the yardstick of the
    /// explosion guard ([`EXPLOSION_FACTOR`]). `None` until the first epoch is done
    /// (and in states saved before the guard existed).
    #[serde(default)]
    pub first_loss: Option<f64>,
}

/// A training loss this many times the stage's first loss (or larger) stops the run as
/// diverged although it is finite: a learning rate far too high makes the loss grow
/// by orders of magnitude per step, while a healthy run's loss never rises 10⁴-fold.
/// The stage's first loss is floored at 10⁻³ so that refining an almost perfect fit
/// is not stopped by noise.
pub const EXPLOSION_FACTOR: f64 = 1e4;

impl Progress {
    fn new() -> Progress {
        Progress {
            epoch: 0,
            step: 0,
            best_val: f64::INFINITY,
            best_epoch: 0,
            bad_epochs: 0,
            history: Vec::new(),
            first_loss: None,
        }
    }
}

/// Training state at an epoch boundary: everything [`Trainer::restore`] needs to
/// continue exactly where the run stopped.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// The stage's schedule.
    pub stage: Stage,
    /// Where it stands.
    pub progress: Progress,
    /// The current weights.
    pub params: Parameters,
    /// The best weights so far.
    pub best: Parameters,
    /// Adam's first moments, in parameter order.
    pub adam_m: Vec<Vec<f32>>,
    /// Adam's second moments, in parameter order.
    pub adam_v: Vec<Vec<f32>>,
}

/// Positions (in `data.windows`) of `range`, grouped into ensembles of `m` consecutive
/// windows of one recording: each run of consecutive windows cut into disjoint blocks of
/// m (a short tail is left out), so an epoch sees every window about once, as in the
/// core stage.
pub fn ensembles(data: &Dataset, range: std::ops::Range<usize>, m: usize) -> Vec<Vec<usize>> {
    consecutive_runs(data, range)
        .iter()
        .flat_map(|run| {
            run.chunks_exact(m)
                .map(<[usize]>::to_vec)
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The positions of `range` split into maximal runs of consecutive windows of one
/// recording (neighbours among all of that recording's windows, whatever their split),
/// in time order.
pub fn consecutive_runs(data: &Dataset, range: std::ops::Range<usize>) -> Vec<Vec<usize>> {
    let key = |p: usize| (data.windows[p].recording, data.windows[p].end);
    let mut all: Vec<(usize, usize)> = (0..data.windows.len()).map(key).collect();
    all.sort_unstable();
    // invariant: all holds the key of every window.
    let rank = |p: usize| all.binary_search(&key(p)).expect("every window is listed");
    let mut order: Vec<usize> = range.collect();
    order.sort_by_key(|&p| key(p));
    let mut runs: Vec<Vec<usize>> = Vec::new();
    for p in order {
        match runs.last_mut() {
            Some(run)
                if {
                    // invariant: a run is pushed with its first member.
                    let last = *run.last().expect("runs are never empty");
                    key(last).0 == key(p).0 && rank(last) + 1 == rank(p)
                } =>
            {
                run.push(p)
            }
            _ => runs.push(vec![p]),
        }
    }
    runs
}

fn epoch_seed(seed: u64, stage: &str, epoch: usize) -> u64 {
    let tag = stage.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    });
    seed ^ tag ^ (epoch as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
}

/// A training stage bound to one network on one device.
pub struct Trainer<'a> {
    data: &'a Dataset,
    config: TrainConfig,
    /// The stage's schedule.
    pub stage: Stage,
    /// The network's shape and variant.
    model: ModelConfig,
    /// The sensor graph (for the native CPU forward of [`Trainer::predict`]).
    graph: Graph,
    /// Where the steps run: the device or the native CPU path.
    engine: Engine,
    batch: usize,
    train_groups: Vec<Vec<usize>>,
    val_groups: Vec<Vec<usize>>,
    groups_per_batch: usize,
    steps_per_epoch: usize,
    /// The current step's windows and their gathered tensors (reused across steps).
    positions: Vec<usize>,
    batch_x: Vec<f32>,
    batch_y: Vec<f32>,
    /// Where the stage stands.
    pub progress: Progress,
    /// The best weights so far (the start's until an epoch improves).
    pub best: Parameters,
    /// Parameters and moments at the start of the current epoch (for the replay).
    start: Snapshot,
}

impl<'a> Trainer<'a> {
    /// A fresh stage starting from `init` with zero Adam moments.
    pub fn new(
        device: &Device,
        data: &'a Dataset,
        graph: &Graph,
        model: &ModelConfig,
        config: &TrainConfig,
        stage: Stage,
        init: &Parameters,
    ) -> Result<Trainer<'a>, TrainError> {
        if data.window.length != model.window || data.nodes.len() != model.nodes {
            return Err(TrainError::Data(format!(
                "the dataset has windows of {} steps over {} nodes, the model expects {} over {}",
                data.window.length,
                data.nodes.len(),
                model.window,
                model.nodes
            )));
        }
        let m = stage.group.max(1);
        let [train, val, _] = data.split_ranges();
        let (train_groups, val_groups) = if m == 1 {
            let single = |r: std::ops::Range<usize>| r.map(|p| vec![p]).collect::<Vec<_>>();
            (single(train), single(val))
        } else {
            (ensembles(data, train, m), ensembles(data, val, m))
        };
        if train_groups.is_empty() {
            return Err(TrainError::Data(format!(
                "stage {}: no training sample of {m} consecutive windows",
                stage.name
            )));
        }
        if val_groups.is_empty() {
            return Err(TrainError::Data(format!(
                "stage {}: no validation sample of {m} consecutive windows (the validation split is too short)",
                stage.name
            )));
        }
        let groups_per_batch = (config.batch / m).max(1).min(train_groups.len());
        let steps_per_epoch = train_groups.len().div_ceil(groups_per_batch);
        let batch = groups_per_batch * m;
        let engine = Engine::new(
            device,
            model,
            graph,
            config,
            batch,
            m,
            steps_per_epoch,
            init,
        )?;
        let (adam_m, adam_v) = engine.moments()?;
        let start = Snapshot {
            stage: stage.clone(),
            progress: Progress::new(),
            params: init.clone(),
            best: init.clone(),
            adam_m,
            adam_v,
        };
        Ok(Trainer {
            data,
            config: config.clone(),
            stage,
            model: model.clone(),
            graph: graph.clone(),
            engine,
            batch,
            train_groups,
            val_groups,
            groups_per_batch,
            steps_per_epoch,
            positions: Vec::with_capacity(batch),
            batch_x: Vec::with_capacity(batch * data.window_len()),
            batch_y: Vec::with_capacity(batch * OUTPUTS),
            progress: Progress::new(),
            best: init.clone(),
            start,
        })
    }

    /// Continues from a saved state (same data, config and stage; the epoch limit and
    /// patience stay this trainer's).
    pub fn restore(&mut self, s: &Snapshot) -> Result<(), TrainError> {
        let same = |a: &Stage, b: &Stage| a.name == b.name && a.group == b.group && a.lr0 == b.lr0;
        if !same(&s.stage, &self.stage) {
            return Err(TrainError::Data(format!(
                "the saved state is of stage {:?} (group {}, lr0 {}), this run is {:?} (group {}, lr0 {})",
                s.stage.name, s.stage.group, s.stage.lr0, self.stage.name, self.stage.group, self.stage.lr0
            )));
        }
        self.engine.load(&s.params)?;
        self.engine.load_moments(&s.adam_m, &s.adam_v)?;
        self.progress = s.progress.clone();
        self.best = s.best.clone();
        self.start = s.clone();
        self.start.stage = self.stage.clone();
        Ok(())
    }

    /// The state at the end of the last finished epoch.
    pub fn snapshot(&self) -> &Snapshot {
        &self.start
    }

    /// Optimiser steps per epoch: ⌈training ensembles / ensembles per step⌉.
    pub fn steps_per_epoch(&self) -> usize {
        self.steps_per_epoch
    }

    /// Windows per optimiser step.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// Where the steps run, for logs and reports: the adapter's name, or
    /// `native CPU (n threads)`.
    pub fn trained_on(&self) -> String {
        self.engine.label()
    }

    /// The device network being trained; `None` when the steps run on the native CPU
    /// path (`[train] backend`).
    pub fn network(&self) -> Option<&Network> {
        self.engine.network()
    }

    /// Sets the epoch limit and patience (e.g. a resumed run allowed more epochs).
    pub fn set_limits(&mut self, max_epochs: usize, patience: usize) {
        self.stage.max_epochs = max_epochs;
        self.stage.patience = patience;
        self.start.stage = self.stage.clone();
    }

    /// True when the stage is over (epoch limit or patience).
    pub fn finished(&self) -> bool {
        self.epoch_limit_reached() || self.patience_ran_out()
    }

    fn epoch_limit_reached(&self) -> bool {
        self.progress.epoch >= self.stage.max_epochs
    }

    fn patience_ran_out(&self) -> bool {
        self.progress.bad_epochs >= self.stage.patience
    }

    /// Why the stage is over, in words (`None` while it is not): the epoch limit, which
    /// counts every epoch of the stage, and/or patience run out.
    pub fn stopped(&self) -> Option<String> {
        let (p, s) = (&self.progress, &self.stage);
        let mut why = Vec::new();
        if self.epoch_limit_reached() {
            why.push(format!(
                "the epoch limit is reached (epoch {} of max_epochs = {}, a total count)",
                p.epoch, s.max_epochs
            ));
        }
        if self.patience_ran_out() {
            why.push(format!(
                "patience ran out at epoch {} ({} epoch{} without a better validation loss than epoch {}'s; patience = {})",
                p.epoch,
                p.bad_epochs,
                if p.bad_epochs == 1 { "" } else { "s" },
                p.best_epoch,
                s.patience
            ));
        }
        (!why.is_empty()).then(|| why.join(", and "))
    }

    /// What a resumed run needs to train further when the stage is over: the limits to
    /// raise, named as the run config names them (`train.max_epochs above 72`).
    pub fn to_continue(&self) -> String {
        let mut raise = Vec::new();
        if self.epoch_limit_reached() {
            raise.push(format!("train.max_epochs above {}", self.progress.epoch));
        }
        if self.patience_ran_out() {
            raise.push(format!("train.patience above {}", self.progress.bad_epochs));
        }
        raise.join(" and ")
    }

    fn lr(&self, step: u64) -> f64 {
        learning_rate(
            self.stage.lr0,
            self.config.lr_decay,
            step,
            self.steps_per_epoch,
        )
    }

    fn epoch_order(&self, epoch: usize) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.train_groups.len()).collect();
        let seed = epoch_seed(self.config.seed, &self.stage.name, epoch);
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
        order
    }

    /// Gathers the windows of step `s` of an epoch and runs it (forward, loss, backward
    /// and Adam; submitted without a wait on the device). The step's windows are
    /// consecutive groups of the shuffled `order`, wrapping around to fill the last batch
    /// (every window is seen each epoch); they are gathered into buffers kept across steps.
    fn submit_step(&mut self, order: &[usize], s: usize) -> Result<(), TrainError> {
        self.positions.clear();
        for g in 0..self.groups_per_batch {
            let group = order[(s * self.groups_per_batch + g) % order.len()];
            self.positions.extend_from_slice(&self.train_groups[group]);
        }
        let data = self.data;
        data.gather_into(&self.positions, &mut self.batch_x, &mut self.batch_y);
        let step = self.progress.step;
        let lr = self.lr(step);
        self.engine.step(&self.batch_x, &self.batch_y, step, lr, s)
    }

    /// Trains one epoch, validates, and updates the early-stopping state; true when the
    /// validation loss improved (the best weights were updated).
    pub fn run_epoch(&mut self) -> Result<(EpochRecord, bool), TrainError> {
        let epoch = self.progress.epoch + 1;
        let order = self.epoch_order(epoch);
        let began = Instant::now();
        let first_step = self.progress.step;
        for s in 0..self.steps_per_epoch {
            self.submit_step(&order, s)?;
            self.progress.step += 1;
        }
        let losses = self.step_losses()?;
        let seconds = began.elapsed().as_secs_f64();
        if let Some(bad) = losses.iter().position(|l| !l.is_finite()) {
            return Err(self.diagnose(epoch, &order, bad, first_step));
        }
        let first_loss = *self.progress.first_loss.get_or_insert(losses[0] as f64);
        let ceiling = EXPLOSION_FACTOR * first_loss.max(1e-3);
        if let Some(bad) = losses.iter().position(|&l| l as f64 >= ceiling) {
            return Err(TrainError::Diverged {
                step: first_step + bad as u64,
                epoch,
                batch: bad + 1,
                what: format!(
                    "the loss rose to {:.3e}, {:.0e} times or more the stage's first loss \
                     ({first_loss:.3e}); the learning rate ({:.3e}) is likely too high",
                    losses[bad],
                    EXPLOSION_FACTOR,
                    self.lr(first_step + bad as u64)
                ),
                last_good: Box::new(self.start.params.clone()),
            });
        }
        let validation_began = Instant::now();
        let val_loss = self.validation_loss()?;
        let validation_seconds = validation_began.elapsed().as_secs_f64();
        let readback_began = Instant::now();
        let params = self.engine.parameters()?;
        if first_non_finite(&params.specs, &params.values).is_some() {
            // The replay names the step and the tensor.
            let last = self.steps_per_epoch - 1;
            return Err(self.diagnose(epoch, &order, last, first_step));
        }
        let (adam_m, adam_v) = self.engine.moments()?;
        let record = EpochRecord {
            stage: self.stage.name.clone(),
            epoch,
            step: self.progress.step,
            train_loss: losses.iter().map(|&l| l as f64).sum::<f64>() / losses.len() as f64,
            val_loss,
            lr: self.lr(self.progress.step - 1),
            seconds,
            windows_per_s: (self.steps_per_epoch * self.batch) as f64 / seconds,
            validation_seconds,
            readback_seconds: readback_began.elapsed().as_secs_f64(),
            trained_on: self.trained_on(),
        };
        self.progress.epoch = epoch;
        self.progress.history.push(record.clone());
        let improved = val_loss < self.progress.best_val;
        if improved {
            self.progress.best_val = val_loss;
            self.progress.best_epoch = epoch;
            self.progress.bad_epochs = 0;
            self.best = params.clone();
        } else {
            self.progress.bad_epochs += 1;
        }
        self.start = Snapshot {
            stage: self.stage.clone(),
            progress: self.progress.clone(),
            params,
            best: self.best.clone(),
            adam_m,
            adam_v,
        };
        Ok((record, improved))
    }

    /// The loss of each step of the last epoch, in order (standardised label space).
    pub fn step_losses(&self) -> Result<Vec<f32>, TrainError> {
        let mut losses = vec![0f32; self.steps_per_epoch];
        self.engine.losses(&mut losses)?;
        Ok(losses)
    }

    /// Replays the failing epoch from its start, one step at a time with readbacks, to
    /// find the first step whose loss or updated parameters are not finite.
    fn diagnose(
        &mut self,
        epoch: usize,
        order: &[usize],
        bad: usize,
        first_step: u64,
    ) -> TrainError {
        let fallback = |what: String, last_good: Parameters| TrainError::Diverged {
            step: first_step + bad as u64,
            epoch,
            batch: bad + 1,
            what,
            last_good: Box::new(last_good),
        };
        let start = self.start.clone();
        let replay = (|| -> Result<TrainError, TrainError> {
            self.engine.load(&start.params)?;
            self.engine.load_moments(&start.adam_m, &start.adam_v)?;
            self.progress.step = first_step;
            let mut before = start.params.clone();
            for s in 0..=bad {
                self.submit_step(order, s)?;
                self.progress.step += 1;
                let mut loss = [0f32];
                self.read_log_at(s, &mut loss)?;
                let step = first_step + s as u64;
                let fail = |what: String, last_good: Parameters| TrainError::Diverged {
                    step,
                    epoch,
                    batch: s + 1,
                    what,
                    last_good: Box::new(last_good),
                };
                if !loss[0].is_finite() {
                    let grads = self.engine.gradients()?;
                    let what = match first_non_finite(&start.params.specs, &grads) {
                        Some((name, i)) => format!(
                            "the loss is {}; first non-finite gradient: {name} (element {i})",
                            loss[0]
                        ),
                        None => format!("the loss is {} with finite gradients", loss[0]),
                    };
                    return Ok(fail(what, before));
                }
                let after = self.engine.parameters()?;
                if let Some((name, i)) = first_non_finite(&after.specs, &after.values) {
                    let what = format!(
                        "the Adam update made parameter {name} (element {i}) non-finite (loss {})",
                        loss[0]
                    );
                    return Ok(fail(what, before));
                }
                before = after;
            }
            Ok(fallback(
                "a non-finite loss that the step-by-step replay did not reproduce".into(),
                start.params.clone(),
            ))
        })();
        replay.unwrap_or_else(|e| e)
    }

    fn read_log_at(&self, s: usize, out: &mut [f32]) -> Result<(), TrainError> {
        out[0] = self.step_losses()?[s];
        Ok(())
    }

    /// ŷ (standardised) of the windows at `positions`, `[len, O]` row-major, with the
    /// current parameters (inference: no dropout). On a CPU adapter or the native path
    /// the IASTGCN variants run on the native CPU forward (about 10× faster than the WGSL
    /// forward there); elsewhere on the device in batches.
    pub fn predict(&self, positions: &[usize]) -> Result<Vec<f32>, TrainError> {
        self.engine
            .predict(&self.model, &self.graph, self.data, positions)
    }

    /// The stage's loss on the validation split (ensemble loss when refining).
    pub fn validation_loss(&self) -> Result<f64, TrainError> {
        let mut positions: Vec<usize> = self.val_groups.iter().flatten().copied().collect();
        positions.sort_unstable();
        positions.dedup();
        let pred = self.predict(&positions)?;
        let o = OUTPUTS;
        let row = |p: usize| {
            // invariant: positions holds every member of every group.
            positions
                .binary_search(&p)
                .expect("group members were predicted")
        };
        let mut total = 0.0;
        for g in &self.val_groups {
            let pg: Vec<f32> = g
                .iter()
                .flat_map(|&p| pred[row(p) * o..(row(p) + 1) * o].to_vec())
                .collect();
            let yg: Vec<f32> = g
                .iter()
                .flat_map(|&p| self.data.y[p * o..(p + 1) * o].to_vec())
                .collect();
            total += ensemble_loss(&pg, &yg, o, self.config.attitude_penalty);
        }
        Ok(total / self.val_groups.len() as f64)
    }

    /// Scores the starting weights with this stage's validation loss and makes them the
    /// best so far: the stage then keeps them unless an epoch improves on them (so
    /// refinement never makes a model worse on validation). Returns that loss.
    pub fn keep_start_unless_improved(&mut self) -> Result<f64, TrainError> {
        let loss = self.validation_loss()?;
        self.progress.best_val = loss;
        self.best = self.start.params.clone();
        self.start.best = self.best.clone();
        self.start.progress = self.progress.clone();
        Ok(loss)
    }

    /// This stage's validation loss of `params` (left loaded in the network).
    pub fn validation_loss_of(&mut self, params: &Parameters) -> Result<f64, TrainError> {
        self.load_parameters(params)?;
        self.validation_loss()
    }

    /// Loads `params` into the network (what [`Trainer::predict`] then uses).
    pub fn load_parameters(&mut self, params: &Parameters) -> Result<(), TrainError> {
        self.engine.load(params)
    }

    /// Loads the best weights into the network (at the end of a stage).
    pub fn restore_best(&mut self) -> Result<(), TrainError> {
        let best = self.best.clone();
        self.engine.load(&best)
    }
}

fn first_non_finite(
    specs: &[crate::model::ParamSpec],
    values: &[Vec<f32>],
) -> Option<(String, usize)> {
    specs.iter().zip(values).find_map(|(s, v)| {
        v.iter()
            .position(|x| !x.is_finite())
            .map(|i| (s.name.clone(), i))
    })
}
