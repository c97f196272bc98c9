//! Where a training stage's steps run (`[train] backend`, docs/usage.md): the WGSL
//! schedule on the adapter (forward, loss, backward and Adam in one submit per step, the
//! step losses logged on the device and read once per epoch), or
//! [`NativeTraining`] on the CPU, the same arithmetic in f32 with the batch split over
//! threads. `auto` takes the native path on a CPU adapter (lavapipe) for the variants
//! it covers, where it is an order of magnitude faster (docs/performance.md).

use super::config::TrainConfig;
use super::error::TrainError;
use super::optimizer::{Moments, Optimizer};
use crate::data::Dataset;
use crate::gpu::{DType, Device, Gpu, Readback, Recorder, Tensor};
use crate::graph::Graph;
use crate::model::native::cores;
use crate::model::{
    ModelConfig, NativeAdam, NativeForward, NativeStepShape, NativeTraining, Network, Parameters,
};
use std::sync::Arc;

/// The steps of one stage, on the device or on the CPU.
pub(super) enum Engine {
    Device(Box<DeviceSteps>),
    Native(Box<NativeSteps>),
}

pub(super) struct DeviceSteps {
    gpu: Arc<Gpu>,
    net: Network,
    opt: Optimizer,
    /// One loss per step of the epoch, read once at its end.
    loss_log: Tensor,
    loss_rb: Readback,
    /// ŷ of up to `table_rows` windows per readback (predictions).
    table: Tensor,
    table_rb: Readback,
    table_rows: usize,
}

pub(super) struct NativeSteps {
    train: NativeTraining,
    /// One loss per step of the epoch.
    losses: Vec<f32>,
    /// One inference forward per thread for the predictions (validation), built at the
    /// first and given the current weights at each.
    forwards: std::sync::Mutex<Vec<NativeForward>>,
}

/// True when `[train] backend` (`auto`, `device`, `native`) puts training on the CPU here
/// (the native path covers every variant): `auto` does on a CPU adapter and without one;
/// `device` without an adapter is an error.
pub fn runs_native(backend: &str, device: &Device) -> Result<bool, TrainError> {
    match backend {
        "auto" => Ok(device.prefers_native()),
        "device" => device
            .gpu("train.backend = \"device\"")
            .map(|_| false)
            .map_err(TrainError::from),
        "native" => Ok(true),
        other => Err(TrainError::Data(format!(
            "train.backend = {other:?}: expected \"auto\", \"device\" or \"native\""
        ))),
    }
}

impl Engine {
    /// The stage's engine with `init` loaded and zero moments: `batch` windows per step in
    /// ensembles of `group`, `steps` steps per epoch.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        device: &Device,
        model: &ModelConfig,
        graph: &Graph,
        config: &TrainConfig,
        batch: usize,
        group: usize,
        steps: usize,
        init: &Parameters,
    ) -> Result<Engine, TrainError> {
        let seed32 = (config.seed as u32) ^ ((config.seed >> 32) as u32);
        if runs_native(&config.backend, device)? {
            let shape = NativeStepShape {
                batch,
                group,
                seed: seed32,
                penalty: config.attitude_penalty,
                threads: config.native_threads(),
            };
            let adam = NativeAdam {
                beta1: config.beta1,
                beta2: config.beta2,
                eps: config.adam_eps,
                weight_decay: config.weight_decay,
            };
            let mut train = NativeTraining::new(model, graph, shape, adam)?;
            train.load_parameters(init)?;
            return Ok(Engine::Native(Box::new(NativeSteps {
                train,
                losses: vec![0.0; steps],
                forwards: Default::default(),
            })));
        }
        let gpu = device.gpu("training on the device")?.clone();
        let gpu = &gpu;
        let net = if group == 1 {
            Network::new(gpu, model, graph, batch, seed32)?
        } else {
            Network::for_ensembles(gpu, model, graph, batch, group, seed32)?
        };
        net.set_attitude_penalty(gpu, config.attitude_penalty)?;
        net.load_parameters(gpu, init)?;
        let opt = Optimizer::new(gpu, &net, config)?;
        let loss_log = gpu.zeros("loss log", &[steps], DType::F32)?;
        let loss_rb = Readback::new(gpu, "loss log", loss_log.byte_len())?;
        let table_rows = batch * 16;
        let table = gpu.zeros("predictions", &[table_rows, model.outputs], DType::F32)?;
        let table_rb = Readback::new(gpu, "predictions", table.byte_len())?;
        Ok(Engine::Device(Box::new(DeviceSteps {
            gpu: gpu.clone(),
            net,
            opt,
            loss_log,
            loss_rb,
            table,
            table_rb,
            table_rows,
        })))
    }

    /// Where the steps run: the adapter's name, or `native CPU (n threads)`.
    pub fn label(&self) -> String {
        match self {
            Engine::Device(d) => d.gpu.info().name.clone(),
            Engine::Native(n) => match (n.train.shape().threads, cores::shared()) {
                (1, false) => "native CPU (1 thread)".into(),
                (t, false) => format!("native CPU ({t} threads)"),
                (t, true) => format!("native CPU ({t} shares on the cores other runs leave)"),
            },
        }
    }

    /// The device network (`None` on the native path).
    pub fn network(&self) -> Option<&Network> {
        match self {
            Engine::Device(d) => Some(&d.net),
            Engine::Native(_) => None,
        }
    }

    /// Replaces the weights.
    pub fn load(&mut self, p: &Parameters) -> Result<(), TrainError> {
        match self {
            Engine::Device(d) => d.net.load_parameters(&d.gpu, p)?,
            Engine::Native(n) => n.train.load_parameters(p)?,
        }
        Ok(())
    }

    /// Replaces Adam's moments.
    pub fn load_moments(&mut self, m: &[Vec<f32>], v: &[Vec<f32>]) -> Result<(), TrainError> {
        match self {
            Engine::Device(d) => d.opt.load_state(&d.gpu, m, v)?,
            Engine::Native(n) => n.train.load_moments(m, v)?,
        }
        Ok(())
    }

    /// The current weights (read back from the device).
    pub fn parameters(&self) -> Result<Parameters, TrainError> {
        Ok(match self {
            Engine::Device(d) => d.net.read_parameters(&d.gpu)?,
            Engine::Native(n) => n.train.parameters(),
        })
    }

    /// Adam's moments.
    pub fn moments(&self) -> Result<Moments, TrainError> {
        Ok(match self {
            Engine::Device(d) => d.opt.read_state(&d.gpu)?,
            Engine::Native(n) => n.train.moments(),
        })
    }

    /// The last step's gradients (for the divergence report).
    pub fn gradients(&self) -> Result<Vec<Vec<f32>>, TrainError> {
        Ok(match self {
            Engine::Device(d) => d.net.read_gradients(&d.gpu)?,
            Engine::Native(n) => n.train.last_gradients().to_vec(),
        })
    }

    /// Optimiser step `step` (from 0 in the stage) at learning rate `lr` on the batch
    /// `x`, `y`; its loss goes to slot `slot` of the epoch's log. On the device this
    /// submits without waiting.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        x: &[f32],
        y: &[f32],
        step: u64,
        lr: f64,
        slot: usize,
    ) -> Result<(), TrainError> {
        match self {
            Engine::Device(d) => {
                let gpu = &*d.gpu;
                gpu.write(&d.net.input, x)?;
                gpu.write(&d.net.target, y)?;
                d.net.set_step(gpu, step as u32)?;
                d.opt.set_step(gpu, lr, step + 1)?;
                let mut rec = Recorder::new(gpu);
                d.net.record_train_forward(&mut rec)?;
                d.net.record_backward(&mut rec)?;
                rec.copy_f32(&d.net.loss, 0, &d.loss_log, slot, 1)?;
                d.opt.record(&mut rec);
                rec.submit()?;
            }
            Engine::Native(n) => {
                n.losses[slot] = n.train.step(x, y, step, lr)? as f32;
            }
        }
        Ok(())
    }

    /// The epoch's step losses so far (waits for the device).
    pub fn losses(&self, out: &mut [f32]) -> Result<(), TrainError> {
        match self {
            Engine::Device(d) => {
                let gpu = &*d.gpu;
                let mut rec = Recorder::new(gpu);
                rec.read_into(&d.loss_log, &d.loss_rb)?;
                rec.submit()?;
                let mut all = vec![0f32; d.loss_log.numel()];
                d.loss_rb.read_into(gpu, &mut all)?;
                out.copy_from_slice(&all[..out.len()]);
            }
            Engine::Native(n) => out.copy_from_slice(&n.losses[..out.len()]),
        }
        Ok(())
    }

    /// ŷ (standardised) of the windows at `positions`, `[len, O]`, with the current
    /// weights and no dropout. IASTGCN variants on a CPU adapter or the native path run
    /// on [`NativeForward`]; the rest on the device in batches.
    pub fn predict(
        &self,
        model: &ModelConfig,
        graph: &Graph,
        data: &Dataset,
        positions: &[usize],
    ) -> Result<Vec<f32>, TrainError> {
        let d = match self {
            Engine::Native(n) => {
                let params = n.train.parameters();
                // A poisoned lock (a panic while it was held) still holds whole
                // forwards: each is given the weights again below.
                let mut forwards = n.forwards.lock().unwrap_or_else(|e| e.into_inner());
                if forwards.is_empty() {
                    for _ in 0..n.train.shape().threads {
                        forwards.push(NativeForward::new(model, graph, &params)?);
                    }
                } else {
                    for f in forwards.iter_mut() {
                        f.set_parameters(&params)?;
                    }
                }
                return native_predict(&mut forwards, data, positions);
            }
            Engine::Device(d) => d,
        };
        let gpu = &*d.gpu;
        if gpu.is_software() {
            let params = d.net.read_parameters(gpu)?;
            let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
            let mut forwards = (0..threads)
                .map(|_| NativeForward::new(model, graph, &params))
                .collect::<Result<Vec<_>, _>>()?;
            return native_predict(&mut forwards, data, positions);
        }
        let (o, len) = (model.outputs, data.window_len());
        let b = d.net.batch;
        let mut out = Vec::with_capacity(positions.len() * o);
        let mut buf = vec![0f32; d.table.numel()];
        for segment in positions.chunks(d.table_rows) {
            for (c, chunk) in segment.chunks(b).enumerate() {
                let (mut x, _) = data.gather(chunk);
                x.resize(b * len, 0.0);
                gpu.write(&d.net.input, &x)?;
                let mut rec = Recorder::new(gpu);
                d.net.record_forward(&mut rec)?;
                rec.copy_f32(&d.net.output, 0, &d.table, c * b * o, b * o)?;
                rec.submit()?;
            }
            let mut rec = Recorder::new(gpu);
            rec.read_into(&d.table, &d.table_rb)?;
            rec.submit()?;
            d.table_rb.read_into(gpu, &mut buf)?;
            out.extend_from_slice(&buf[..segment.len() * o]);
        }
        Ok(out)
    }
}

/// ŷ of the windows at `positions`, split into `forwards.len()` contiguous shares, one
/// thread and one [`NativeForward`] each (a window's output does not depend on the split).
fn native_predict(
    forwards: &mut [NativeForward],
    data: &Dataset,
    positions: &[usize],
) -> Result<Vec<f32>, TrainError> {
    let Some(o) = forwards.first().map(|f| f.config().outputs) else {
        return Err(TrainError::Data("no native forward to predict with".into()));
    };
    let len = data.window_len();
    let mut out = vec![0f32; positions.len() * o];
    let run = |native: &mut NativeForward, positions: &[usize], out: &mut [f32]| {
        for (&p, row) in positions.iter().zip(out.chunks_mut(o)) {
            native.forward(&data.x[p * len..][..len], row)?;
        }
        Ok::<(), TrainError>(())
    };
    // A window's prediction is the same on any forward and thread; the threads are
    // those the jobs beside this one leave (`cores`).
    let lease = cores::lease(forwards.len());
    let used = lease.threads().min(forwards.len());
    if used == 1 {
        run(&mut forwards[0], positions, &mut out)?;
        return Ok(out);
    }
    let share = positions.len().div_ceil(used).max(1);
    std::thread::scope(|scope| {
        let jobs: Vec<_> = positions
            .chunks(share)
            .zip(out.chunks_mut(share * o))
            .zip(forwards[..used].iter_mut())
            .map(|((p, out), native)| scope.spawn(move || run(native, p, out)))
            .collect();
        jobs.into_iter().try_for_each(|j| match j.join() {
            Ok(result) => result,
            Err(_) => Err(TrainError::Data(
                "a native prediction thread panicked".into(),
            )),
        })
    })?;
    Ok(out)
}
